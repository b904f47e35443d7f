"""Hardening v2: writers stay inside their directory, numbers are bounded before work.

Each case is a command a user could type; the answer is one line, exit code 2, and
nothing written (or nothing outside the directory touched)."""

from __future__ import annotations

import time

import pytest

from pimbot import cli
from pimbot.training import runner, store


def run_cli(argv: list[str], capsys) -> tuple[int, str]:
    code = cli.main(argv)
    err = capsys.readouterr().err.strip()
    return code, err


def test_report_refuses_a_figures_folder_that_links_out_and_leaves_its_target_alone(
    tmp_path, capsys
):
    suite, user = tmp_path / "suite", tmp_path / "user"
    suite.mkdir(), user.mkdir()
    (user / "mine.png").write_bytes(b"the user's figure")
    (suite / "figures").symlink_to(user)
    code, err = run_cli(["report", str(suite)], capsys)
    assert code == 2 and len(err.splitlines()) == 1
    assert "figures: a symbolic link" in err and "never through a link" in err
    assert (user / "mine.png").read_bytes() == b"the user's figure"
    assert sorted(p.name for p in suite.iterdir()) == ["figures"]


@pytest.mark.parametrize("name", ["tables/provenance.csv", "report.md"])
def test_report_refuses_a_file_that_links_out(tmp_path, capsys, name):
    suite, target = tmp_path / "suite", tmp_path / "target.txt"
    (suite / "tables").mkdir(parents=True)
    target.write_text("keep")
    (suite / name).symlink_to(target)
    code, err = run_cli(["report", str(suite)], capsys)
    assert code == 2 and "a symbolic link" in err and name.split("/")[-1] in err
    assert target.read_text() == "keep"


def test_write_atomic_never_writes_through_a_link_at_the_old_temporary_name(tmp_path):
    target, path = tmp_path / "target.txt", tmp_path / "report.md"
    target.write_text("keep")
    (tmp_path / "report.md.tmp").symlink_to(target)
    store.write_atomic(path, b"new")
    assert target.read_text() == "keep"
    assert path.read_bytes() == b"new" and not path.is_symlink()
    assert not list(tmp_path.glob(".report.md.*"))  # no temporary file left


@pytest.mark.parametrize(
    "args, expected",
    [
        (["--first-seed", "4294967296"], "first_seed: must be an integer in [0, 4294967294]"),
        (["--first-seed", "4294967295"], "first_seed: must be an integer in [0, 4294967294]"),
        (["--iterations", str(10**20)], "iterations: must be an integer in [1, 2147483647]"),
        (["--eval-episodes", "1000000000"], "eval_episodes: 1000000000 evaluation episodes"),
    ],
)
def test_numbers_beyond_what_the_program_represents_are_refused_before_work(
    tmp_path, capsys, args, expected
):
    out = tmp_path / "run"
    argv = ["train", "escape_room-v0", "--seeds", "2", "--out", str(out), *args]
    if "--iterations" not in args:
        argv += ["--iterations", "100"]
    code, err = run_cli(argv, capsys)
    assert code == 2 and len(err.splitlines()) == 1 and expected in err, err
    assert not out.exists()


def test_the_chunk_plan_takes_no_time_proportional_to_the_iterations():
    start = time.perf_counter()
    assert runner.evals_per_chunk(10**12, 100, 100) == 1
    assert runner.evals_per_chunk(10**12, 1, 500) == 500
    assert time.perf_counter() - start < 1.0
    # the same answers as the full search on small inputs
    for num_evals in range(1, 60):
        for period in (1, 3, 7, 100):
            for target in (1, 50, 500):
                full = max(
                    [
                        k
                        for k in range(1, num_evals + 1)
                        if num_evals % k == 0 and k * period <= target
                    ]
                    or [1]
                )
                assert runner.evals_per_chunk(num_evals, period, target) == full


def test_a_tables_csv_is_written_whole(tmp_path):
    from pimbot.analysis.tables import Table, write_csv

    path = tmp_path / "t.csv"
    write_csv(Table(["a", "b"], [[1, "x|y"]]), path)
    assert path.read_text().splitlines() == ["a,b", "1,x|y"]
    assert [p.name for p in tmp_path.iterdir()] == ["t.csv"]


def test_markdown_escapes_what_it_did_not_write():
    from pimbot.analysis.tables import Table, markdown_lines

    lines = markdown_lines(Table(["env", "param"], [["<img src=x onerror=alert(1)>", "a|b\nc"]]))
    row = lines[2]
    assert "<img" not in row and "&lt;img" in row
    assert row.count(" | ") == 1 and "a\\|b c" in row


def test_sigterm_prints_one_line_and_the_run_resumes(tmp_path):
    import os
    import signal
    import subprocess
    import sys

    out = tmp_path / "run"
    argv = [sys.executable, "-m", "pimbot.cli", "train", "escape_room-v0", "--seeds", "2"]
    argv += ["--iterations", "20000000", "--chunk-iterations", "100", "--quiet", "--out", str(out)]
    process = subprocess.Popen(argv, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 300
    while store.load_checkpoint(out) is None and time.monotonic() < deadline:
        time.sleep(0.5)
    process.send_signal(signal.SIGTERM)
    _, err = process.communicate(timeout=120)
    assert process.returncode == 143, err
    assert err.strip().splitlines()[-1] == "pimbot: terminated; rerun the same command to resume"
    assert store.load_checkpoint(out) is not None
    assert os.path.exists(out / store.METRICS)


@pytest.mark.parametrize(
    "uri, expected",
    [
        ("http://127.0.0.1:9", "did not answer within 5 s"),
        ("gopher://example", "unknown scheme 'gopher'"),
    ],
)
def test_an_unreachable_tracking_server_is_refused_at_once_with_nothing_written(
    tmp_path, capsys, monkeypatch, uri, expected
):
    pytest.importorskip("mlflow")
    monkeypatch.setenv("MLFLOW_TRACKING_URI", uri)
    out = tmp_path / "run"
    start = time.monotonic()
    argv = ["train", "escape_room-v0", "--seeds", "2", "--iterations", "100"]
    code, err = run_cli([*argv, "--log", "mlflow", "--out", str(out)], capsys)
    assert code == 2 and len(err.splitlines()) == 1 and expected in err, err
    assert time.monotonic() - start < 60
    assert not out.exists()


def test_damaged_files_are_named_in_one_line_never_read_as_good(tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    metrics = run / store.METRICS
    metrics.write_text("iteration,seed,eval/success\n100,0,0.5\n100,1,0.25\n200,0,0.7\n")
    identity = {"seeds": 2, "iterations": 200, "eval_period": 100}
    rows = store.read_metrics(run)
    with pytest.raises(store.DamagedRunDir, match="3 rows, expected 4"):
        store.check_rows_complete(run, rows, identity)
    metrics.write_text("iteration,seed,eval/success\n100,0,0.5\n100,1\n")
    with pytest.raises(store.DamagedRunDir, match="line 3 has the wrong number of cells"):
        store.read_metrics(run)
    metrics.write_text("iteration,seed,eval/success\n100,0,half\n")
    with pytest.raises(store.DamagedRunDir, match="line 2 holds a non-number"):
        store.read_metrics(run)
    other = tmp_path / "other.csv"
    other.write_text("iteration,seed,eval/success\n")
    metrics.unlink()
    metrics.symlink_to(other)
    with pytest.raises(store.DamagedRunDir, match="a symbolic link"):
        store.read_metrics(run)
    (run / "summary.json").write_text("[1, 2]")
    with pytest.raises(store.DamagedRunDir, match="a JSON list, expected an object"):
        store.read_json(run / "summary.json")


def test_a_binary_grid_file_is_one_line(tmp_path, capsys):
    grid = tmp_path / "grid.toml"
    grid.write_bytes(bytes(range(256)))
    code, err = run_cli(["sweep", str(grid), "--out", str(tmp_path / "out")], capsys)
    assert code == 2 and len(err.splitlines()) == 1 and "not valid TOML" in err, err
    assert not (tmp_path / "out").exists()


def test_profile_widths_and_robot_json_are_checked_before_work(tmp_path, capsys):
    code, err = run_cli(
        [
            "profile",
            "--env",
            "escape_room-v0",
            "--hidden",
            "100000000",
            "--out",
            str(tmp_path / "p"),
        ],
        capsys,
    )
    assert code == 2 and "hidden[0]: must be an integer in [1, 65536]" in err
    blocker = tmp_path / "file"
    blocker.write_text("")
    code, err = run_cli(
        ["robot", "eval", str(tmp_path), "--episodes", "1", "--json", str(blocker / "s.json")],
        capsys,
    )
    assert code == 2 and len(err.splitlines()) == 1
    assert "is not a directory" in err or "not a pimbot run directory" in err


def test_a_sweep_too_big_for_memory_is_refused_before_its_index_is_written(tmp_path, capsys):
    grid = tmp_path / "big.toml"
    grid.write_text(
        'name = "big"\nseeds = 100000000\niterations = 200\neval_period = 100\n'
        '[[envs]]\nid = "escape_room-v0"\n[[learners]]\nname = "lio"\n'
    )
    code, err = run_cli(["sweep", str(grid), "--out", str(tmp_path / "out"), "--quiet"], capsys)
    assert code == 2 and len(err.splitlines()) == 1 and "100000000 seeds need" in err, err
    assert not (tmp_path / "out").exists()


def test_state_files_are_never_written_through_a_link_at_the_old_temporary_names(tmp_path):
    """The channel's replay state, the audit log's head and a rendered video are staged
    under fresh names (a link at the names they once used is left alone)."""
    import numpy as np

    from pimbot.defenses import audit, channel
    from pimbot.robot import render

    target = tmp_path / "target.txt"
    target.write_text("keep")
    state, log, video = tmp_path / "state.json", tmp_path / "audit.log", tmp_path / "ep.gif"
    for planted in ("state.json.tmp", "audit.log.head.tmp", "ep.tmp.gif"):
        (tmp_path / planted).symlink_to(target)
    keys = channel.KeyRing({(0, 1): b"k" * 32})
    receiver = channel.Receiver(1, keys, state_path=state)
    assert receiver.receive(channel.Sender(0, keys).send(1, 0, 0, 1.0)).accepted
    audit.AuditLog(log, b"a" * 32).append("incentive", value=1.0)
    render.write_video([np.zeros((4, 4, 3), np.uint8)] * 2, video, fps=2)
    assert target.read_text() == "keep"
    assert state.is_file() and audit.head_path(log).is_file() and video.is_file()
    assert not list(tmp_path.glob(".*"))  # no staged file left behind


def test_a_failed_jobs_error_is_the_error_not_a_note_added_to_it():
    """index.json records a failed job's error: JAX's note on its filtered traceback
    (added after the message) is not the error."""
    from pimbot.suites import sweep

    error = ValueError("hook emit returned shape (3,), expected (3, 3)\nmore detail")
    error.add_note("For simplicity, JAX has removed its internal frames from the traceback")
    assert sweep._one_line(error) == "ValueError: hook emit returned shape (3,), expected (3, 3)"
    assert sweep._one_line(KeyError()) == "KeyError"
