"""The Python API: the commands as keyword calls, and a run directory as an object.

    import jax, pimbot

    run = pimbot.train("escape_room-v0", seeds=2, iterations=300, out="runs/demo")
    run.config, run.summary                  # config.json and summary.json as dicts
    run.metrics                              # metrics.csv as a pandas DataFrame
    obs, _ = run.env.reset(jax.random.key(0))
    probabilities, actions = run.policy(0)(obs[0], key=jax.random.key(1))
    given = run.incentive(0)(obs[0], actions=jax.numpy.array([1, 2]))   # LIO: [N]

`train`, `sweep` and `report` take the options of `pimbot train`, `sweep` and `report`
as keywords, spelled as in a --config file (`--attack-param` is `attack_param`, a
NAME=VALUE option takes a dict): each builds the command object the command line would,
and runs it through the command line's own steps (`_execute`: plugins, compilation
cache, name and range checks, the command's handler). Bad input raises
`pimbot.errors.InvalidParameter` with the line the command line prints, before anything
is written. `load_run` reads a run directory: nothing of it is computed again.

This module lives with the command line because it runs the commands; `import pimbot`
exposes its names lazily (`pimbot.__init__`).
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import inspect
import json
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, NamedTuple

from pimbot.errors import InvalidParameter, check_int

_EXCLUDED = ("plugin", "config", "from_run")
"""Command fields that are no keyword option: `plugins` and `config` are keywords of their
own; `train --from RUN_DIR` is the command line's (to resume, call `train` with the same
`out` again)."""


@contextlib.contextmanager
def _one_line() -> Iterator[None]:
    """The command line's usage errors as `InvalidParameter` (its line, unchanged)."""
    from pimbot.cli.parsing import UsageError

    try:
        yield
    except UsageError as error:
        raise InvalidParameter(str(error)) from None


def _execute(path: tuple[str, ...], values: dict[str, Any], source: str) -> Any:
    """Builds command `path` from keyword `values` (as a --config table: the same
    conversions and checks) and runs it as `pimbot.cli.run` runs a parsed command line."""
    import tyro

    from pimbot import jax_setup, plugins
    from pimbot.cli import Parsed, commands, parsing

    cls = commands.COMMANDS[path]
    with _one_line():
        if values.get("config") is not None:
            values = {**parsing.read_config_file(str(values["config"])), **values}
        values.pop("config", None)
        values = {k: str(v) if isinstance(v, Path) else v for k, v in values.items()}
        if cls.all_cpu_cores:
            jax_setup.use_all_cpu_cores()  # no effect once JAX has started its backend
        command = parsing.defaults(cls, values, source)
        missing = [
            f.name for f in dataclasses.fields(command) if getattr(command, f.name) is tyro.MISSING
        ]
        if missing:
            raise InvalidParameter(f"{', '.join(missing)}: required ({source})")
        loaded = plugins.load_plugins(command.plugin)
        if cls.compiles:
            jax_setup.enable_compilation_cache()
        if plugins.loaded():
            from pimbot import learners  # noqa: F401 (the built-ins a plugin's defaults name)
            from pimbot.contracts import preflight

            preflight.check_plugins()
        Parsed(path, command).check()
        return command.run(loaded)


def _options(path: tuple[str, ...], leading: tuple[str, ...]) -> list[inspect.Parameter]:
    """The keyword parameters of command `path` (its fields, their defaults), for the
    signature `help()` and notebooks show."""
    from pimbot.cli import commands

    parameters = []
    for field in dataclasses.fields(commands.COMMANDS[path]):
        if field.name in (*leading, *_EXCLUDED):
            continue
        default = field.default
        if default is dataclasses.MISSING:
            default = inspect.Parameter.empty
        parameters.append(
            inspect.Parameter(field.name, inspect.Parameter.KEYWORD_ONLY, default=default)
        )
    return parameters


def _signed(path: tuple[str, ...], leading: tuple[str, ...]):
    """Gives the decorated function the signature of command `path`'s options."""

    def decorate(function: Callable) -> Callable:
        own = inspect.signature(function).parameters
        first = [p for p in own.values() if p.kind is not inspect.Parameter.VAR_KEYWORD]
        try:
            rest = _options(path, leading)
        except Exception:  # the signature is documentation: never fail an import for it
            return function
        names = {p.name for p in first}
        function.__signature__ = inspect.Signature(first + [p for p in rest if p.name not in names])
        return function

    return decorate


def _call_values(function: str, options: dict[str, Any], path) -> dict[str, Any]:
    from pimbot.cli import commands

    allowed = {f.name for f in dataclasses.fields(commands.COMMANDS[path])} - set(_EXCLUDED)
    unknown = sorted(set(options) - allowed)
    if unknown:
        raise InvalidParameter(
            f"{unknown[0]}: not an option of pimbot.{function}; allowed: "
            f"{', '.join(sorted(allowed))}"
        )
    return dict(options)


@_signed(("train",), ("env_id",))
def train(
    env_id: str,
    *,
    plugins: tuple[str, ...] | list[str] = (),
    config: str | Path | None = None,
    quiet: bool = True,
    **options: Any,
) -> Run:
    """Trains a learner on an env (or resumes the run in `out`) and returns the run.

    The keywords are `pimbot train`'s options (`pimbot train --help`), e.g. `learner`,
    `seeds`, `iterations`, `hp={"lr_policy": 1e-3}`, `attack`, `attack_param={...}`,
    `defense=[...]`, `defense_param={"DEFENSE": {...}}`, `out`; `env_params={"n_agents":
    4}` are the env's parameters. `plugins` are loaded first, as --plugin; `config` is a
    TOML/YAML file of options (the keywords override it); `quiet=False` shows the progress
    display. Prints the command's result line.

    Raises:
        InvalidParameter: bad input, one line naming the option (nothing written).
    """
    values = _call_values("train", options, ("train",))
    values.update(env_id=env_id, plugin=list(plugins), quiet=quiet, config=config)
    _execute(("train",), values, "pimbot.train")
    return load_run(values["out"])


@_signed(("sweep",), ("grid",))
def sweep(
    grid: str | Path,
    *,
    plugins: tuple[str, ...] | list[str] = (),
    config: str | Path | None = None,
    quiet: bool = True,
    **options: Any,
) -> Suite | None:
    """Runs (or resumes) the grid of a TOML file into `out` and returns the suite (None
    with `list=True`, which prints the plan).

    The keywords are `pimbot sweep`'s options (`out`, `only=[...]`, `workers`,
    `backend`, ...); a job that fails is listed in `Suite.failed`, as the command line
    lists it, and the other jobs still run.

    Raises:
        InvalidParameter: a bad grid or option, one line (nothing written).
    """
    values = _call_values("sweep", options, ("sweep",))
    values.update(grid=grid, plugin=list(plugins), quiet=quiet, config=config)
    _execute(("sweep",), values, "pimbot.sweep")
    if values.get("list"):  # the plan was printed; nothing ran
        return None
    return load_suite(values["out"])


@_signed(("report",), ("suite_dir",))
def report(suite_dir: str | Path, *, config: str | Path | None = None, **options: Any) -> Path:
    """Writes report.md and report.html of a suite directory (into `out`, default the
    suite directory) and returns the path of report.html."""
    from pimbot.analysis.report import HTML

    values = _call_values("report", options, ("report",))
    values.update(suite_dir=suite_dir, config=config)
    _execute(("report",), values, "pimbot.report")
    return Path(values.get("out") or suite_dir) / HTML


class PolicyOutput(NamedTuple):
    """What a `Policy` gives for observations [..., obs_dim]."""

    probabilities: Any
    """float32 [..., num_actions]: the trained policy's action probabilities (ε = 0)."""
    actions: Any
    """int32 [...]: sampled from them with the key given, else the most probable."""


@dataclasses.dataclass(frozen=True)
class Policy:
    """One agent's trained policy (one seed): `policy(obs, key=None)` -> (probabilities,
    actions) for observations [obs_dim] or [B, obs_dim] (NumPy or JAX arrays). One
    compiled program per shape of `obs`, with and without a key."""

    agent: int
    seed: int
    num_actions: int
    obs_dim: int
    logits_fn: Callable[[Any], Any] = dataclasses.field(repr=False)

    @functools.cached_property
    def _programs(self) -> dict[bool, Callable]:
        import jax

        def program(obs, key, sample: bool):
            logits = self.logits_fn(obs)
            actions = jax.random.categorical(key, logits) if sample else logits.argmax(-1)
            return logits, jax.nn.softmax(logits, axis=-1), actions.astype("int32")

        return {
            sample: jax.jit(functools.partial(program, sample=sample)) for sample in (False, True)
        }

    def _run(self, obs, key) -> tuple[Any, Any, Any]:
        import jax

        obs = _observations(obs, self.obs_dim)
        flat = obs.reshape((-1, self.obs_dim))
        sample = key is not None
        outputs = self._programs[sample](flat, key if sample else jax.random.key(0))
        lead = obs.shape[:-1]
        logits, probabilities, actions = outputs
        return (
            logits.reshape((*lead, self.num_actions)),
            probabilities.reshape((*lead, self.num_actions)),
            actions.reshape(lead),
        )

    def logits(self, obs) -> Any:
        """The action logits [..., num_actions] of observations [..., obs_dim]."""
        return self._run(obs, None)[0]

    def __call__(self, obs, key=None) -> PolicyOutput:
        _, probabilities, actions = self._run(obs, key)
        return PolicyOutput(probabilities, actions)


@dataclasses.dataclass(frozen=True)
class Incentive:
    """One agent's learned incentive function (one seed): `incentive(obs, actions)` -> what
    the agent gives each agent [..., N] after the joint action (its own entry 0)."""

    agent: int
    seed: int
    num_agents: int
    obs_dim: int
    give_fn: Callable[[Any, Any], Any] = dataclasses.field(repr=False)

    @functools.cached_property
    def _program(self) -> Callable:
        import jax

        return jax.jit(self.give_fn)

    def __call__(self, obs, actions) -> Any:
        """obs [..., obs_dim] (the giver's), actions int [..., N] (everyone's)."""
        import jax.numpy as jnp

        obs = _observations(obs, self.obs_dim)
        actions = jnp.asarray(actions, jnp.int32)
        lead = obs.shape[:-1]
        if actions.shape != (*lead, self.num_agents):
            raise InvalidParameter(
                f"actions: must have shape {(*lead, self.num_agents)} (one action "
                f"per agent for each observation), got {actions.shape}"
            )
        flat = obs.reshape((-1, self.obs_dim)), actions.reshape((-1, self.num_agents))
        return self._program(*flat).reshape((*lead, self.num_agents))


def _observations(obs, obs_dim: int):
    import jax.numpy as jnp

    obs = jnp.asarray(obs, jnp.float32)
    if obs.ndim == 0 or obs.shape[-1] != obs_dim:
        raise InvalidParameter(
            f"obs: must end in the env's obs_dim {obs_dim} ([obs_dim] or [B, obs_dim]), "
            f"got shape {obs.shape}"
        )
    return obs


@dataclasses.dataclass(frozen=True, eq=False)
class Run:
    """A run directory (finished, or checkpointed and resumable): what `load_run` gives.

    `config` and `summary` are config.json and summary.json as written (None where the
    run has not finished); `metrics` is metrics.csv as a pandas DataFrame (one row per
    seed × evaluation point); the checkpoint is read at the first `policy`, `incentive`,
    `env` or `iteration`."""

    dir: Path
    config: dict[str, Any] = dataclasses.field(repr=False)
    summary: dict[str, Any] | None = dataclasses.field(repr=False)

    @functools.cached_property
    def metrics(self):
        """metrics.csv as a `pandas.DataFrame`: columns `iteration`, `seed`, `eval/...`,
        `train/...`, ... (docs/usage.md, "A run directory")."""
        import pandas

        from pimbot.training import store

        return pandas.read_csv(self.dir / store.METRICS)

    @functools.cached_property
    def _loaded(self):
        from pimbot.training import runs

        return runs.load_run(self.dir)

    @property
    def seeds(self) -> tuple[int, ...]:
        """The seed values of the run."""
        run = self.config["run_config"]
        return tuple(range(run["first_seed"], run["first_seed"] + run["seeds"]))

    @property
    def iteration(self) -> int:
        """The training iteration of the checkpoint."""
        return self._loaded.iteration

    @property
    def env(self):
        """The run's environment (`pimbot.make(...)` with its parameters): `env.reset(key)`
        gives observations [N, obs_dim] for `policy`."""
        return self._loaded.resolved.env

    def _seed_index(self, seed: int | None) -> int:
        from pimbot.robot.export import seed_index_of

        return seed_index_of(self._loaded, seed)

    def _agent(self, agent: int, seed: int | None):
        from pimbot.robot.exportable import exported_agents

        n = self.env.num_agents
        check_int("agent", agent, 0, n - 1)
        index = self._seed_index(seed)
        try:
            agents = exported_agents(self._loaded, index)
        except InvalidParameter as error:
            raise InvalidParameter(
                f"{error} (pimbot.load_run(...).policy needs the same PolicyExport)"
            ) from None
        return agents[agent], self._loaded.seeds[index]

    def policy(self, agent: int, seed: int | None = None) -> Policy:
        """Agent `agent`'s trained policy, of seed `seed` (a seed value; None: the first)."""
        exported, seed = self._agent(agent, seed)
        env = self.env
        return Policy(agent, seed, env.num_actions, env.obs_dim, exported.logits)

    def incentive(self, agent: int, seed: int | None = None) -> Incentive:
        """Agent `agent`'s learned incentive function, of seed `seed` (None: the first).

        Raises:
            InvalidParameter: the learner has no incentive channel (pg, the Reciprocator).
        """
        exported, seed = self._agent(agent, seed)
        if exported.give is None:
            learner = self.config["run_config"]["learner"]
            raise InvalidParameter(
                f"incentive: learner {learner} has no incentive function (no incentive "
                f"channel); lio has one"
            )
        env = self.env
        return Incentive(agent, seed, env.num_agents, env.obs_dim, exported.give)

    def __repr__(self) -> str:
        run = self.config["run_config"]
        attack = f", attack {run['attack']}" if run.get("attack") else ""
        defenses = "".join(f", defense {name}" for name, _ in run.get("defenses") or [])
        final = ((self.summary or {}).get("final") or {}).get("eval/success")
        success = f", success {final['mean']:.3f}" if final else " (not finished)"
        return (
            f"Run({str(self.dir)!r}: {run['learner']} on {run['env_id']}{attack}{defenses}, "
            f"{run['seeds']} seeds × {run['iterations']} iterations{success})"
        )


def load_run(run_dir: str | Path, *, plugins: tuple[str, ...] | list[str] = ()) -> Run:
    """The run in `run_dir`: its config, summary, metrics, policies and incentives.

    `plugins` (files or modules, as --plugin) are loaded first: those a plugin's run was
    made with (config.json, "plugins"), for its policies.

    Raises:
        InvalidParameter: not a pimbot run directory (one line).
        PluginError: a plugin that does not load (one line).
    """
    from pimbot import plugins as loader
    from pimbot.training import store

    if plugins:
        loader.load_plugins(list(plugins))
    run_dir = Path(run_dir)
    config_path = run_dir / store.CONFIG
    if not config_path.is_file():
        raise InvalidParameter(f"run_dir: {run_dir} is not a pimbot run (no {store.CONFIG})")
    summary_path = run_dir / store.SUMMARY
    summary = store.read_json(summary_path) if summary_path.is_file() else None
    return Run(run_dir, store.read_json(config_path), summary)


@dataclasses.dataclass(frozen=True, eq=False)
class Suite:
    """A suite directory of `pimbot sweep` or `reproduce`: its index.json and its jobs."""

    dir: Path
    index: dict[str, Any] = dataclasses.field(repr=False)

    @property
    def jobs(self) -> dict[str, str]:
        """Job name -> its status (finished, failed, pending, ...)."""
        return {entry["name"]: entry["status"] for entry in self.index.get("jobs", [])}

    @property
    def failed(self) -> list[str]:
        """The jobs that failed (index.json says why)."""
        return [name for name, status in self.jobs.items() if status == "failed"]

    def run(self, name: str) -> Run:
        """The run of training job `name` (a key of `jobs`)."""
        from pimbot.cli.parsing import unknown_name

        if name not in self.jobs:
            raise InvalidParameter(unknown_name("name", "job", name, list(self.jobs)))
        return load_run(self.dir / name)


def load_suite(suite_dir: str | Path) -> Suite:
    """The suite in `suite_dir` (InvalidParameter where it has no index.json)."""
    from pimbot.suites.sweep import INDEX

    path = Path(suite_dir) / INDEX
    if not path.is_file():
        raise InvalidParameter(f"suite_dir: {suite_dir} is not a pimbot suite (no {INDEX})")
    return Suite(Path(suite_dir), json.loads(path.read_text()))


__all__ = [
    "Incentive",
    "Policy",
    "PolicyOutput",
    "Run",
    "Suite",
    "load_run",
    "load_suite",
    "report",
    "sweep",
    "train",
]
