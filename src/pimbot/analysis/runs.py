"""The runs of a suite directory, loaded once: one `RunRecord` per training run (its
config.json, its summary recomputed from metrics.csv's rows (`training.summary.summarize_rows`), and
metrics.csv itself read into `Curves`) and the summaries of the robot and profile jobs, in
one `RunTable`.

Every report section and figure reads this table; none opens a run's files again.
Labels are derived from each run's config.json, never looked up in a list: the
condition is the attack's name and the parameters the run set explicitly (``admo_disrupt``,
``fake_incentive(amount=10.0)``), the env is a short form of its id with its
size parameters (``ER(4,2)``, ``IPD(2)``, ``SH(3)``), and defenses are their
names joined by ``+``. So an attack, env or defense the report has never heard
of gets its own label and colour instead of an error. The paper's order of
conditions is kept as a preference for sorting only: other names sort after.
"""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

from pimbot.analysis.curves import Curves, curves_of
from pimbot.attacks import CONDITION_ORDER
from pimbot.training import store
from pimbot.training.summary import summarize_rows

CLEAN = "clean"
NO_DEFENSE = "none"
PIMBOT = "pimbot"
ORIGINAL_CODE = "original code"
SIZE_PARAMS = ("n_agents", "n_players", "min_at_lever")
"""Env parameters written in the env label, in this order: ER(n_agents,min_at_lever)."""
PROFILE_RUN = "profile/er21_paired"
"""The paired profile's job directory (its summary.json: `RunTable.profile`)."""
ROBOT_SUMMARIES = "robot/*/summary.json"
"""The robot evaluations' summaries (`RunTable.robot`)."""


@dataclasses.dataclass(frozen=True)
class RunRecord:
    """One finished training run of the suite, with the labels the report groups it by."""

    name: str
    """The job name: the run directory relative to the suite directory (`<group>/<setting>`)."""
    path: Path
    config: dict[str, Any]
    """config.json as written by the runner."""
    summary: dict[str, Any]
    """summary.json, its final metrics and convergence recomputed from metrics.csv."""
    condition: str
    env: str
    learner: str
    hparams: str
    """The learner hyperparameters the run overrode, "k=v, …" ("" for the defaults)."""
    defenses: str
    seeds: int
    iterations: int
    curves: Curves = dataclasses.field(compare=False, repr=False)
    """metrics.csv, read once: every column per seed."""

    @property
    def group(self) -> str:
        return self.name.split("/", 1)[0]

    @property
    def setting(self) -> str:
        return self.name.rsplit("/", 1)[-1]

    @property
    def identity(self) -> dict[str, Any]:
        return self.config["identity"]

    @property
    def env_key(self) -> tuple:
        """The environment itself (id and every parameter), for matching runs across groups."""
        return self.identity["env_id"], tuple(sorted(self.identity["env_params"].items()))

    @property
    def cell(self) -> tuple:
        """Runs of one cell differ only in the attack: env, learner, hparams and defenses."""
        return self.env_key, self.learner, self.hparams, self.defenses

    @property
    def num_agents(self) -> int:
        return int(self.config["env"]["num_agents"])

    @property
    def adversary(self) -> int:
        return int(self.identity["attack_params"].get("adversary", 0)) if self.attack else 0

    @property
    def attack(self) -> str | None:
        return self.identity["attack"]

    @property
    def attack_inferred(self) -> bool:
        """An original-code log whose attack its name does not record, only inferred from
        elsewhere (config.json "original" "attack_inferred"): shown beside pimbot's run,
        never the ground of a cause (`RunTable.original_for`)."""
        return bool(self.config.get("original", {}).get("attack_inferred", False))

    @property
    def source(self) -> str:
        """ "pimbot", or "original code" for a run converted from the original PIMbot
        repository's logs (config.json "source")."""
        return str(self.config.get("source", PIMBOT))

    def per_seed(self, column: str) -> np.ndarray:
        """Final value of `column` per seed (mean of the last evaluation points); [] if absent."""
        entry = self.summary["final"].get(column)
        return np.array(entry["per_seed"]) if entry else np.array([])


@dataclasses.dataclass(frozen=True)
class RunTable:
    """Every finished run of a suite, and one colour per condition."""

    records: tuple[RunRecord, ...]
    original: tuple[RunRecord, ...] = ()
    """Runs converted from the original code's logs (source "original code"): the claims'
    original-code column, never a section's own rows."""
    robot: tuple[dict[str, Any], ...] = ()
    """The robot evaluations' summary.json files, in path order."""
    profile: dict[str, Any] | None = None
    """The paired profile's summary.json (None: no finished profile)."""

    def original_for(
        self, run: RunRecord, horizon: int | None = None, recorded: bool = False
    ) -> RunRecord | None:
        """The original code's run at `run`'s settings: the same env (id and every
        parameter), learner and learner configuration, attack and resolved attack
        parameters. Nothing else stands in for it: a log of the same attack under other
        parameters is no evidence about this run (`originals_elsewhere` names those). Of
        several log directories, every one that reaches `horizon` (where none does, or
        without one: the longest's length), pooled (`pooled`: no directory is preferred to
        another at the same settings; comparisons are made at the common horizon).
        `recorded`: only logs whose name records their attack (not `attack_inferred`),
        the logs a cause may rest on: a log whose settings are inferred is not shown to
        be at `run`'s settings."""
        matches = [r for r in self.originals_for(run) if not (recorded and r.attack_inferred)]
        if not matches:
            return None
        longest = max(r.iterations for r in matches)
        cut = longest if horizon is None else min(horizon, longest)
        return pooled(sorted((r for r in matches if r.iterations >= cut), key=lambda r: r.name))

    def originals_for(self, run: RunRecord) -> list[RunRecord]:
        """Every original-code run at `run`'s exact settings (`same_settings`)."""
        return [r for r in self.original if same_settings(r, run)]

    def originals_elsewhere(self, run: RunRecord) -> list[RunRecord]:
        """The original code's runs of `run`'s env, learner and attack at other settings
        (attack parameters or learner configuration): never compared with `run`, only
        named (`settings_difference`)."""
        return [
            r
            for r in self.original
            if r.env_key == run.env_key
            and r.learner == run.learner
            and r.attack == run.attack
            and not same_settings(r, run)
        ]

    def group(self, name: str) -> list[RunRecord]:
        return [r for r in self.records if r.group == name]

    @property
    def groups(self) -> list[str]:
        return sorted({r.group for r in self.records})

    @property
    def colors(self) -> dict[str, str]:
        """The colour of every condition of the table (`condition_colors`), clean first."""
        return condition_colors(r.condition for r in self.records)

    def clean_for(self, record: RunRecord) -> RunRecord | None:
        """The clean run of `record`'s group and cell (same env, learner, hparams, defenses)."""
        return next(
            (
                r
                for r in self.records
                if r.condition == CLEAN and r.group == record.group and r.cell == record.cell
            ),
            None,
        )


def same_settings(a: RunRecord, b: RunRecord) -> bool:
    """Whether two runs share env (id and parameters), learner, learner configuration,
    attack and resolved attack parameters: what makes one evidence about the other."""
    keys = ("learner_config", "attack", "attack_params")
    return (
        a.env_key == b.env_key
        and a.learner == b.learner
        and all(a.identity.get(k) == b.identity.get(k) for k in keys)
    )


def settings_difference(original: RunRecord, ours: RunRecord) -> str:
    """ "amount 10 in the original code's logs, 50 here": every attack parameter and
    learner setting in which two runs of one attack differ."""
    parts = []
    for key in ("attack_params", "learner_config"):
        a, b = original.identity.get(key) or {}, ours.identity.get(key) or {}
        for name in sorted(set(a) | set(b)):
            if a.get(name) != b.get(name):
                parts.append(
                    f"{name} {_shown(a.get(name))} in the original code's logs, "
                    f"{_shown(b.get(name))} here"
                )
    return "; ".join(parts) or "other settings"


def _shown(value: Any) -> str:
    return "unset" if value is None else _value(value)


# --- labels ----------------------------------------------------------------------------


def _value(value: Any) -> str:
    return f"{value:g}" if isinstance(value, float) else str(value)


def env_label(env_id: str, params: dict[str, Any]) -> str:
    """``ER(4,2)`` for escape_room-v0 with 4 agents, 2 at the lever; ``IPD(2)``; ``SH(3)``.

    The short name is the id's initials (the whole word for a one-word id); the size
    parameters follow. An env with none of them shows every parameter by name.
    """
    base = env_id.rsplit("-v", 1)[0]
    words = [w for w in base.split("_") if w]
    short = base.upper() if len(words) <= 1 else "".join(w[0] for w in words).upper()
    sizes = [_value(params[k]) for k in SIZE_PARAMS if k in params]
    if not sizes:
        sizes = [f"{k}={_value(v)}" for k, v in sorted(params.items())]
    return f"{short}({','.join(sizes)})" if sizes else short


def condition_label(attack: str | None, params: dict[str, Any], given: list | tuple = ()) -> str:
    """`clean`, or the attack's name, its text-valued (mode) parameters joined by ``_``
    (``admo_disrupt``), and the numeric parameters the run set, in parentheses
    (``fake_incentive(amount=10)``). `params`: every resolved parameter; `given`: the
    (name, value) pairs the run set."""
    if attack is None:
        return CLEAN
    words = [str(v) for _, v in sorted(params.items()) if isinstance(v, str)]
    others = [f"{k}={_value(v)}" for k, v in sorted(given) if not isinstance(v, str)]
    label = "_".join([attack, *words])
    return label + (f"({', '.join(others)})" if others else "")


def distinct_env_labels(records: list[RunRecord]) -> dict[tuple, str]:
    """Env label per `env_key`, with the parameters that tell apart envs of one label."""
    by_label: dict[str, dict[tuple, dict]] = {}
    for r in records:
        by_label.setdefault(r.env, {})[r.env_key] = r.identity["env_params"]
    out = {}
    for label, envs in by_label.items():
        keys = sorted({k for params in envs.values() for k in params})
        varying = [k for k in keys if len({repr(p.get(k)) for p in envs.values()}) > 1]
        for env_key, params in envs.items():
            extra = ", ".join(f"{k}={_value(params.get(k))}" for k in varying)
            out[env_key] = f"{label} {extra}" if extra else label
    return out


def defense_label(defenses: list | tuple) -> str:
    """`none`, or the defenses' names joined by ``+``, each with the parameters it set."""
    if not defenses:
        return NO_DEFENSE
    parts = []
    for name, params in defenses:
        given = ", ".join(f"{k}={_value(v)}" for k, v in sorted(params))
        parts.append(f"{name}({given})" if given else name)
    return "+".join(parts)


def hparams_label(hparams: list | tuple) -> str:
    return ", ".join(f"{k}={_value(v)}" for k, v in sorted(hparams))


def run_label(run_dir: Path) -> str:
    """ "lio ER(2,1) reverse + incentive_guard": learner, env and condition (the attack and
    the parameters the run set), the defenses (`defense_label`), then what else tells runs
    of one setting apart."""
    config = store.read_json(run_dir / store.CONFIG)
    identity = config["identity"]
    env = env_label(config["env"]["id"], config["env"]["params"])
    given = config.get("run_config", {}).get("attack_params", ())
    condition = condition_label(identity["attack"], identity["attack_params"], given)
    label = f"{identity['learner']} {env} {condition}"
    defenses = config.get("run_config", {}).get("defenses", ())
    if defenses:
        label += f" + {defense_label(defenses)}"
    first, count = config["identity"]["first_seed"], config["identity"]["seeds"]
    if first:
        label += f" seeds {first}–{first + count - 1}"
    if incentive_updates(config) == "own":
        label += " own-η"
    return label


def incentive_updates(config: dict[str, Any]) -> str | None:
    """ "shared" or "own": how a LIO run's givers updated incentives where the two differ
    (N ≥ 3); None otherwise. Run directories written before the option had a name carry
    `original_shared_incentive_updates` (true = shared, false = own)."""
    learner_config = config["identity"].get("learner_config", {})
    if config.get("env", {}).get("num_agents", 0) < 3:
        return None
    if "incentive_updates" in learner_config:
        return learner_config["incentive_updates"]
    if "original_shared_incentive_updates" in learner_config:
        return "shared" if learner_config["original_shared_incentive_updates"] else "own"
    return None


PALETTE = (
    "#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#bcbd22",
    "#17becf", "#393b79", "#637939", "#8c6d31", "#843c39", "#7b4173", "#3182bd", "#e6550d",
    "#31a354", "#756bb1", "#636363", "#ad494a",
)  # fmt: skip
"""Condition colours: matplotlib's tab10 without its grey (grey is the random-team
reference), then darker tab20b/tab20c tones; the first seven are the paper's conditions."""


def condition_colors(conditions: Iterable[str]) -> dict[str, str]:
    """The one colour mapping of every figure: condition -> hex colour, clean first.

    A paper condition always gets the colour of its place in the paper's order (so a
    condition keeps its colour across figures, sections and reports); any other
    condition takes the next free colour in `condition_key` order.
    """
    wanted = sorted(set(conditions) | {CLEAN}, key=condition_key)
    taken = {c: CONDITION_ORDER.index(c) for c in wanted if c in CONDITION_ORDER}
    free = (k for k in range(len(PALETTE) * 64) if k not in taken.values())
    for c in wanted:
        if c not in taken:
            taken[c] = next(free)
    return {c: PALETTE[taken[c] % len(PALETTE)] for c in wanted}


def condition_key(condition: str) -> tuple[int, str]:
    """Sort key: the paper's conditions in the paper's order, then any other by name."""
    if condition in CONDITION_ORDER:
        return CONDITION_ORDER.index(condition), ""
    return len(CONDITION_ORDER), condition


def natural_key(text: str) -> tuple:
    """Sort key that orders numbers by value: ER(4,2) < ER(10,2)."""
    return tuple(int(p) if p.isdigit() else p for p in re.split(r"(\d+)", text))


# --- loading ---------------------------------------------------------------------------


def pooled(records: list[RunRecord]) -> RunRecord:
    """Several runs at the same settings as one: their seeds side by side (numbered in
    order), the columns every one has, the shortest horizon's iterations; named
    "A + B" after the runs. An original-code seed whose log opens as one already pooled
    does (`opening_of`: a rerun of the same random seed, kept in another directory) counts
    once: the summary's "reruns_dropped" says how many. One run is returned as it is."""
    if len(records) == 1:
        return records[0]
    columns = tuple(
        c for c in records[0].curves.columns if all(c in r.curves.columns for r in records)
    )
    iterations, values, openings, dropped = {}, {}, set(), 0
    for record in records:
        for seed in record.curves.seeds:
            opening = opening_of(record, seed)
            if opening is not None and opening in openings:
                dropped += 1
                continue
            openings.add(opening)
            number = len(iterations)
            iterations[number] = record.curves.iterations[seed]
            kept = record.curves.values[seed]
            values[number] = {c: kept[c] for c in columns if c in kept}
    curves = Curves(columns, tuple(iterations), iterations, values)
    horizon = min(r.iterations for r in records)
    final = {c: {"per_seed": curves.final(c).tolist()} for c in values[0]}
    summary = {"seeds": list(curves.seeds), "iterations": horizon, "final": final}
    return dataclasses.replace(
        records[0],
        name=" + ".join(r.name for r in records),
        summary=summary | ({"reruns_dropped": dropped} if dropped else {}),
        seeds=len(iterations),
        iterations=horizon,
        curves=curves,
    )


def opening_of(record: RunRecord, seed: int) -> str | None:
    """The SHA-256 of an original-code seed's opening log rows (the import's
    `opening_sha256`; logs that open alike are reruns of one random seed), None for
    pimbot's own runs."""
    seeds = record.config.get("original", {}).get("seeds", [])
    found = next((s for s in seeds if s.get("seed") == seed), None)
    return found.get("opening_sha256") if found else None


def load_record(suite_dir: Path, name: str) -> RunRecord:
    path = Path(suite_dir) / name
    config = store.read_json(path / store.CONFIG)
    identity, run = config["identity"], config["run_config"]
    rows = store.read_metrics(path)
    store.check_rows_complete(path, rows, identity)  # a damaged run is never read as good
    summary = {**store.read_json(path / store.SUMMARY), **summarize_rows(rows, config)}
    curves = curves_of(rows)
    return RunRecord(
        name=name,
        path=path,
        config=config,
        summary=summary,
        condition=condition_label(
            identity["attack"], identity["attack_params"], run.get("attack_params", ())
        ),
        env=env_label(identity["env_id"], identity["env_params"]),
        learner=identity["learner"],
        hparams=hparams_label(run.get("hparams", ())),
        defenses=defense_label(run.get("defenses", ())),
        seeds=len(summary["seeds"]),
        iterations=int(summary["iterations"]),
        curves=curves,
    )


def _is_training_run(path: Path) -> bool:
    if not (path / store.SUMMARY).exists() or not (path / store.CONFIG).exists():
        return False
    config = store.read_json(path / store.CONFIG)
    return isinstance(config, dict) and "identity" in config and "run_config" in config


def read_profile(suite_dir: Path) -> dict[str, Any] | None:
    """The paired profile's summary.json under `suite_dir` (None: none finished)."""
    path = Path(suite_dir) / PROFILE_RUN / store.SUMMARY
    return store.read_json(path) if path.exists() else None


def load_table(suite_dir: Path, index: dict | None = None) -> RunTable:
    """Every finished run under `suite_dir` (`<group>/<setting>/` directories).

    Jobs the index lists with another kind (profiles, robot evaluations) are not training
    runs: their summaries are `RunTable.profile` and `RunTable.robot`; finished run
    directories the index does not list are read too. Run directories converted from the
    original code's logs (config.json "source": "original code") are kept apart, in
    `RunTable.original`.
    """
    suite_dir = Path(suite_dir)
    other_kinds = {
        job["name"] for job in (index or {}).get("jobs", []) if job.get("kind", "train") != "train"
    }
    names = sorted(
        path.relative_to(suite_dir).as_posix()
        for path in suite_dir.glob("*/*")
        if path.is_dir() and _is_training_run(path)
    )
    loaded = [load_record(suite_dir, n) for n in names if n not in other_kinds]
    return RunTable(
        tuple(r for r in loaded if r.source != ORIGINAL_CODE),
        tuple(r for r in loaded if r.source == ORIGINAL_CODE),
        tuple(store.read_json(p) for p in sorted(suite_dir.glob(ROBOT_SUMMARIES))),
        read_profile(suite_dir),
    )
