"""Experiment grids: envs × learners × attacks × defenses, expanded into sweep jobs.

`pimbot sweep GRID.toml --out DIR` runs a grid with the machinery of
`pimbot reproduce` (local pool or Ray, resumable, DIR/index.json); the paper's
training groups are grids too (`presets`). A grid file (TOML)::

    name = "my_grid"        # optional; default: the file name. Jobs run in DIR/<name>/...
    plugins = ["my_attack.py"]  # optional: plugins to load, like --plugin (a .py path is
                            # relative to this file; a dotted name is a module)
    seeds = 3               # seeds per run
    iterations = 2000       # training iterations per run (an env may set its own)
    eval_period = 100       # optional: iterations between evaluations (default: the env's)
    eval_episodes = 10      # optional: episodes per evaluation (default 10)
    first_seed = 0          # optional

    [[envs]]                # one or more; see `pimbot envs`
    id = "escape_room-v0"
    params = { n_agents = 4, min_at_lever = 2 }   # optional
    label = "er42"          # optional; default: the id and its params
    iterations = 1000       # optional per-env overrides of iterations and eval_period,
    hparams = {}            # and learner hparams used on this env (a learner's own win)

    [[learners]]            # one or more; see `pimbot learners`
    name = "lio"
    hparams = { lr_incentive = 1e-3 }             # optional
    label = "lio_fast"      # optional; default: the name and its hparams

    [[attacks]]             # optional (default: clean only); see `pimbot attacks`
    name = "none"           # "none" = clean (label "clean")
    [[attacks]]
    name = "admo"
    params = { mode = "disrupt" }                 # optional
    label = "admo_disrupt"  # optional; default: the name and its params

    [[defenses]]            # optional (default: no defense); see `pimbot defenses`
    names = []              # no defense: this entry adds nothing to the job names
    [[defenses]]
    names = ["incentive_guard", "health_monitor"]
    params = { health_monitor = { patience = 20 } }  # optional, by defense name
    label = "guard_monitor" # optional; default: the names joined by "+"

Every combination is one training job named
``<name>/<env label>_<learner label>_<attack label>[_<defense label>]``; labels
are sanitised for directory names and an empty label (``label = ""``) leaves
its axis out of the name. `load` checks every field and `validate` resolves
every job (`config.resolve`) before anything is written; a bad field fails
with one line naming it and the allowed values.

A grid may mix learners with different hook points: a cell whose attack or
defense acts at a hook point its learner does not have
(`config.IncompatibleHooks`) is skipped, not run, and listed with its reason
(`pimbot sweep --list`, index.json "skipped", the report). A grid whose every
cell is skipped is refused.
"""

from __future__ import annotations

import dataclasses
import re
import tomllib
from pathlib import Path
from typing import Any

from pimbot import attacks, defenses, envs, learners
from pimbot import plugins as plugin_loader
from pimbot.contracts import preflight
from pimbot.envs.core import InvalidParameter
from pimbot.suites.jobs import Job, Skipped
from pimbot.training.config import (
    IncompatibleHooks,
    RunConfig,
    coerce_like,
    resolve,
    resolving,
)

Pairs = tuple[tuple[str, Any], ...]
CLEAN = "none"
"""The attack name of a clean (unattacked) run in a grid file."""


class GridError(InvalidParameter):
    """A grid file that cannot be run; the message is one line naming the field."""


@dataclasses.dataclass(frozen=True)
class EnvEntry:
    """An environment of the grid, optionally with its own budget and hparams."""

    env_id: str
    params: Pairs = ()
    label: str | None = None
    """Its part of the job names; None = the id and its params."""
    iterations: int | None = None
    """Overrides the grid's iterations on this env."""
    eval_period: int | None = None
    """Overrides the grid's eval_period on this env."""
    hparams: Pairs = ()
    """Learner hparams on this env (a learner entry's own hparams take precedence)."""

    @property
    def name_label(self) -> str:
        return _label(self.label, self.env_id, self.params)


@dataclasses.dataclass(frozen=True)
class LearnerEntry:
    name: str
    hparams: Pairs = ()
    label: str | None = None

    @property
    def name_label(self) -> str:
        return _label(self.label, self.name, self.hparams)


@dataclasses.dataclass(frozen=True)
class AttackEntry:
    name: str | None
    """A registered attack, or None for a clean run."""
    params: Pairs = ()
    label: str | None = None

    @property
    def name_label(self) -> str:
        return _label(self.label, self.name or "clean", self.params)


@dataclasses.dataclass(frozen=True)
class DefenseEntry:
    defenses: tuple[tuple[str, Pairs], ...] = ()
    """`RunConfig.defenses`: (name, sorted params) pairs; empty = no defense."""
    label: str | None = None

    @property
    def name_label(self) -> str:
        if self.label is not None:
            return _sanitise(self.label)
        params = tuple((f"{d}.{k}", v) for d, pairs in self.defenses for k, v in pairs)
        return _label(None, "+".join(d for d, _ in self.defenses), params)


@dataclasses.dataclass(frozen=True)
class Grid:
    """A product of entries; every cell is one training run of `seeds` seeds."""

    name: str
    envs: tuple[EnvEntry, ...]
    learners: tuple[LearnerEntry, ...]
    seeds: int
    iterations: int | None = None
    """Training iterations of every run whose env entry does not set its own."""
    attacks: tuple[AttackEntry, ...] = (AttackEntry(None),)
    defenses: tuple[DefenseEntry, ...] = (DefenseEntry(),)
    eval_period: int | None = None
    eval_episodes: int | None = None
    first_seed: int = 0
    plugins: tuple[str, ...] = ()
    """The plugins the grid file names, loaded (`plugins.load_plugins`'s canonical names)."""


@dataclasses.dataclass(frozen=True)
class Cell:
    """One combination of entries, with the job it expands to."""

    env: EnvEntry
    learner: LearnerEntry
    attack: AttackEntry
    defense: DefenseEntry
    job: Job


# --- expansion ---------------------------------------------------------------------------


def _sanitise(text: str) -> str:
    """A directory-safe label: runs of other characters become "-"."""
    return re.sub(r"[^A-Za-z0-9._=+-]+", "-", text).strip("-").lstrip(".")


def _value_text(value: Any) -> str:
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, list | tuple):
        return ",".join(_value_text(v) for v in value)
    return str(value)


def _label(label: str | None, name: str, params: Pairs) -> str:
    if label is not None:
        return _sanitise(label)
    return _sanitise("_".join([name] + [f"{k}={_value_text(v)}" for k, v in params]))


def _merged(env_hparams: Pairs, own: Pairs) -> Pairs:
    if not own:
        return env_hparams
    if not env_hparams:
        return own
    return tuple((dict(env_hparams) | dict(own)).items())


def expand_cells(grid: Grid) -> list[Cell]:
    """Every cell of `grid`, envs outermost, then learners, attacks and defenses.

    Raises:
        GridError: two cells with the same job name, or an env without iterations.
    """
    cells: list[Cell] = []
    names: set[str] = set()
    group = _sanitise(grid.name)
    label = {id(e): e.name_label for e in (*grid.envs, *grid.learners, *grid.attacks)}
    label |= {id(e): e.name_label for e in grid.defenses}  # each entry's label made once
    for env in grid.envs:
        iterations = env.iterations if env.iterations is not None else grid.iterations
        if iterations is None:
            raise GridError(f"iterations: missing; set it for the grid or for env {env.env_id}")
        eval_period = env.eval_period if env.eval_period is not None else grid.eval_period
        for learner in grid.learners:
            for attack in grid.attacks:
                for defense in grid.defenses:
                    labels = (label[id(env)], label[id(learner)], label[id(attack)])
                    setting = "_".join(x for x in (*labels, label[id(defense)]) if x)
                    name = f"{group}/{setting}"
                    if not setting or name in names:
                        raise GridError(
                            f"label: two jobs would be named {name!r}; give the entries "
                            "distinct labels"
                        )
                    names.add(name)
                    run = RunConfig(
                        env_id=env.env_id,
                        env_params=env.params,
                        learner=learner.name,
                        hparams=_merged(env.hparams, learner.hparams),
                        seeds=grid.seeds,
                        first_seed=grid.first_seed,
                        iterations=iterations,
                        eval_period=eval_period,
                        eval_episodes=grid.eval_episodes,
                        attack=attack.name,
                        attack_params=attack.params,
                        defenses=defense.defenses,
                    )
                    cells.append(Cell(env, learner, attack, defense, Job(name, "train", run)))
    return cells


def expand(grid: Grid) -> list[Job]:
    """The training jobs of `grid` (see `expand_cells`)."""
    return [cell.job for cell in expand_cells(grid)]


def validate(jobs: list[Job]) -> list[Skipped]:
    """Resolves every job's RunConfig (env, learner, attack, defenses, budget together).

    Returns:
        The jobs to skip: those whose attack or defense acts at a hook point their
        learner does not have, each with its one-line reason.

    Raises:
        GridError: ``<job name>: <field>: <why; allowed values>``; or every job skipped.
    """
    skipped = []
    with resolving():  # each distinct env, config, attack and defense stack built once
        for job in jobs:
            try:
                resolve(job.spec)
            except IncompatibleHooks as error:
                skipped.append(Skipped(job.name, error.reason))
            except InvalidParameter as error:
                raise GridError(f"{job.name}: {error}") from None
    if jobs and len(skipped) == len(jobs):
        raise GridError(
            f"grid: every cell is incompatible ({len(jobs)} cells), e.g. {skipped[0].name}: "
            f"{skipped[0].reason}"
        )
    return skipped


# --- the grid file -------------------------------------------------------------------------

TOP_FIELDS = (
    "name",
    "seeds",
    "iterations",
    "eval_period",
    "eval_episodes",
    "first_seed",
    "envs",
    "learners",
    "attacks",
    "defenses",
    "plugins",
)
ENV_FIELDS = ("id", "params", "label", "iterations", "eval_period", "hparams")
LEARNER_FIELDS = ("name", "hparams", "label")
ATTACK_FIELDS = ("name", "params", "label")
DEFENSE_FIELDS = ("names", "params", "label")


class _Reader:
    """Typed access to one TOML table, failing with the field's full name."""

    def __init__(self, table: Any, where: str, allowed: tuple[str, ...]):
        if not isinstance(table, dict):
            raise GridError(f"{where}: must be a table, got {table!r}")
        for key in table:
            if key not in allowed:
                raise GridError(
                    f"{self._at(where, key)}: not a field here; allowed: {', '.join(allowed)}"
                )
        self.table, self.where = table, where

    @staticmethod
    def _at(where: str, key: str) -> str:
        return f"{where}.{key}" if where else key

    def field(self, key: str) -> str:
        return self._at(self.where, key)

    def integer(self, key: str, low: int, required: bool = False) -> int | None:
        value = self.table.get(key)
        if value is None:
            if required:
                raise GridError(f"{self.field(key)}: missing; must be an integer ≥ {low}")
            return None
        if isinstance(value, bool) or not isinstance(value, int) or value < low:
            raise GridError(f"{self.field(key)}: must be an integer ≥ {low}, got {value!r}")
        return value

    def text(self, key: str, required: bool = False) -> str | None:
        value = self.table.get(key)
        if value is None and not required:
            return None
        if not isinstance(value, str):
            raise GridError(f"{self.field(key)}: must be a string, got {value!r}")
        return value

    def table_of(self, key: str) -> dict[str, Any]:
        value = self.table.get(key, {})
        if not isinstance(value, dict):
            raise GridError(f"{self.field(key)}: must be a table (name = value, ...)")
        return value

    def entries(self, key: str, required: bool) -> list[Any]:
        value = self.table.get(key)
        if value is None:
            if required:
                raise GridError(f"{key}: missing; add at least one [[{key}]] entry")
            return []
        if not isinstance(value, list):
            raise GridError(f"{key}: must be a list of [[{key}]] tables")
        if required and not value:
            raise GridError(f"{key}: empty; add at least one [[{key}]] entry")
        return value


def _typed(values: dict[str, Any], defaults: dict[str, Any], where: str, what: str) -> Pairs:
    """`values` checked against `defaults` and typed like them, sorted by name."""
    typed = {}
    for name, value in values.items():
        if name not in defaults:
            raise GridError(
                f"{where}: {name}: not a {what}; allowed: {', '.join(defaults) or 'none'}"
            )
        try:
            typed[name] = coerce_like(name, value, defaults[name])
        except InvalidParameter as error:
            raise GridError(f"{where}: {error}") from None
    return tuple(sorted(typed.items()))


def _checked(where: str, check, *args):
    try:
        return check(*args)
    except InvalidParameter as error:
        raise GridError(f"{where}: {error}") from None


def _env(table: Any, where: str) -> EnvEntry:
    r = _Reader(table, where, ENV_FIELDS)
    env_id = r.text("id", required=True)
    entry = _checked(r.field("id"), envs.spec, env_id)
    params = _typed(r.table_of("params"), entry.parameters(), r.field("params"), "parameter")
    _checked(r.field("params"), lambda: envs.make(env_id, **dict(params)))
    return EnvEntry(
        env_id,
        params,
        label=r.text("label"),
        iterations=r.integer("iterations", 1),
        eval_period=r.integer("eval_period", 1),
        hparams=tuple(r.table_of("hparams").items()),
    )


def _learner(table: Any, where: str) -> LearnerEntry:
    r = _Reader(table, where, LEARNER_FIELDS)
    name = r.text("name", required=True)
    definition = _checked(r.field("name"), learners.get, name)
    fields = [f.name for f in dataclasses.fields(definition.config_cls)]
    hparams = r.table_of("hparams")
    for key in hparams:
        if key not in fields:
            raise GridError(
                f"{r.field('hparams')}: {key}: not a hyperparameter of {name}; "
                f"allowed: {', '.join(fields)}"
            )
    return LearnerEntry(name, tuple(hparams.items()), label=r.text("label"))


def _attack(table: Any, where: str) -> AttackEntry:
    r = _Reader(table, where, ATTACK_FIELDS)
    name = r.text("name", required=True)
    if name == CLEAN:
        if r.table_of("params"):
            raise GridError(f'{r.field("params")}: a clean run (name = "none") has none')
        return AttackEntry(None, label=r.text("label"))
    defaults = _checked(r.field("name"), attacks.parameters, name)
    params = _typed(r.table_of("params"), defaults, r.field("params"), f"parameter of {name}")
    return AttackEntry(name, params, label=r.text("label"))


def _defense(table: Any, where: str) -> DefenseEntry:
    r = _Reader(table, where, DEFENSE_FIELDS)
    names = r.table.get("names", [])
    if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
        raise GridError(f"{r.field('names')}: must be a list of defense names (or [] for none)")
    params = r.table_of("params")
    for owner in params:
        if owner not in names:
            raise GridError(
                f"{r.field('params')}: {owner}: not one of this entry's names; "
                f"allowed: {', '.join(names) or 'none'}"
            )
    stack = []
    for name in names:
        defaults = _checked(r.field("names"), defenses.parameters, name)
        values = params.get(name, {})
        if not isinstance(values, dict):
            raise GridError(f"{r.field('params')}.{name}: must be a table (name = value, ...)")
        where_params = f"{r.field('params')}.{name}"
        stack.append((name, _typed(values, defaults, where_params, f"parameter of {name}")))
    return DefenseEntry(tuple(stack), label=r.text("label"))


def parse(data: dict[str, Any], default_name: str, plugins: tuple[str, ...] = ()) -> Grid:
    """A `Grid` from a parsed grid file; every entry checked against the registries (its
    `plugins`, loaded by `load_grid_plugins`, are recorded as they are).

    Raises:
        GridError: the first bad field, named (``attacks[1].params: mode: ...``).
    """
    r = _Reader(data, "", TOP_FIELDS)
    name = r.text("name") or default_name
    if not _sanitise(name):
        raise GridError(f"name: must contain a letter or digit, got {name!r}")

    def entries(key: str, make, required: bool):
        return tuple(make(t, f"{key}[{i}]") for i, t in enumerate(r.entries(key, required)))

    grid = Grid(
        name=_sanitise(name),
        envs=entries("envs", _env, True),
        learners=entries("learners", _learner, True),
        seeds=r.integer("seeds", 1, required=True),
        iterations=r.integer("iterations", 1),
        eval_period=r.integer("eval_period", 1),
        eval_episodes=r.integer("eval_episodes", 1),
        first_seed=r.integer("first_seed", 0) or 0,
        plugins=plugins,
    )
    replace = {}
    if attack_entries := entries("attacks", _attack, False):
        replace["attacks"] = attack_entries
    if defense_entries := entries("defenses", _defense, False):
        replace["defenses"] = defense_entries
    return dataclasses.replace(grid, **replace)


def load(path: str | Path) -> Grid:
    """Reads and checks a grid file (TOML).

    Raises:
        GridError: unreadable file, bad TOML, or a bad field (one line, named).
    """
    path = Path(path)
    try:
        with open(path, "rb") as f:
            data = tomllib.load(f)
    except OSError as error:
        raise GridError(f"grid: cannot read {path}: {error.strerror or error}") from None
    except tomllib.TOMLDecodeError as error:
        raise GridError(f"grid: {path} is not valid TOML: {error}") from None
    except UnicodeDecodeError:
        raise GridError(f"grid: {path} is not valid TOML: not UTF-8 text") from None
    plugins = load_grid_plugins(data.get("plugins"), path)
    return parse(data, default_name=path.stem, plugins=plugins)


def load_grid_plugins(names: Any, path: Path) -> tuple[str, ...]:
    """Loads the plugins a grid file names (``plugins = [...]``: a .py path relative to the
    grid file, or a dotted module name) like --plugin, and checks what they registered.

    Returns:
        Their canonical names (what a sweep's workers load).

    Raises:
        GridError: not a list of strings, or a file that does not exist.
        PluginError, ContractError: a plugin that cannot be imported or breaks its contract.
    """
    if names is None:
        return ()
    if not isinstance(names, list) or not all(isinstance(n, str) and n.strip() for n in names):
        raise GridError(f"plugins: must be a list of .py paths or module names, got {names!r}")
    modules = []
    for k, name in enumerate(names):
        if plugin_loader.is_path(name):
            file = (path.parent / Path(name).expanduser()).resolve()
            if not file.is_file():
                raise GridError(f"plugins[{k}]: no such file {file} (relative to {path})")
            name = str(file)
        modules.append(name)
    loaded = plugin_loader.load_plugins(modules, from_env=False)
    preflight.check_plugins()  # what they registered, before any job is planned
    return loaded


def load_jobs(path: str | Path) -> tuple[Grid, list[Job], list[Skipped]]:
    """The grid in `path`, the jobs to run (every one resolved; nothing is written) and the
    cells skipped (`validate`)."""
    grid = load(path)
    jobs = expand(grid)
    skipped = validate(jobs)
    names = {s.name for s in skipped}
    return grid, [job for job in jobs if job.name not in names], skipped
