"""Checks of plugins before anything is written: what they registered, and a run's program.

* `check_plugins()`, once the plugins are loaded: every environment a plugin registered
  is made with its defaults and passes `pimbot.envs.check_env` (an env whose constructor
  has required parameters is skipped: it has no default instance), and the learner
  defaults it declares name registered learners' hyperparameters with values of their
  types. (Attacks and defenses are checked when they register, learners' own defaults
  too: `conformance.check_hooked_class`, `learner.register`.)
* `check_run(...)`, before a run's directory is written: where any part of the run is a
  plugin's, one iteration of it (init, update, evaluate) is traced abstractly
  (`jax.eval_shape`: shapes only, nothing compiled or computed), so every hook's output
  check and every exception in the plugin's code is met before training starts, as one
  line at the plugin's file and line. A run whose structure this code (pimbot's sources,
  the plugin files loaded and each plugin part's own file) traced without error before
  is not traced again: the pass is recorded in the compilation cache's directory
  (`jax_setup.marker`). A change to a helper module a plugin imports (no plugin itself,
  not one of its parts' files) is not seen by it; the program's own trace still is.

Each failure is a `conformance.ContractError` (an `InvalidParameter`): one line, exit 2.
"""

from __future__ import annotations

import dataclasses
import functools
import inspect
from typing import Any

import jax

from pimbot import jax_setup, plugins
from pimbot.contracts import conformance
from pimbot.contracts.attack import state_metrics
from pimbot.contracts.conformance import ContractError, PluginCodeError
from pimbot.contracts.learner import LEARNERS, check_hparams
from pimbot.envs import check_env
from pimbot.envs.core import registered, spec
from pimbot.errors import InvalidParameter

ENV_METHODS = {
    "reset": "reset(key) -> (obs, state)",
    "step": "step(key, state, actions) -> (obs, state, rewards, done, info)",
    "obs_bounds": "obs_bounds() -> (low, high)",
    "episode_success": "episode_success(success_steps, num_steps, env_return) -> score",
}
"""The methods of the environment protocol (`pimbot.envs.core.Env`)."""


def check_plugins() -> None:
    """Checks every environment a plugin registered (see the module docstring).

    Raises:
        ContractError: one line naming the plugin's file and line.
        InvalidParameter: a learner default of the wrong type, naming where it was declared.
    """
    for env_id in registered():
        entry = spec(env_id)
        if conformance.is_builtin(entry.constructor):
            continue
        check_env_once(env_id, entry.constructor)
        check_declared_defaults(entry)


@functools.cache
def check_env_once(env_id: str, constructor) -> None:
    """`check_env` of `constructor()` (once per process and constructor), unless it has
    required parameters; a missing protocol method, a failed check or an exception in the
    env's code is one line at its file."""
    if _required_parameters(constructor):
        return
    where = conformance.location(constructor)
    files = [conformance.source_file(constructor) or ""]
    try:
        env = constructor()
    except InvalidParameter as error:
        raise ContractError(f"{where}: env {env_id}: its defaults are refused: {error}") from None
    except Exception as error:
        raise PluginCodeError(
            conformance.code_error(error, files, f"env {env_id}, made with its defaults", where)
        ) from error
    for name, signature in ENV_METHODS.items():
        if not callable(getattr(env, name, None)):
            raise ContractError(
                f"{where}: env {env_id}: no method {name}; the Env protocol "
                f"(pimbot.envs.core.Env) needs {signature}"
            )
    try:
        check_env(env)
    except AssertionError as error:
        raise ContractError(f"{where}: env {env_id}: {conformance.first_line(error)}") from error
    except Exception as error:
        raise PluginCodeError(
            conformance.code_error(error, files, f"env {env_id}, check_env", where)
        ) from error


def _required_parameters(constructor) -> list[str]:
    try:
        parameters = inspect.signature(constructor).parameters.values()
    except (TypeError, ValueError):
        return []
    return [
        p.name
        for p in parameters
        if p.default is inspect.Parameter.empty
        and p.kind not in (inspect.Parameter.VAR_POSITIONAL, inspect.Parameter.VAR_KEYWORD)
    ]


def check_declared_defaults(entry) -> None:
    """The learner defaults a plugin env's registration declares (`EnvSpec.learner_defaults`)
    name registered learners and their hyperparameters, with values of their types; its
    `learner_env_defaults` name the env's own parameters."""
    where = conformance.location(entry.constructor)
    for learner, values in entry.learner_defaults.items():
        definition = _learner(learner, entry.env_id, "learner_defaults", where)
        what = f"{learner}'s default on {entry.env_id}"
        check_hparams(definition, values, what, f"by env {entry.env_id}, {where}")
    allowed = entry.parameters() if dataclasses.is_dataclass(entry.constructor) else None
    for learner, values in entry.learner_env_defaults.items():
        _learner(learner, entry.env_id, "learner_env_defaults", where)
        unknown = [name for name in values if allowed is not None and name not in allowed]
        if unknown:
            raise ContractError(
                f"{where}: env {entry.env_id}: learner_env_defaults[{learner!r}] names "
                f"{unknown[0]!r}, no parameter of the env; allowed: {', '.join(allowed)}"
            )


def _learner(name: str, env_id: str, field: str, where: str):
    if name not in LEARNERS:
        raise ContractError(
            f"{where}: env {env_id}: {field} names learner {name!r}, which is not registered; "
            f"registered: {', '.join(LEARNERS.names())}"
        )
    return LEARNERS.get(name)


def check_run(learner, env, config, attack, defenses, eval_episodes: int) -> None:
    """Traces one iteration of a run abstractly where any part of it is a plugin's: the
    learner's `init`, `update` and `evaluate` (`jax.eval_shape`: no compilation, no number
    computed, nothing written), so the hooks' output checks run and an exception in plugin
    code is met before training starts. A run of built-ins only is not traced here (its
    program is traced when it compiles, with the same checks).

    Args:
        learner: the `LearnerDef`; env, config, attack, defenses: as the run takes them;
        eval_episodes: episodes of an evaluation.

    Raises:
        ContractError: one line at the plugin's file and line.
    """
    parts = [
        (f"learner {learner.name}", f) for f in (learner.init, learner.update, learner.evaluate)
    ]
    parts += [(f"env {type(env).__name__}", type(env)), (f"attack {attack.name}", type(attack))]
    parts += [(f"defense {defense.name}", type(defense)) for defense in defenses]
    plugin_parts = [(name, part) for name, part in parts if not conformance.is_builtin(part)]
    key = _trace_key(learner, env, config, attack, defenses, eval_episodes)
    if not plugin_parts or key in _TRACED:
        return
    passed = _passed_marker(key, [part for _, part in plugin_parts])
    if passed is not None and passed.exists():  # this code traced this structure before
        _TRACED.add(key)
        return

    def one_iteration(key):
        state = learner.init(key, env, config, attack, defenses)
        state, metrics = learner.update(state, env, config, attack, defenses)
        logged = state_metrics(attack, state, env.num_agents)  # as the runner reads them
        return learner.evaluate(key, state, env, config, eval_episodes, attack), metrics, logged

    try:
        jax.eval_shape(one_iteration, jax.random.PRNGKey(0))
    except InvalidParameter:
        raise
    except Exception as error:
        files = [conformance.source_file(part) or "" for _, part in plugin_parts]
        names = ", ".join(dict.fromkeys(name for name, _ in plugin_parts))
        where = f"a traced iteration with {names}"
        fallback = conformance.location(plugin_parts[0][1])
        raise PluginCodeError(conformance.code_error(error, files, where, fallback)) from error
    if key is not None:
        _TRACED.add(key)
    _mark_passed(passed)


def _passed_marker(key: Any, parts: list[Any]):
    """The file that records that this code traced a run of `key`'s structure without
    error, so a later process skips the trace (`jax_setup.marker`: in the compilation
    cache's directory, keyed by pimbot's sources and the plugin files loaded). Its name
    covers the key and each plugin part's class or function and the sha256 of its file.
    None where something could differ unseen: a key printed with an address, a part
    defined inside a function (it may close over values) or without a readable file; or
    where no cache is active."""
    if key is None:
        return None
    learner, env, config, *rest = key
    texts = [repr((learner, _typed(env), _typed(config), *rest))]
    for part in parts:
        qualname = getattr(part, "__qualname__", "<locals>")
        file = conformance.source_file(part)
        digest = plugins.file_sha256(file) if file else None
        if "<locals>" in qualname or digest is None:
            return None
        texts.append(f"{part.__module__}.{qualname} {digest}")
    if " at 0x" in texts[0]:
        return None
    return jax_setup.marker("preflight", "\n".join(texts))


def _typed(value: Any) -> tuple[str, Any]:
    """`value` with its class's module and name (two classes may print alike)."""
    return f"{type(value).__module__}.{type(value).__qualname__}", value


def _mark_passed(path) -> None:
    if path is None:
        return
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.touch()
    except OSError:  # a read-only cache: the next process traces again
        pass


_TRACED: set = set()
"""The runs this process has traced (`_trace_key`): a sweep's jobs that differ only in
numbers are traced once."""


def _trace_key(learner, env, config, attack, defenses, eval_episodes) -> Any:
    """What the trace of a run depends on: the learner, env and config (hashable frozen
    dataclasses), the attack's and defenses' structure and leaf shapes, not their numbers;
    None where one of them cannot be hashed."""
    leaves, structure = jax.tree.flatten((attack, tuple(defenses)))
    key = (
        learner.name,
        env,
        config,
        structure,
        tuple(map(conformance.aval, leaves)),
        eval_episodes,
    )
    try:
        hash(key)
    except TypeError:
        return None
    return key
