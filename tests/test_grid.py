"""User grids (`pimbot sweep GRID.toml`) and the paper suite built from the same expansion."""

from __future__ import annotations

import dataclasses
import json
import tomllib
from pathlib import Path

import pytest

from pimbot import cli
from pimbot.suites import grid, presets, sweep
from pimbot.training.config import RunConfig

DATA = Path(__file__).parent / "data"
PLUGIN_FILE = DATA / "coordination_plugin.py"
EXAMPLE = Path(__file__).parents[1] / "docs" / "examples" / "grid.toml"

# 2 envs (one from a plugin) × 2 attacks, tiny budget; the attacks differ only in numbers
# (traced data), so each env's second run reuses the first one's compiled program.
TINY_GRID = """
name = "tiny"
seeds = 1
iterations = 20
eval_period = 10
eval_episodes = 2

[[envs]]
id = "my_env-v0"
label = "coord"

[[envs]]
id = "ipd-v0"

[[learners]]
name = "lio"

[[attacks]]
name = "fake_incentive"
label = "fake"

[[attacks]]
name = "fake_incentive"
params = { amount = 5.0 }
label = "fake_small"
"""


ATTACKS = ("fake", "fake_small")


def _as_json(job) -> dict:
    spec = json.loads(json.dumps(dataclasses.asdict(job.spec), default=str))
    return {
        "name": job.name,
        "kind": job.kind,
        "claims": list(job.claims),
        "after": list(job.after),
        "spec": spec,
    }


@pytest.mark.parametrize("budget", ["quick", "full"])
def test_paper_suite_is_unchanged_by_the_grid_expansion(budget):
    golden = json.loads((DATA / "paper_suite.json").read_text())[budget]
    jobs = presets.suite(quick=budget == "quick")
    assert [j.name for j in jobs] == [g["name"] for g in golden]
    for job, expected in zip(jobs, golden, strict=True):
        now = _as_json(job)
        spec = now.pop("spec")
        assert now == {k: v for k, v in expected.items() if k != "spec"}
        # fields added to a spec since the golden file was written must keep their defaults
        defaults = {f.name: f.default for f in dataclasses.fields(job.spec)}
        for key, value in spec.items():
            if key in expected["spec"]:
                assert value == expected["spec"][key], (job.name, key)
            else:
                assert getattr(job.spec, key) == defaults[key], (job.name, key)


def test_expansion_names_and_configs():
    data = tomllib.loads(
        """
        seeds = 2
        iterations = 200
        [[envs]]
        id = "escape_room-v0"
        params = { n_agents = 4, min_at_lever = 2 }
        [[envs]]
        id = "ipd-v0"
        label = "ipd"
        iterations = 100
        eval_period = 50
        [[learners]]
        name = "lio"
        hparams = { lr_incentive = 0.01 }
        label = "lio"
        [[attacks]]
        name = "none"
        [[attacks]]
        name = "admo"
        params = { mode = "disrupt" }
        [[defenses]]
        [[defenses]]
        names = ["incentive_guard"]
        """
    )
    jobs = grid.expand(grid.parse(data, default_name="my grid"))
    assert [j.name for j in jobs] == [
        f"my-grid/{env}_lio_{attack}{defense}"
        for env in ("escape_room-v0_min_at_lever=2_n_agents=4", "ipd")
        for attack in ("clean", "admo_mode=disrupt")
        for defense in ("", "_incentive_guard")
    ]
    assert jobs[3].spec == RunConfig(
        env_id="escape_room-v0",
        env_params=(("min_at_lever", 2), ("n_agents", 4)),
        learner="lio",
        hparams=(("lr_incentive", 0.01),),
        seeds=2,
        iterations=200,
        attack="admo",
        attack_params=(("mode", "disrupt"),),
        defenses=(("incentive_guard", ()),),
    )
    assert (jobs[4].spec.iterations, jobs[4].spec.eval_period, jobs[4].spec.attack) == (
        100,
        50,
        None,
    )
    assert {j.group for j in jobs} == {"my-grid"} and {j.kind for j in jobs} == {"train"}
    grid.validate(jobs)


def test_example_grid_is_valid_and_lists_its_plan(tmp_path, capsys):
    out = tmp_path / "example"
    assert cli.main(["sweep", str(EXAMPLE), "--list", "--out", str(out)]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert len(lines) == 12 and all(" pending " in line for line in lines)
    assert lines[-1].startswith("example/er42_lio_admo_disrupt_guard ")
    assert not out.exists(), "--list writes nothing"


def test_grid_sweep_over_a_plugin_env_runs_and_resumes(tmp_path, capsys):
    path = tmp_path / "tiny.toml"
    path.write_text(TINY_GRID)
    out = tmp_path / "sweep"
    argv = ["sweep", str(path), "--out", str(out), "--plugin", str(PLUGIN_FILE)]
    argv += ["--workers", "1", "--devices-per-job", "1", "--quiet"]  # one spawned worker
    assert cli.main(argv) == 0, capsys.readouterr().err
    assert "4/4 jobs finished" in capsys.readouterr().out
    index = sweep.read_index(out)
    names = [f"tiny/{env}_lio_{attack}" for env in ("coord", "ipd-v0") for attack in ATTACKS]
    assert [j["name"] for j in index["jobs"]] == sorted(names)
    assert index["suite"] == "tiny" and {j["status"] for j in index["jobs"]} == {"finished"}
    assert all((out / j["name"] / "summary.json").exists() for j in index["jobs"])

    assert cli.main(argv) == 0  # a rerun finds everything finished
    assert "all 4 selected jobs have already finished; nothing to do" in capsys.readouterr().out

    assert cli.main(argv[:4] + ["--list", "--plugin", str(PLUGIN_FILE)]) == 0
    assert capsys.readouterr().out.count(" finished ") == 4


GOOD = {
    "seeds": "seeds = 1",
    "iterations": "iterations = 20\neval_period = 10",
    "envs": "[[envs]]\nid = 'ipd-v0'",
    "learners": "[[learners]]\nname = 'lio'",
}
"""A valid grid, by part; each bad case replaces (or, with "", drops) some parts."""
BAD_GRIDS = [
    ({"extra": "colour = 1"}, "colour: not a field here; allowed: name, seeds"),
    ({"seeds": ""}, "seeds: missing"),
    ({"seeds": "seeds = 0"}, "seeds: must be an integer ≥ 1, got 0"),
    ({"envs": "envs = []"}, "envs: empty; add at least one [[envs]] entry"),
    ({"envs": "envs = 3"}, "envs: must be a list of [[envs]] tables"),
    ({"envs": "[[envs]]\nid = 'nope-v0'"}, "envs[0].id: env_id: unknown environment 'nope-v0'"),
    ({"envs": "[[envs]]\nid = 'ipd-v0'\nparams = { colour = 1 }"}, "envs[0].params: colour"),
    ({"envs": "[[envs]]\nid = 'ipd-v0'\nparams = { n_players = 1 }"}, "n_players"),
    ({"envs": "[[envs]]\nid = 'ipd-v0'\nsize = 1"}, "envs[0].size: not a field here"),
    ({"learners": "[[learners]]\nname = 'dqn'"}, "learners[0].name: learner: unknown learner"),
    ({"learners": "[[learners]]\nname = 'lio'\nhparams = { momentum = 1 }"}, "momentum: not a"),
    ({"attacks": "[[attacks]]\nname = 'nope'"}, "attacks[0].name: attack: unknown attack 'nope'"),
    (
        {"attacks": "[[attacks]]\nname = 'admo'\nparams = { mode = 3 }"},
        "mode: unknown ADMO mode 3; allowed: stealthy, disrupt",
    ),
    ({"attacks": "[[attacks]]\nname = 'admo'\nparams = { colour = 1 }"}, "colour: not a param"),
    ({"defenses": "[[defenses]]\nnames = ['nope']"}, "defenses[0].names: defenses: unknown"),
    ({"defenses": "[[defenses]]\nparams = { health_monitor = {} }"}, "not one of this entry's"),
    ({"attacks": "[[attacks]]\nname = 'none'\n[[attacks]]\nname = 'none'"}, "two jobs would"),
    ({"iterations": "iterations = 25\neval_period = 10"}, "iterations: must be a multiple of"),
    ({"attacks": "[[attacks]]\nname = 'admo'\nparams = { adversary = 5 }"}, "adversary: must"),
]


@pytest.mark.parametrize(("changes", "expected"), BAD_GRIDS)
def test_bad_grid_field_is_one_line_exit_2(tmp_path, capsys, changes, expected):
    parts = GOOD | changes
    top = [v for v in parts.values() if v and not v.startswith("[[")]
    tables = [v for v in parts.values() if v.startswith("[[")]
    path = tmp_path / "bad.toml"
    path.write_text("\n".join(top + tables) + "\n")  # top-level keys before the tables
    out = tmp_path / "out"
    assert cli.main(["sweep", str(path), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("pimbot: error: ") and len(err.strip().splitlines()) == 1, err
    assert expected in err, err
    assert not out.exists()


def test_unreadable_grid_files_are_one_line(tmp_path, capsys):
    (tmp_path / "broken.toml").write_text("seeds = \n")
    for name, expected in (("missing.toml", "grid: cannot read"), ("broken.toml", "not valid")):
        assert cli.main(["sweep", str(tmp_path / name), "--out", str(tmp_path / "o")]) == 2
        err = capsys.readouterr().err
        assert expected in err and len(err.strip().splitlines()) == 1, err


def test_the_quick_suite_runs_the_fewest_seeds_at_which_its_tests_can_decide():
    """Every quick job runs `QUICK_SEEDS` seeds: with all of them agreeing, a one-sided
    sign-flip test reaches p < 0.05 there and not with one seed fewer, and the report's
    intervals are BCa CIs from there on."""
    import numpy as np

    from pimbot.statistics import MIN_SEEDS_FOR_CI, sign_p_value

    quick = presets.QUICK_SEEDS
    assert sign_p_value(np.ones(quick)) < 0.05 <= sign_p_value(np.ones(quick - 1))
    assert quick >= MIN_SEEDS_FOR_CI
    trained = [j for j in presets.suite(quick=True) if j.kind == "train"]
    assert {j.spec.seeds for j in trained} == {quick}
