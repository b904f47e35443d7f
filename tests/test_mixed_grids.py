"""Grids that mix learners with different hook points (incompatible cells skipped and
listed), grid files that name their plugins, plugin provenance in config.json and
`train --from`, and the report naming every grid that wrote into its directory."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from pimbot import cli, plugins
from pimbot.analysis import layout, report
from pimbot.analysis.document import Report, Section
from pimbot.suites import grid, sweep
from pimbot.suites.jobs import Skipped

DATA = Path(__file__).parent / "data"

# lio takes every attack and defense here; pg has neither the hook point `emit` (where
# fake_incentive acts) nor `learning_incentives` (incentive_guard's).
MIXED = """
name = "mixed"
seeds = 1
iterations = 2
eval_period = 2
eval_episodes = 1
[[envs]]
id = "ipd-v0"
[[learners]]
name = "lio"
[[learners]]
name = "pg"
[[attacks]]
name = "none"
[[attacks]]
name = "fake_incentive"
label = "fake"
[[defenses]]
[[defenses]]
names = ["incentive_guard"]
label = "guard"
"""
PG_EMIT = "attack fake_incentive acts at the hook point(s) emit, which learner pg does not have"
PG_GUARD = (
    "defense incentive_guard acts at the hook point(s) learning_incentives, which learner pg "
    "does not have"
)


def _write(path: Path, text: str) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def _one_line_error(capsys) -> str:
    err = capsys.readouterr().err
    assert err.startswith("pimbot: error: ") and len(err.strip().splitlines()) == 1, err
    return err.strip()


def test_validate_skips_incompatible_cells_with_their_reasons():
    jobs = grid.expand(grid.parse(tomllib.loads(MIXED), "mixed"))
    skipped = grid.validate(jobs)
    assert skipped == [
        Skipped("mixed/ipd-v0_pg_clean_guard", PG_GUARD),
        Skipped("mixed/ipd-v0_pg_fake", PG_EMIT),
        Skipped("mixed/ipd-v0_pg_fake_guard", PG_EMIT),
    ]
    only_pg = tomllib.loads(MIXED.replace('[[learners]]\nname = "lio"\n', ""))
    only_pg["attacks"] = [{"name": "fake_incentive"}]
    with pytest.raises(grid.GridError, match="every cell is incompatible .2 cells., e.g."):
        grid.validate(grid.expand(grid.parse(only_pg, "pg")))


def test_list_shows_skipped_cells_and_only_selects_among_them(tmp_path, capsys):
    path = _write(tmp_path / "mixed.toml", MIXED)
    out = tmp_path / "out"
    assert cli.main(["sweep", str(path), "--list", "--out", str(out)]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert len(lines) == 8 and sum(" pending " in line for line in lines) == 5
    skipped = [line.split() for line in lines if " skipped " in line]
    assert [(s[0], " ".join(s[3:])) for s in skipped] == [
        ("mixed/ipd-v0_pg_clean_guard", PG_GUARD),
        ("mixed/ipd-v0_pg_fake", PG_EMIT),
        ("mixed/ipd-v0_pg_fake_guard", PG_EMIT),
    ]
    argv = ["sweep", str(path), "--list", "--out", str(out), "--only", "*_pg_*"]
    assert cli.main(argv) == 0  # --only keeps the runnable cell and lists its skipped ones
    lines = capsys.readouterr().out.strip().splitlines()
    assert [line.split()[2] for line in lines] == ["pending", "skipped", "skipped", "skipped"]
    assert cli.main(argv[:-1] + ["*_pg_fake*"]) == 2
    err = _one_line_error(capsys)
    assert "only: every cell matching *_pg_fake* is skipped (2 cells)" in err and PG_EMIT in err
    assert not out.exists(), "--list and a refusal write nothing"


def test_grid_of_incompatible_cells_only_is_one_line_exit_2(tmp_path, capsys):
    text = MIXED.replace('[[learners]]\nname = "lio"\n', "").replace(
        '[[attacks]]\nname = "none"\n', ""
    )
    out = tmp_path / "out"
    assert cli.main(["sweep", str(_write(tmp_path / "g.toml", text)), "--out", str(out)]) == 2
    err = _one_line_error(capsys)
    assert "grid: every cell is incompatible (2 cells), e.g. mixed/ipd-v0_pg_fake: " in err
    assert not out.exists()


def test_index_keeps_every_suite_and_the_skipped_cells_of_each(tmp_path):
    jobs = grid.expand(grid.parse(tomllib.loads(MIXED), "mixed"))
    skipped = grid.validate(jobs)
    run = [j for j in jobs if j.name not in {s.name for s in skipped}]
    statuses = {j.name: "pending" for j in run}
    sweep.start_index(run, statuses, tmp_path, "mixed", skipped)
    other = grid.expand(grid.parse(tomllib.loads(MIXED.replace("mixed", "other")), "other"))
    other_skipped = grid.validate(other)
    sweep.start_index(other[:1], {other[0].name: "pending"}, tmp_path, "other", other_skipped)
    index = sweep.read_index(tmp_path)
    assert index["suites"] == ["mixed", "other"] and index["suite"] == "other"
    assert [s["name"] for s in index["skipped"]] == sorted(
        [s.name for s in skipped] + [s.name for s in other_skipped]
    )
    assert {s["reason"] for s in index["skipped"]} == {PG_EMIT, PG_GUARD}
    # a cell skipped before that runs now is a job, no longer listed as skipped
    now_runs = [*run, *(j for j in jobs if j.name == skipped[0].name)]
    statuses = {j.name: "pending" for j in now_runs}
    sweep.start_index(now_runs, statuses, tmp_path, "mixed", skipped[1:])
    index = sweep.read_index(tmp_path)
    assert skipped[0].name not in {s["name"] for s in index["skipped"]}
    assert index["suites"] == ["other", "mixed"], "the latest suite last"
    assert sweep.suite_names({"suite": "quick"}) == ["quick"]  # an index from before


def test_report_intro_names_every_suite_and_the_skipped_cells():
    index = {
        "suite": "b",
        "suites": ["a", "b"],
        "jobs": [],
        "skipped": [{"name": f"a/cell{k}", "reason": "why"} for k in range(14)],
    }
    text = "\n".join(layout.intro(Report(index, Section("Provenance"), [], [])))
    assert text.startswith("Suites: a, b — 0/0 jobs finished")
    assert "Skipped cells (14, not run:" in text and "a/cell0 (why); a/cell1 (why)" in text
    assert "a/cell11 (why); and 2 more." in text and "a/cell12" not in text
    one = layout.intro(Report({"suite": "a", "jobs": []}, Section("Provenance"), [], []))
    assert one[0].startswith("Suite: a — ") and not any("Skipped" in p for p in one)
    # Jobs a stopped sweep finished without recording their time are counted as such.
    jobs = [{"status": "finished", "wall_s": 60.0}, {"status": "finished"}, {"status": "pending"}]
    timed = layout.intro(Report({"suite": "a", "jobs": jobs}, Section("Provenance"), [], []))[0]
    assert "2/3 jobs finished (1 timed by `pimbot sweep`, 1.0 min of job wall time" in timed
    assert "summed; 1 found finished in the directory, untimed)" in timed
    everyone = [{"status": "finished", "wall_s": 60.0}]
    alone = layout.intro(Report({"suite": "a", "jobs": everyone}, Section("Provenance"), [], []))
    assert "1.0 min of job wall time summed). Generated" in alone[0]


# --- a grid that names its plugins; provenance; --from ---------------------------------

PLUGIN = (DATA / "coordination_plugin.py").read_text().replace("my_env-v0", "{env_id}")


def _plugin_grid(root: Path, name: str, env_id: str) -> Path:
    """A grid in `root` whose env comes from the plugin plugins/<env_id>.py it names."""
    _write(root / "plugins" / f"{env_id}.py", PLUGIN.format(env_id=env_id))
    return _write(
        root / f"{name}.toml",
        f'name = "{name}"\nplugins = ["plugins/{env_id}.py"]\nseeds = 1\niterations = 2\n'
        f'eval_period = 2\neval_episodes = 1\n[[envs]]\nid = "{env_id}"\nlabel = "coord"\n'
        '[[learners]]\nname = "pg"\n[[attacks]]\nname = "none"\n[[attacks]]\n'
        'name = "fake_incentive"\nlabel = "fake"\n',
    )


def test_grid_plugins_field_is_checked_in_one_line(tmp_path, capsys):
    path = _plugin_grid(tmp_path, "g", "mixgrid_listed-v0")
    assert cli.main(["sweep", str(path), "--list", "--out", str(tmp_path / "o")]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert [line.split()[:3] for line in lines] == [
        ["g/coord_pg_clean", "train", "pending"],
        ["g/coord_pg_fake", "train", "skipped"],
    ]
    for value, expected in (
        ('["plugins/nope.py"]', f"plugins[0]: no such file {tmp_path / 'plugins' / 'nope.py'}"),
        ("3", "plugins: must be a list of .py paths or module names, got 3"),
    ):
        text = path.read_text().replace('["plugins/mixgrid_listed-v0.py"]', value)
        bad = _write(tmp_path / "bad.toml", text)
        assert cli.main(["sweep", str(bad), "--list", "--out", str(tmp_path / "o")]) == 2
        assert expected in _one_line_error(capsys)


def test_missing_names_a_recorded_plugin_not_loaded_and_how_its_file_stands(tmp_path):
    file = _write(tmp_path / "p.py", "X = 1\n")
    record = {"plugin": str(file), "file": str(file), "sha256": plugins.file_sha256(file)}
    assert plugins.missing([record]) == [(str(file), f"sha256 {record['sha256'][:12]}…, unchanged")]
    file.write_text("X = 2\n")
    ((name, state),) = plugins.missing([record])
    assert name == str(file) and state == (
        f"the file has changed since: sha256 {record['sha256'][:12]}… then, "
        f"{plugins.file_sha256(file)[:12]}… now"
    )
    file.unlink()
    assert plugins.missing([record]) == [(str(file), "the file no longer exists")]
    loaded = plugins.provenance()
    assert plugins.missing(loaded) == [], "every plugin this process loaded is loaded"


@pytest.fixture(scope="module")
def swept(tmp_path_factory) -> Path:
    """Two grids of different names (one naming its plugin, one cell skipped) swept into
    one directory, then reported."""
    root = tmp_path_factory.mktemp("mixed")
    out = root / "out"
    for name in ("first", "second"):
        path = _plugin_grid(root, name, "mixgrid_swept-v0")
        argv = ["sweep", str(path), "--out", str(out), "--workers", "1"]
        assert cli.main(argv + ["--devices-per-job", "1", "--quiet"]) == 0
    report.write_report(out, out)
    return out


def test_sweeps_record_skipped_cells_plugins_and_every_grid_in_the_report(swept):
    index = sweep.read_index(swept)
    assert index["suites"] == ["first", "second"]
    assert [j["name"] for j in index["jobs"]] == ["first/coord_pg_clean", "second/coord_pg_clean"]
    assert {j["status"] for j in index["jobs"]} == {"finished"}
    reason = "attack fake_incentive acts at the hook point(s) emit, which learner pg does not have"
    assert index["skipped"] == [
        {"name": f"{g}/coord_pg_fake", "reason": reason} for g in ("first", "second")
    ]
    plugin = (swept.parent / "plugins" / "mixgrid_swept-v0.py").resolve()
    config = json.loads((swept / "first/coord_pg_clean/config.json").read_text())
    assert {"plugin": str(plugin), "file": str(plugin), "sha256": plugins.file_sha256(plugin)} in (
        config["plugins"]
    )
    markdown = (swept / report.MARKDOWN).read_text()
    assert "Suites: first, second — 2/2 jobs finished" in markdown
    assert (
        "Skipped cells (2, not run:" in markdown and f"first/coord_pg_fake ({reason})" in markdown
    )
    assert "suites 'first', 'second'" in markdown and "mixgrid_swept-v0.py (sha256 " in markdown
    assert "Skipped cells (2" in (swept / report.HTML).read_text()


def _pimbot(*argv: str) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k != plugins.ENV_VAR}
    command = [sys.executable, "-m", "pimbot.cli", *argv]
    return subprocess.run(command, capture_output=True, text=True, env=env, timeout=300)


def test_train_from_names_the_plugin_file_it_lacks(swept, tmp_path):
    run_dir = swept / "first" / "coord_pg_clean"
    plugin = (swept.parent / "plugins" / "mixgrid_swept-v0.py").resolve()
    digest = plugins.file_sha256(plugin)
    done = _pimbot("train", "--from", str(run_dir), "--out", str(tmp_path / "again"))
    assert done.returncode == 2 and len(done.stderr.strip().splitlines()) == 1, done.stderr
    assert done.stderr.strip() == (
        f"pimbot: error: from: {run_dir}/config.json: the run was made with plugin {plugin} "
        f"(sha256 {digest[:12]}…, unchanged), which is not loaded; add --plugin {plugin}"
    )
    changed = _write(tmp_path / "plugins" / plugin.name, plugin.read_text() + "# edited\n")
    moved = tmp_path / "run"
    moved.mkdir()
    config = json.loads((run_dir / "config.json").read_text())
    config["plugins"] = [dict(r, file=str(changed), plugin=str(changed)) for r in config["plugins"]]
    (moved / "config.json").write_text(json.dumps(config))
    done = _pimbot("train", "--from", str(moved), "--out", str(tmp_path / "again"))
    assert done.returncode == 2 and len(done.stderr.strip().splitlines()) == 1, done.stderr
    now = plugins.file_sha256(changed)
    assert f"(the file has changed since: sha256 {digest[:12]}… then, {now[:12]}… now)" in (
        done.stderr
    )
    assert not (tmp_path / "again").exists()
