"""Hardening v3: a run read again is checked against how it was made; interruptions, writers
and scale (issue 42, parts 2-4).

Each case is a command a user could type, or the one place a kind of failure is guarded:
plugins are imported in `plugins.load`, figures staged in `atomic_files.save_figure`, a
run's code checked in `training.provenance.check`, a killed writer's leftovers removed in
`store.settle_checkpoint`."""

from __future__ import annotations

import json
import multiprocessing
import shutil
import signal
import time
from pathlib import Path

import pytest

import pimbot
from pimbot import atomic_files, cli, plugins
from pimbot.errors import InvalidParameter
from pimbot.training import provenance, runs, store

SRC = Path(pimbot.__file__).parent
HERE = Path(__file__).parent


def run_cli(argv: list[str], capsys) -> tuple[int, str]:
    code = cli.main(argv)
    return code, capsys.readouterr().err.strip()


# --- plugins that exit or are interrupted at import ---------------------------------------


@pytest.mark.parametrize(
    "body, said",
    [
        ("import sys\nsys.exit(0)\n", ":2: it called exit(0) while being imported"),
        ("raise SystemExit(3)\n", ":1: it called exit(3) while being imported"),
        ("raise KeyboardInterrupt\n", ":1: interrupted (KeyboardInterrupt) while being imported"),
    ],
)
def test_a_plugin_that_exits_or_is_interrupted_at_import_is_one_line_exit_2(
    tmp_path, capsys, body, said
):
    plugin = tmp_path / "quits.py"
    plugin.write_text(body)
    code, err = run_cli(["check", str(plugin)], capsys)
    assert code == 2 and len(err.splitlines()) == 1, err
    assert f"cannot import {plugin}: {plugin}{said}" in err
    assert str(plugin) not in plugins.loaded()


# --- check: a bounded budget, with progress ---------------------------------------------


@pytest.mark.parametrize(
    "args, said",
    [
        (["--iterations", "100000000"], "iterations: a canary runs 1 to 10000 iterations"),
        (["--seeds", "1000"], "seeds: a canary runs 1 to 16 seeds"),
    ],
)
def test_check_bounds_its_budget_before_any_work(capsys, args, said):
    plugin = str(Path(__file__).parent / "data" / "coordination_plugin.py")
    start = time.perf_counter()
    code, err = run_cli(["check", plugin, *args], capsys)
    assert code == 2 and len(err.splitlines()) == 1 and said in err, err
    assert time.perf_counter() - start < 60


def test_check_announces_each_canary_run(capsys):
    from pimbot.training import canary

    size = canary.Size(seeds=2, iterations=2, eval_episodes=1, progress=True)
    resolved = canary.resolved_run("escape_room-v0", "lio", size)
    canary.paired_run(resolved, lambda on: (resolved.attack, resolved.defenses), size)
    err = capsys.readouterr().err.splitlines()
    assert err == [
        f"check: lio escape_room-v0 ×2, {half}: seed {k}/2, 2 iterations"
        for half in ("with its hooks", "hooks as no-ops")
        for k in (1, 2)
    ]


# --- figures and staged files -------------------------------------------------------------


def test_every_figure_is_written_through_one_staged_writer():
    """`savefig` appears only in atomic_files.save_figure: no writer can leave a truncated
    figure (a full disk while `pimbot report` wrote figures/scorecard_effects.png)."""
    callers = [
        str(path.relative_to(SRC))
        for path in SRC.rglob("*.py")
        if ".savefig(" in path.read_text(encoding="utf-8")
    ]
    assert callers == ["atomic_files.py"]


def test_a_figure_cut_by_a_full_disk_leaves_the_old_figure_and_nothing_staged(tmp_path):
    import matplotlib.pyplot as plt

    from pimbot.analysis import plots

    path = tmp_path / "figures" / "scorecard_effects.png"
    path.parent.mkdir()
    path.write_bytes(b"the previous figure")
    fig, ax = plt.subplots()
    ax.plot([0, 1], [0, 1])

    def full_disk(target, **options):
        Path(target).write_bytes(b"\x89PNG half")
        raise OSError(28, "No space left on device")

    fig.savefig = full_disk
    with pytest.raises(OSError, match="No space left"):
        plots.save(fig, path)
    assert path.read_bytes() == b"the previous figure"
    assert sorted(p.name for p in path.parent.iterdir()) == ["scorecard_effects.png"]


def test_a_killed_writers_staged_files_are_removed_by_the_next_writer(tmp_path):
    run_dir = tmp_path / "run"
    (run_dir / store.CHECKPOINT_DIR).mkdir(parents=True)
    left = [
        run_dir / store.CHECKPOINT_DIR / ".state.msgpack.k2j4l1x_.msgpack",
        run_dir / store.CHECKPOINT_DIR / ".meta.json.a1b2c3d4.json",
        run_dir / ".metrics.csv.zz99yy88.csv",
        run_dir / ".config.json.q1w2e3r4.json",
    ]
    kept = [run_dir / "notes.txt", run_dir / ".hidden", run_dir / ".metrics.csv.short.csv"]
    for path in left + kept:
        path.write_bytes(b"x")
    staging = run_dir / ".tensorboard.ab12cd34"  # a staged directory
    staging.mkdir()
    assert atomic_files.leftovers(run_dir) == sorted([*left[2:], staging])
    store.settle_checkpoint(run_dir)  # the writer, under the run's lock, as it resumes
    assert not any(p.exists() for p in [*left, staging])
    assert all(p.exists() for p in kept)


# --- export --out -----------------------------------------------------------------------


@pytest.mark.parametrize("out", [".", "./", "sub/.."])
def test_export_out_that_is_the_current_directory_is_refused_before_work(
    tmp_path, monkeypatch, out
):
    from pimbot.robot import export

    monkeypatch.chdir(tmp_path)
    (tmp_path / "sub").mkdir()
    with pytest.raises(InvalidParameter, match="is the current directory or holds it"):
        export.check_out(Path(out))
    export.check_out(Path("new_export"))  # a directory to create: fine


def test_a_staged_directory_is_named_after_its_directory(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with atomic_files.staged_directory(Path("sub") / ".." / "made") as new:
        assert new.parent.name.startswith(".made.")
        new.mkdir()
    assert (tmp_path / "made").is_dir() and sorted(p.name for p in tmp_path.iterdir()) == ["made"]


# --- Ctrl-C in a sweep: the workers never see it -------------------------------------------


def _report_sigint(queue) -> None:
    queue.put(signal.SIGINT in signal.pthread_sigmask(signal.SIG_BLOCK, []))


def test_sweep_workers_start_deaf_to_ctrl_c_and_the_sweep_loses_none():
    from pimbot.suites import sweep

    context = multiprocessing.get_context("spawn")
    queue = context.Queue()
    with sweep._interrupts_held():
        worker = context.Process(target=_report_sigint, args=(queue,))
        worker.start()
        assert signal.SIGINT in signal.pthread_sigmask(signal.SIG_BLOCK, [])
    assert queue.get(timeout=60) is True  # blocked from its first instruction
    worker.join(timeout=60)
    assert signal.SIGINT not in signal.pthread_sigmask(signal.SIG_BLOCK, [])
    with pytest.raises(KeyboardInterrupt):  # a Ctrl-C meanwhile reaches the sweep after
        with sweep._interrupts_held():
            signal.raise_signal(signal.SIGINT)
        time.sleep(0.1)


def test_ctrl_c_in_a_sweep_is_one_line_while_its_workers_start(tmp_path):
    """Ctrl-C reaches the whole process group (a terminal's): the sweep, and its workers
    while they import JAX or train. One line, exit 130, no worker's traceback."""
    import os
    import subprocess
    import sys

    grid = tmp_path / "grid.toml"
    grid.write_text(
        'name = "g"\nseeds = 1\niterations = 200000\neval_period = 100\n'
        '[[envs]]\nid = "escape_room-v0"\n[[learners]]\nname = "lio"\n'
        '[[attacks]]\nname = "none"\n[[attacks]]\nname = "admo"\n'
    )
    out = tmp_path / "out"
    argv = [sys.executable, "-m", "pimbot.cli", "sweep", str(grid), "--out", str(out)]
    sweep = subprocess.Popen(
        [*argv, "--workers", "2", "--quiet"],
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    deadline = time.monotonic() + 120
    while not (out / "index.json").exists() and time.monotonic() < deadline:
        time.sleep(0.2)
    time.sleep(2)  # the workers are starting: spawned, importing
    os.killpg(sweep.pid, signal.SIGINT)
    _, err = sweep.communicate(timeout=120)
    assert sweep.returncode == 130, err
    assert err.splitlines() == ["pimbot: interrupted; rerun the same command to resume"]


# --- the scorecard names what it cannot pair -----------------------------------------------


def test_an_attacked_run_without_a_clean_run_is_named(tmp_path):
    import importlib.util

    from pimbot.analysis import runs as analysis_runs
    from pimbot.analysis import scorecard as sc

    spec = importlib.util.spec_from_file_location("_scorecard_runs", HERE / "test_scorecard.py")
    helpers = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(helpers)
    ATTACK, write_run = helpers.ATTACK, helpers.write_run

    write_run(tmp_path, "grid/attacked", ATTACK)
    card = sc.scorecard(analysis_runs.load_table(tmp_path).records)
    assert card.comparisons == []
    note = sc.unmatched_note(card)
    assert note == (
        "1 run(s) without the run they are compared with: grid/attacked (no clean run with "
        "defenses none)."
    )


# --- scale: planning and --list are linear in the jobs ---------------------------------------


def big_grid(path: Path, envs: int, learners: int, attacks: int) -> Path:
    lines = ['name = "big"', "seeds = 1", "iterations = 100", "eval_period = 100"]
    for i in range(envs):
        lines += ["[[envs]]", 'id = "escape_room-v0"', f'label = "e{i}"']
        lines += [f"iterations = {100 * (i + 1)}"]
    for i in range(learners):
        lines += ["[[learners]]", 'name = "lio"', f'label = "l{i}"']
        lines += [f"hparams = {{ lr_incentive = {1e-3 * (i + 1)} }}"]
    for i in range(attacks):
        lines += ["[[attacks]]", 'name = "admo"', f'label = "a{i}"']
        lines += [f"params = {{ adversary = {i % 2} }}"]
    path.write_text("\n".join(lines) + "\n")
    return path


def test_sweep_list_of_100000_jobs_lists_every_job(tmp_path, capsys):
    """10^5 jobs are planned and listed (the time it takes is measured outside the tests:
    8.2–9.0 s on 2 loaded cores, against no answer in 600 s before; a timed unit test would
    fail on a busy machine, not on slow code)."""
    grid = big_grid(tmp_path / "big.toml", 50, 20, 100)
    warm = big_grid(tmp_path / "warm.toml", 1, 1, 2)
    cli.main(["sweep", str(warm), "--out", str(tmp_path / "warm"), "--list"])
    capsys.readouterr()  # imports and the first state size traced: not what scales
    start = time.perf_counter()
    code = cli.main(["sweep", str(grid), "--out", str(tmp_path / "out"), "--list"])
    elapsed = time.perf_counter() - start
    lines = capsys.readouterr().out.splitlines()
    assert code == 0 and len(lines) == 100_000 and lines[-1].startswith("big/e49_l19_a99 ")
    print(f"sweep --list of 10^5 jobs: {elapsed:.1f} s")
    assert not (tmp_path / "out").exists()  # --list writes nothing


# --- provenance: a run goes on only with the code it was made with -------------------------


@pytest.fixture(scope="module")
def made(tmp_path_factory):
    """A finished run trained with a plugin file, and the command that made it."""
    root = tmp_path_factory.mktemp("provenance")
    plugin = root / "tweak.py"
    plugin.write_text("VALUE = 1\n")
    run_dir = root / "run"
    argv = ["train", "escape_room-v0", "--seeds", "1", "--iterations", "20"]
    argv += ["--eval-period", "10", "--eval-episodes", "1", "--chunk-iterations", "10"]
    argv += ["--plugin", str(plugin), "--out", str(run_dir), "--quiet"]
    assert cli.main(argv) == 0
    return run_dir, plugin, argv


def unfinished_copy(made, tmp_path, version: str | None = None) -> tuple[Path, list[str]]:
    """The run, copied, without summary.json (so a rerun resumes it), its config.json
    saying it was made by pimbot `version`."""
    run_dir, _, argv = made
    copy = tmp_path / "run"
    shutil.copytree(run_dir, copy)
    (copy / store.SUMMARY).unlink()
    if version is not None:
        config = json.loads((copy / store.CONFIG).read_text())
        config["pimbot_version"] = version
        (copy / store.CONFIG).write_text(json.dumps(config))
    return copy, [*argv[:-2], str(copy), "--quiet"]


def test_a_run_made_by_another_pimbot_resumes_only_with_the_flag_which_is_recorded(
    made, tmp_path, capsys
):
    copy, argv = unfinished_copy(made, tmp_path, "0.1.0")
    code, err = run_cli(argv, capsys)
    assert code == 2 and len(err.splitlines()) == 1, err
    assert f"the run was made with pimbot 0.1.0 (this is pimbot {pimbot.__version__})" in err
    assert "--accept-changed-code" in err
    assert not (copy / store.SUMMARY).exists()
    code, err = run_cli(["train", "--from", str(copy), "--quiet"], capsys)
    assert code == 2 and "pimbot 0.1.0" in err and "--accept-changed-code" in err
    assert cli.main([*argv, "--accept-changed-code"]) == 0
    config = json.loads((copy / store.CONFIG).read_text())
    assert config["pimbot_version"] == pimbot.__version__
    (change,) = config[provenance.CHANGES]
    assert change["before"]["pimbot_version"] == "0.1.0"
    assert change["changes"] == [f"pimbot 0.1.0 (this is pimbot {pimbot.__version__})"]
    assert (copy / store.SUMMARY).exists()


def test_a_run_whose_plugin_changed_resumes_only_with_the_flag(made, tmp_path, capsys):
    run_dir, plugin, _ = made
    copy, argv = unfinished_copy(made, tmp_path)
    before = plugin.read_text()
    plugin.write_text("VALUE = 2\n")
    try:
        code, err = run_cli(argv, capsys)
        assert code == 2 and len(err.splitlines()) == 1, err
        assert f"plugin {plugin} at sha256" in err and "--accept-changed-code" in err
        code, err = run_cli(
            ["train", "--from", str(copy), "--plugin", str(plugin), "--quiet"], capsys
        )
        assert code == 2 and f"plugin {plugin} at sha256" in err
        export_refused = provenance.changes(json.loads((copy / store.CONFIG).read_text()))
        assert export_refused and export_refused[0].startswith(f"plugin {plugin}")
    finally:
        plugin.write_text(before)
    code, err = run_cli(argv, capsys)  # the code it was made with again: it resumes
    assert code == 0, err


def test_a_sweep_refuses_to_resume_a_job_made_by_other_code(made, tmp_path, capsys):
    from pimbot.suites import sweep
    from pimbot.suites.jobs import Job
    from pimbot.training.runs import saved_run_config

    run_dir, _, _ = made
    suite = tmp_path / "suite"
    copy, _ = unfinished_copy(made, suite / "g", "0.1.0")
    job = Job("g/run", "train", saved_run_config(copy))
    with pytest.raises(sweep.SweepError, match=r"g/run: .*pimbot 0\.1\.0.*--accept-changed"):
        sweep.plan([job], suite)
    assert sweep.plan([job], suite, accept_changed_code=True) == {"g/run": "partial"}


@pytest.mark.parametrize(
    "section, name, value, said",
    [
        ("env_params", "n_agents", 3, "differ in env_params"),
        ("hparams", "policy_hidden", [8, 8], "differ in learner_config"),
    ],
)
def test_a_config_json_edited_after_the_run_is_named_in_one_line(
    made, tmp_path, section, name, value, said
):
    run_dir, _, _ = made
    copy = tmp_path / "run"
    shutil.copytree(run_dir, copy)
    config = json.loads((copy / store.CONFIG).read_text())
    config["run_config"][section] = [*config["run_config"][section], [name, value]]
    (copy / store.CONFIG).write_text(json.dumps(config))
    with pytest.raises(store.DamagedRunDir) as error:
        runs.load_run(copy)
    message = str(error.value)
    assert len(message.splitlines()) == 1 and said in message and "was edited" in message
    # identity edited the same way: the checkpoint itself disagrees, by leaf and shape
    config["identity"] = runs.resolve(runs.saved_run_config(copy)).identity()
    (copy / store.CONFIG).write_text(json.dumps(config, default=str))
    with pytest.raises(store.DamagedRunDir, match="does not match the checkpoint"):
        runs.load_run(copy)


def test_a_run_made_with_a_plugin_not_loaded_now_names_the_flag_that_loads_it(tmp_path):
    """`pimbot export` (or a resume) of a plugin learner's run without `--plugin` names the
    file its config.json recorded, before the learner is looked up ("unknown learner")."""
    from pimbot.training import provenance

    run = tmp_path / "run"
    run.mkdir()
    record = {"plugin": "mine", "file": "/somewhere/mine.py", "sha256": "ab" * 32}
    (run / "config.json").write_text(json.dumps({"plugins": [record]}))
    with pytest.raises(provenance.CodeChanged, match=r"add --plugin /somewhere/mine.py to export"):
        provenance.check(run, accept=False, doing="export")
    assert provenance.check(run, accept=True, doing="export")  # the change, accepted
