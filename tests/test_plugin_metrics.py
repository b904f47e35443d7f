"""Every metric a plugin adds is visible: an attack's numbers of its own state
(`Attack.metrics`) reach metrics.csv as `attack/<name>/…` at every evaluation, even for an
attack without a learning step; `pimbot table --metric` and `pimbot plot --metric` show any
metrics.csv column (an unknown one is one line listing the columns, exit 2, nothing
written); the report's sweep section has a table of them.

The plugin is a one-file attack written to tmp_path and loaded with `--plugin`, as a user
would: it counts the iterations it has observed, reports the count, a per-agent number and
a "not yet" NaN that never turns finite.
"""

from __future__ import annotations

import csv
import math
import textwrap
from pathlib import Path

import pytest

from pimbot import attacks, cli, plugins
from pimbot.analysis import plots, report
from pimbot.attacks import strategy_union
from pimbot.suites import sweep
from pimbot.training import store

NAME = "metrics_call_counter"
PREFIX = f"attack/{NAME}/"
CALLS = f"{PREFIX}calls"
ITERATIONS, PERIOD = 20, 10
TINY = ["--seeds", "2", "--iterations", str(ITERATIONS), "--eval-period", str(PERIOD)]
TINY += ["--eval-episodes", "2", "--learner", "pg", "--quiet"]

HEADER = """\
from typing import ClassVar

import jax.numpy as jnp
from flax import struct

from pimbot.attacks import Attack, register
"""

COUNTER = f"""
@register
@struct.dataclass
class CallCounter(Attack):
    name: ClassVar[str] = "{NAME}"
    hooks: ClassVar[tuple[str, ...]] = ("observe",)
    threshold: float = 2.0

    def init_state(self, key, num_agents, adversary):
        del key, adversary
        return {{
            "calls": jnp.zeros((), jnp.int32),
            "seen": jnp.zeros((num_agents,), jnp.float32),
            "woke_at": jnp.full((), jnp.nan, jnp.float32),
        }}

    def observe(self, state, key, outcome):
        del key
        calls = state["calls"] + 1
        waking = jnp.isnan(state["woke_at"]) & (outcome.success > self.threshold)
        woke_at = jnp.where(waking, outcome.iteration.astype(jnp.float32), state["woke_at"])
        seen = state["seen"] + self.is_adversary(state["seen"].shape[0])
        return {{"calls": calls, "seen": seen, "woke_at": woke_at}}

    def metrics(self, state):
        return {{"calls": state["calls"], "seen": state["seen"], "woke_at": state["woke_at"]}}
"""


def write(directory: Path, name: str, body: str) -> Path:
    path = directory / f"{name}.py"
    path.write_text(HEADER + textwrap.dedent(body))
    return path


@pytest.fixture(scope="module")
def sweep_dir(tmp_path_factory) -> Path:
    """A sweep directory with one run of the counting attack (group `mygrid`)."""
    root = tmp_path_factory.mktemp("plugin_metrics")
    plugin = write(root, "metrics_counter_plugin", COUNTER)
    run = root / "mygrid" / "er21_counter"
    argv = ["train", "escape_room-v0", "--plugin", str(plugin), "--attack", NAME, *TINY]
    assert cli.main([*argv, "--out", str(run)]) == 0
    job = {"name": "mygrid/er21_counter", "group": "mygrid", "kind": "train", "claims": []}
    sweep.write_index(root, {"suite": "mygrid", "jobs": [{**job, "status": "finished"}]})
    return root


@pytest.fixture(scope="module")
def run_dir(sweep_dir) -> Path:
    return sweep_dir / "mygrid" / "er21_counter"


def rows(run_dir: Path) -> list[dict[str, str]]:
    with open(run_dir / store.METRICS, newline="") as f:
        return list(csv.DictReader(f))


def test_state_metrics_are_written_at_every_evaluation(run_dir):
    found = rows(run_dir)
    assert len(found) == 2 * ITERATIONS // PERIOD  # seeds × evaluations
    for row in found:
        # observe ran once per iteration: the count is the iteration of the evaluation
        assert float(row[CALLS]) == float(row["iteration"])
        assert float(row[f"{PREFIX}seen/agent_0"]) == float(row["iteration"])  # the adversary
        assert float(row[f"{PREFIX}seen/agent_1"]) == 0.0
        assert math.isnan(float(row[f"{PREFIX}woke_at"]))  # a sentinel, not a divergence


def test_table_shows_any_column(run_dir, capsys):
    assert cli.main(["table", str(run_dir), "--metric", CALLS, "--metric", "eval/steps"]) == 0
    out = capsys.readouterr().out
    assert f"final {CALLS} [interval]" in out and "final eval/steps [interval]" in out
    row = next(line for line in out.splitlines() if line.startswith("| pg "))
    # mean of the evaluations at iterations 10 and 20, the same in both seeds
    assert row.split("|")[-3].strip() == "15.000 (range 15.000 … 15.000)"
    assert cli.main(["table", str(run_dir), "--metric", f"{PREFIX}woke_at"]) == 0
    assert capsys.readouterr().out.splitlines()[2].endswith("| – |")  # never finite


def test_plot_draws_any_column(run_dir, tmp_path, capsys, monkeypatch):
    drawn = {}
    save = plots.save

    def spy(fig, path, **options):  # what each panel shows, then the file as usual
        drawn.update({ax.get_ylabel(): list(ax.lines[0].get_ydata()) for ax in fig.axes})
        save(fig, path, **options)

    monkeypatch.setattr(plots, "save", spy)
    out = tmp_path / "calls.png"
    argv = ["plot", str(run_dir), "--metric", CALLS, "--metric", f"{PREFIX}seen/agent_0"]
    assert cli.main([*argv, "--out", str(out)]) == 0
    assert out.stat().st_size > 0 and f"wrote {out}" in capsys.readouterr().out
    assert drawn == {CALLS: [10.0, 20.0], f"{PREFIX}seen/agent_0": [10.0, 20.0]}


@pytest.mark.parametrize("command", ["table", "plot"])
def test_an_unknown_metric_is_one_line_listing_the_columns(run_dir, tmp_path, capsys, command):
    out = tmp_path / "figure.png"
    argv = [command, str(run_dir), "--metric", "attack/calls"]
    argv += ["--out", str(out)] if command == "plot" else []
    assert cli.main(argv) == 2
    captured = capsys.readouterr()
    line = captured.err.strip()
    assert len(line.splitlines()) == 1 and not captured.out, captured
    assert line.startswith("pimbot: error: metric: no column 'attack/calls' in the runs' ")
    assert "; available: " in line and "eval/success" in line
    assert CALLS in line and f"{PREFIX}seen/agent_0…1" in line  # per-agent columns once
    assert not out.exists()


def test_the_sweep_section_shows_the_attacks_metrics(sweep_dir, tmp_path):
    out = report.write_report(sweep_dir, tmp_path / "report")
    generic = (out / report.MARKDOWN).read_text().split("## Other training runs", 1)[1]
    table = generic.split("mygrid: metrics the runs' attacks, defenses and learners logged", 1)
    assert len(table) == 2, generic
    header = next(line for line in table[1].splitlines() if line.startswith("| env"))
    cells = [c.strip() for c in header.strip("|").split("|")]
    assert cells[4:] == ["written by", "metric", "final [interval]", "run"]
    rows = {
        cells[5]: cells
        for line in table[1].splitlines()
        if "| er21_counter |" in line
        for cells in [[c.strip() for c in line.strip("|").split("|")]]
    }
    # every column the attack wrote, per-agent ones included, with what wrote it
    assert set(rows) == {
        CALLS,
        f"{PREFIX}woke_at",
        f"{PREFIX}seen/agent_0",
        f"{PREFIX}seen/agent_1",
    }
    assert rows[CALLS][4:] == [
        f"attack {NAME}",
        CALLS,
        "15.000 (range 15.000 … 15.000)",
        "er21_counter",
    ]
    assert rows[f"{PREFIX}woke_at"][6] == "–"  # never finite
    assert (out / report.TABLES / "mygrid_own_metrics.csv").exists()


def test_own_metrics_name_their_writer():
    """The built-in defenses log `defense/guard_*` without their name: the row names every
    defense of the run; a column under a defense's name names that one."""
    from types import SimpleNamespace

    from pimbot.analysis.sections.generic import writer

    defenses = [["incentive_guard", []], ["health_monitor", []]]
    run = SimpleNamespace(
        attack="admo", learner="mine", config={"run_config": {"defenses": defenses}}
    )
    assert writer(run, "defense/guard_clipped") == "defense incentive_guard+health_monitor"
    assert writer(run, "defense/health_monitor/alarms") == "defense health_monitor"
    assert writer(run, "learner/mine/given_per_step/agent_0") == "learner mine"
    assert writer(run, "attack/admo/c_1") == "attack admo"


# --- the contract: checked before anything is written; not folded into shared programs -----


def test_metrics_of_a_wrong_shape_are_one_line_before_anything_is_written(tmp_path, capsys):
    body = COUNTER.replace(NAME, "metrics_wrong_shape").replace("CallCounter", "WrongShape")
    body = body.replace('"seen": state["seen"],', '"seen": jnp.ones((3, 3)),')
    path = write(tmp_path, "metrics_wrong_shape", body)
    run = tmp_path / "run"
    argv = ["train", "escape_room-v0", "--plugin", str(path), "--attack", "metrics_wrong_shape"]
    assert cli.main([*argv, *TINY, "--out", str(run)]) == 2
    line = capsys.readouterr().err.strip()
    metrics_line = next(
        i for i, t in enumerate(path.read_text().splitlines(), 1) if "def metrics" in t
    )
    assert line == (
        f"pimbot: error: {path}:{metrics_line}: attack metrics_wrong_shape: metrics returned "
        "metrics['seen'] float32[3, 3]; expected float/int/uint/bool[] or [2]"
    )
    assert not run.exists()


def test_a_misspelt_metrics_method_is_refused_when_it_registers(tmp_path, capsys):
    body = COUNTER.replace(NAME, "metrics_misspelt").replace("def metrics(", "def metric(")
    path = write(tmp_path, "metrics_misspelt", body.replace("CallCounter", "Misspelt"))
    argv = ["train", "escape_room-v0", "--plugin", str(path), "--attack", "metrics_misspelt"]
    assert cli.main([*argv, *TINY, "--out", str(tmp_path / "run")]) == 2
    line = capsys.readouterr().err.strip()
    assert (
        "method metric() is no hook point and would never be called: did you mean metrics()?"
        in line
    )
    assert "metrics_misspelt" not in attacks.registered()


def test_an_attack_with_metrics_gets_its_own_program(tmp_path):
    """A strategy attack (no state, no learning step) that reports metrics is not folded into
    `Strategies`, whose members would differ in their metrics' names."""
    body = """
    @register
    @struct.dataclass
    class Frozen(Attack):
        name: ClassVar[str] = "metrics_frozen"
        hooks: ClassVar[tuple[str, ...]] = ("policy_sign",)

        def policy_sign(self, state, num_agents):
            return jnp.where(self.is_adversary(num_agents), 0.0, 1.0)
    """
    frozen = plugins.load(str(write(tmp_path, "metrics_frozen", body))).Frozen()
    assert strategy_union.shareable(frozen)
    reporting = body.replace("Frozen", "Reporting").replace("metrics_frozen", "metrics_reporting")
    reporting += """
        def metrics(self, state):
            return {"frozen_agents": jnp.ones(())}
    """
    module = plugins.load(str(write(tmp_path, "metrics_reporting", reporting)))
    assert not strategy_union.shareable(module.Reporting())
