"""Bad input, damaged run directories, concurrency and divergence: each ends in one clear
line (exit status ≠ 0), nothing half-written, nothing silently wrong."""

from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
from pathlib import Path
from typing import ClassVar

import jax.numpy as jnp
import pytest
from flax import struct

from pimbot import cli
from pimbot.attacks import Attack, register
from pimbot.training import store

TINY = ["--seeds", "2", "--iterations", "200", "--eval-period", "100", "--eval-episodes", "2"]
TRAIN = ["train", "ipd-v0", *TINY, "--chunk-iterations", "100", "--quiet"]  # 2 checkpoints


@register
@struct.dataclass
class NanAfter(Attack):
    """Test attack: the adversary's incentives become NaN after `after` iterations."""

    after: int = 150
    """Iterations before the incentives turn NaN."""

    name: ClassVar[str] = "test_nan_after"
    lever: ClassVar[str] = "incentive"
    hooks: ClassVar[tuple[str, ...]] = ("emit", "observe")

    def init_state(self, key, num_agents, adversary):
        del key, num_agents, adversary
        return {"iterations": jnp.zeros((), jnp.int32)}

    def emit(self, state, key, given_so_far):
        del key
        n = given_so_far.shape[0]
        poisoned = jnp.where(state["iterations"] >= self.after, jnp.nan, 0.0)
        return jnp.ones((n, n)), jnp.where(self.is_adversary(n)[:, None], poisoned, 0.0)

    def observe(self, state, key, outcome):
        del key, outcome
        return {"iterations": state["iterations"] + 1}


def _one_line_error(capsys) -> str:
    err = capsys.readouterr().err
    assert err.startswith("pimbot: error: ") and len(err.strip().splitlines()) == 1, err
    return err


def test_divergence_stops_with_iteration_and_quantity_keeping_the_last_finite_checkpoint(
    tmp_path, capsys
):
    out = tmp_path / "run"
    argv = ["train", "ipd-v0", "--seeds", "2", "--iterations", "400", "--eval-period", "100"]
    argv += ["--chunk-iterations", "100", "--attack", "test_nan_after", "--quiet"]
    assert cli.main([*argv, "--out", str(out)]) == 1
    err = _one_line_error(capsys)
    assert "diverged: iteration 200, seed 0:" in err and "nan" in err
    assert "last finite checkpoint (iteration 100)" in err
    meta = json.loads((out / "checkpoint" / "meta.json").read_text())
    assert meta["iteration"] == 100
    with open(out / "metrics.csv") as f:
        rows = list(csv.DictReader(f))
    assert {r["iteration"] for r in rows} == {"100"}  # nothing of the diverged chunk
    assert not (out / "summary.json").exists()


def _results(run_dir) -> list[dict]:
    """metrics.csv without its timing columns (perf/*)."""
    return [
        {k: v for k, v in row.items() if not k.startswith("perf/")}
        for row in store.read_metrics(run_dir)
    ]


def _train(out) -> None:
    assert cli.main([*TRAIN, "--out", str(out)]) == 0


def _damage_metrics_truncate(out):
    text = (out / "metrics.csv").read_text()
    (out / "metrics.csv").write_text(text[: len(text) - 25])


def _damage_metrics_delete(out):
    (out / "metrics.csv").unlink()


def _damage_checkpoint_byte(out):
    path = out / "checkpoint" / "state.msgpack"
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 1
    path.write_bytes(bytes(data))


def _damage_checkpoint_meta(out):
    (out / "checkpoint" / "meta.json").write_text('{"iteration": "many"}')


def _damage_checkpoint_meta_garbage(out):
    (out / "checkpoint" / "meta.json").write_bytes(b"\x00\xff\xfe")


def _damage_checkpoint_iteration(out):  # consistent bytes, the metadata's count changed
    meta = json.loads((out / "checkpoint" / "meta.json").read_text())
    meta["iteration"] = 100
    (out / "checkpoint" / "meta.json").write_text(json.dumps(meta))


def _damage_config(out):
    (out / "config.json").write_text("{not json")


def _damage_config_edited(out):  # valid JSON, identity kept, the env's parameters changed
    config = json.loads((out / "config.json").read_text())
    config["env"]["params"]["max_steps"] += 1
    (out / "config.json").write_text(json.dumps(config))


def _damage_metrics_value(out):  # one digit of a checkpointed row, same length
    path = out / "metrics.csv"
    lines = path.read_text().splitlines(keepends=True)
    lines[1] = lines[1].replace("0", "1", 1) if "0" in lines[1] else lines[1].replace("1", "2", 1)
    path.write_text("".join(lines))


def _damage_metrics_header(out):
    path = out / "metrics.csv"
    path.write_text(path.read_text().replace("eval/success", "eval/succes", 1))


def _damage_checkpoint_deleted(out):
    import shutil

    shutil.rmtree(out / "checkpoint")


def _damage_checkpoint_is_a_file(out):
    import shutil

    shutil.rmtree(out / "checkpoint")
    (out / "checkpoint").write_text("x")


DAMAGE = {
    "metrics truncated mid-row": (_damage_metrics_truncate, "metrics.csv: damaged (the rows"),
    "metrics value edited": (_damage_metrics_value, "metrics.csv: damaged (the rows"),
    "metrics header edited": (_damage_metrics_header, "metrics.csv: damaged (the rows"),
    "metrics deleted": (_damage_metrics_delete, "metrics.csv: missing"),
    "checkpoint byte flipped": (_damage_checkpoint_byte, "its SHA-256 differs"),
    "checkpoint metadata wrong": (_damage_checkpoint_meta, "no valid iteration"),
    "checkpoint metadata binary": (_damage_checkpoint_meta_garbage, "not valid JSON"),
    "checkpoint metadata disagrees with the state": (
        _damage_checkpoint_iteration,
        "its metadata says iteration 100, the state it holds is at iteration 200",
    ),
    "config.json garbage": (_damage_config, "config.json: damaged"),
    "config.json edited": (_damage_config_edited, "env disagree with its identity"),
    "checkpoint deleted": (_damage_checkpoint_deleted, "the checkpoint was deleted"),
    "checkpoint a file": (_damage_checkpoint_is_a_file, "checkpoint: damaged (not a directory)"),
}


@pytest.fixture(scope="module")
def finished_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("finished") / "run"
    _train(out)
    return out


@pytest.mark.parametrize("case", DAMAGE, ids=str)
def test_a_damaged_run_dir_refuses_to_resume_in_one_line(finished_run, tmp_path, capsys, case):
    import shutil

    damage, expected = DAMAGE[case]
    out = tmp_path / "run"
    shutil.copytree(finished_run, out)
    (out / "summary.json").unlink()  # interrupted at its last checkpoint
    damage(out)
    assert cli.main([*TRAIN, "--out", str(out)]) == 2
    err = _one_line_error(capsys)
    assert expected in err and "--restart" in err


def test_restart_after_damage_gives_the_undamaged_results(finished_run, tmp_path):
    import shutil

    out = tmp_path / "run"
    shutil.copytree(finished_run, out)
    (out / "summary.json").unlink()
    _damage_checkpoint_byte(out)
    assert cli.main([*TRAIN, "--out", str(out)]) == 2
    assert cli.main([*TRAIN, "--out", str(out), "--restart"]) == 0
    assert _results(out) == _results(finished_run)


def test_summary_json_is_strictly_valid_json(finished_run):
    json.loads((finished_run / "summary.json").read_text(), parse_constant=pytest.fail)


def test_two_trains_into_one_directory_the_second_is_refused(tmp_path):
    out = tmp_path / "run"
    env = dict(os.environ, JAX_PLATFORMS="cpu")
    slow = [*TRAIN[:-1], "--iterations", "20000", "--eval-period", "100"]
    first = subprocess.Popen(
        [sys.executable, "-m", "pimbot.cli", *slow, "--quiet", "--out", str(out)],
        env=env,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        lock = out.parent / f".{out.name}.lock"
        for _ in range(600):  # the first holds the lock once it has validated its command
            if lock.exists() and (out / "config.json").exists():
                break
            if first.poll() is not None:
                pytest.fail(f"first run ended early: {first.stderr.read()}")
            import time

            time.sleep(0.1)
        second = subprocess.run(
            [sys.executable, "-m", "pimbot.cli", *slow, "--quiet", "--out", str(out)],
            env=env,
            capture_output=True,
            text=True,
        )
        assert second.returncode == 2
        assert "is in use by another pimbot process" in second.stderr
        assert len(second.stderr.strip().splitlines()) == 1
    finally:
        first.kill()
        first.wait()


XSS = "<script>alert(1)</script><img src=x onerror=alert(2)>"


def test_strings_from_run_directories_are_escaped_in_the_html_report(tmp_path):
    grid = tmp_path / "grid.toml"
    grid.write_text(
        'name = "g"\nseeds = 2\niterations = 200\neval_period = 100\n'
        '[[envs]]\nid = "ipd-v0"\nlabel = "ipd"\n[[learners]]\nname = "lio"\n'
        '[[attacks]]\nname = "fake_incentive"\n'
    )
    suite = tmp_path / "suite"
    assert cli.main(["sweep", str(grid), "--out", str(suite), "--quiet"]) == 0
    for config in suite.glob("**/config.json"):
        saved = json.loads(config.read_text())
        saved["identity"]["env_params"]["note"] = XSS
        saved["identity"]["learner_config"]["incentive_updates"] = XSS
        saved["run_config"]["attack_params"] = [["note", XSS]]
        config.write_text(json.dumps(saved))
    index = json.loads((suite / "index.json").read_text())
    index["suite"] += XSS
    for job in index["jobs"]:
        job["error"] = XSS
    (suite / "index.json").write_text(json.dumps(index))
    assert cli.main(["report", str(suite), "--out", str(tmp_path / "report")]) == 0
    html = (tmp_path / "report" / "report.html").read_text()
    assert "&lt;script&gt;" in html  # the strings are shown ...
    assert "<script>alert" not in html and "<img src=x" not in html  # ... never run


def test_reading_a_run_while_it_saves_checkpoints_neither_breaks_it_nor_misreads_it(tmp_path):
    """`pimbot export` or a report may read a run that is training: the reader changes
    nothing, and sees a whole checkpoint at every moment of the writer's saves."""
    import threading

    saved, errors = {}, []

    def writer():
        try:
            for iteration in range(1, 301):
                state = f"state at {iteration}".encode() * 50
                saved[iteration] = state
                store.save_checkpoint(tmp_path, state, iteration)
        except BaseException as error:  # the writer must never fail
            errors.append(error)

    thread = threading.Thread(target=writer)
    thread.start()
    reads = 0
    while thread.is_alive():
        found = store.load_checkpoint(tmp_path)
        if found is not None:
            state, iteration = found
            assert state == saved[iteration]
            reads += 1
    thread.join()
    assert not errors, errors
    assert reads > 0
    assert store.load_checkpoint(tmp_path) == (saved[300], 300)


@pytest.mark.parametrize("killed_before", ["state", "meta.json", "pending removal"])
def test_a_checkpoint_write_killed_between_its_files_resumes(tmp_path, monkeypatch, killed_before):
    """A process killed inside `save_checkpoint` (the sweep ends its workers at any point)
    leaves the old checkpoint or the new one, whole: never a state whose metadata disagree."""
    store.save_checkpoint(tmp_path, b"old state", 100)
    # save_checkpoint's atomic writes: the pending metadata, the state, meta.json
    allowed = {"state": 1, "meta.json": 2, "pending removal": 3}[killed_before]
    written, real_write, real_unlink = [], store.write_atomic, Path.unlink

    def write(path, data):
        written.append(path)
        if len(written) > allowed:
            raise SystemExit("killed")
        real_write(path, data)

    def unlink(self, *args, **kwargs):
        if self.name == store.PENDING_META:
            raise SystemExit("killed")
        return real_unlink(self, *args, **kwargs)

    monkeypatch.setattr(store, "write_atomic", write)
    monkeypatch.setattr(Path, "unlink", unlink)
    with pytest.raises(SystemExit):
        store.save_checkpoint(tmp_path, b"new state", 200)
    monkeypatch.undo()
    expected = (b"old state", 100) if killed_before == "state" else (b"new state", 200)
    before = sorted((p.name, p.read_bytes()) for p in (tmp_path / store.CHECKPOINT_DIR).iterdir())
    assert store.load_checkpoint(tmp_path) == expected  # a reader sees it settled ...
    after = sorted((p.name, p.read_bytes()) for p in (tmp_path / store.CHECKPOINT_DIR).iterdir())
    assert after == before  # ... and changes nothing: the run may be in use
    store.settle_checkpoint(tmp_path)  # the writer, on resuming, completes it
    assert store.load_checkpoint(tmp_path) == expected
    assert not (tmp_path / store.CHECKPOINT_DIR / store.PENDING_META).exists()
    assert (
        store.read_json(tmp_path / store.CHECKPOINT_DIR / store.STATE_META)["iteration"]
        == (expected[1])
    )
