"""The registries hold the facts: registered names appear only where they are registered,
and a learner's defaults on an env are declared in its registry entry, by env id."""

from __future__ import annotations

import ast
import dataclasses
from pathlib import Path

import pytest

from pimbot import attacks, defenses, envs, learners
from pimbot.contracts import learner as learner_contract
from pimbot.errors import InvalidParameter
from pimbot.training.config import RunConfig, resolve

SRC = Path(__file__).resolve().parents[1] / "src" / "pimbot"

NAMES_MAY_APPEAR_IN = {
    # where the names are registered: the registrations themselves
    "envs/__init__.py": "registers the built-in envs under their ids",
    "envs/jaxmarl.py": "registers JaxMARL's envs under their ids (when JaxMARL is loaded)",
    "learners/__init__.py": "registers the built-in learners, with their defaults by env id",
    # data that names what it is about
    "suites/presets.py": "the paper's suite as data: the jobs it names are the paper's",
    "analysis/sections/attack_claims.py": "the paper's claims C1-C5, each about a named attack",
    "analysis/sections/attacks.py": "the paper's attack figures (Figs. 1-5), of LIO's attacks",
    "analysis/sections/reciprocators.py": "the paper's claim C7, about the Reciprocator",
    "analysis/sections/device.py": "the paper's claim C8, the benign vs ADMO controllers",
    "profiling/decision_loop.py": "CONTROLLERS, the profiled controllers, named after the attack",
    "profiling/report.py": "the paired profile compares the CONTROLLERS by name",
    "profiling/runner.py": "the paired profile compares the CONTROLLERS by name",
    # copies the command line keeps so that --help imports no JAX; tests check they are equal
    "cli/commands.py": "CONTROLLERS and the default learner, checked equal by tests",
    "cli/options.py": "CHECK_ENV, the env `pimbot check` runs on where the file names none",
}
"""Modules allowed to write a registered name (the attack and defense modules name theirs
in their class bodies, `name = "..."`, which the scan knows as the definition)."""


def registered_names() -> dict[str, str]:
    """Every registered name of pimbot's own (not a plugin another test loaded) -> kind."""
    own = "pimbot."
    names = {
        e: "env" for e in envs.registered() if envs.spec(e).constructor.__module__.startswith(own)
    }
    for name in learners.registered():
        if learners.get(name).init.__module__.startswith(own):
            names[name] = "learner"
    for kind, registry in (("attack", attacks), ("defense", defenses)):
        for name in registry.registered():
            cls = registry.attack_class(name) if kind == "attack" else defenses.defense_class(name)
            if cls.__module__.startswith(own):
                names[name] = kind
    return names


def _definitions_and_docstrings(tree: ast.AST) -> set[int]:
    """ids of the string constants that are docstrings or a class's own `name`."""
    skipped = set()
    for node in ast.walk(tree):
        if not isinstance(node, ast.Module | ast.ClassDef | ast.FunctionDef | ast.AsyncFunctionDef):
            continue
        body = node.body
        if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant):
            skipped.add(id(body[0].value))
        if isinstance(node, ast.ClassDef):
            for statement in body:
                target = getattr(statement, "target", None) or (
                    statement.targets[0] if isinstance(statement, ast.Assign) else None
                )
                if isinstance(target, ast.Name) and target.id == "name":
                    skipped.add(id(statement.value))
    return skipped


def names_outside_registries() -> list[str]:
    """`path:line: 'name' (kind)` for every registered name written as a string constant
    in a module not allowed to name it."""
    names = registered_names()
    found = []
    for path in sorted(SRC.rglob("*.py")):
        module = path.relative_to(SRC).as_posix()
        if module in NAMES_MAY_APPEAR_IN:
            continue
        tree = ast.parse(path.read_text(), filename=str(path))
        skipped = _definitions_and_docstrings(tree)
        for node in ast.walk(tree):
            if (
                isinstance(node, ast.Constant)
                and isinstance(node.value, str)
                and node.value in names
                and id(node) not in skipped
            ):
                found.append(f"src/pimbot/{module}:{node.lineno}: {node.value!r}")
    return sorted(found, key=lambda line: (line.split(":")[0], int(line.split(":")[1])))


def test_the_scan_knows_every_kind_of_registered_name():
    kinds = set(registered_names().values())
    assert kinds == {"env", "learner", "attack", "defense"}


def test_registered_names_appear_only_in_their_registries():
    found = names_outside_registries()
    assert not found, (
        f"{len(found)} registered names outside their registries (read the fact from the "
        "registry entry instead):\n" + "\n".join(found)
    )


# --- learners' per-env defaults live in their entries ----------------------------------


@pytest.fixture
def restored_learners():
    """Every learner entry as it was before the test (`set_env_*` replaces entries)."""
    saved = {name: learners.get(name) for name in learners.registered()}
    yield
    for definition in saved.values():
        learner_contract.register(definition, replace=True)


def test_a_plugin_declares_defaults_on_a_built_in_env_without_registering_it(
    restored_learners,
):
    before = learners.default_config("lio", "ipd-v0")
    learners.set_env_defaults("lio", "ipd-v0", lr_policy=0.05)
    after = learners.default_config("lio", "ipd-v0")
    assert after == dataclasses.replace(before, lr_policy=0.05)  # merged over the column
    resolved = resolve(RunConfig(env_id="ipd-v0", learner="lio", iterations=10))
    assert resolved.learner_config.lr_policy == 0.05
    assert learners.default_config("lio", "escape_room-v0").lr_policy != 0.05


def test_env_params_declared_for_a_learner_are_its_runs_defaults(restored_learners):
    learners.set_env_params("pg", "stag_hunt_matrix-v0", max_steps=7)
    assert resolve(RunConfig(env_id="stag_hunt_matrix-v0", learner="pg")).env.max_steps == 7
    given = RunConfig(env_id="stag_hunt_matrix-v0", learner="pg", env_params=(("max_steps", 3),))
    assert resolve(given).env.max_steps == 3  # the run's own parameter wins
    assert learners.declared_env_params("stag_hunt_matrix-v0") == {"pg": {"max_steps": 7}}


def test_nl_takes_the_reciprocators_declarations_under_its_own_overrides(restored_learners):
    assert learners.default_env_params("nl", "ipd-v0") == {"max_steps": 32}
    assert learners.declared_env_params("ipd-v0") == {"reciprocator": {"max_steps": 32}}
    learners.set_env_defaults("reciprocator", "ipd-v0", num_envs=64, reciprocal_weight=2.0)
    nl = learners.default_config("nl", "ipd-v0")
    assert (nl.num_envs, nl.reciprocal_weight) == (64, 0.0)  # NL's own weight 0 stays


def test_unknown_learner_or_hyperparameter_is_refused_by_name():
    with pytest.raises(InvalidParameter, match="^lr_polcy: not a hyperparameter of lio"):
        learners.set_env_defaults("lio", "ipd-v0", lr_polcy=1.0)
    with pytest.raises(InvalidParameter, match="^learner: unknown learner 'lo'"):
        learners.set_env_params("lo", "ipd-v0", max_steps=3)


def test_built_in_defaults_are_declared_by_the_learners_not_the_envs():
    for env_id in envs.registered():
        if envs.spec(env_id).constructor.__module__.startswith("pimbot."):
            assert not envs.spec(env_id).learner_defaults, env_id
            assert not envs.spec(env_id).learner_env_defaults, env_id
    assert learners.get("reciprocator").env_params == {"ipd-v0": {"max_steps": 32}}
    assert set(learners.get("lio").env_defaults) == {"ipd-v0", "stag_hunt_matrix-v0"}


def test_a_run_without_an_evaluation_takes_its_envs():
    assert RunConfig(env_id="escape_room-v0", iterations=400).resolved_eval() == (100, 10)
    assert RunConfig(env_id="stag_hunt-v0", iterations=5000).resolved_eval() == (1000, 10)
    short = RunConfig(env_id="ipd-v0", iterations=300)  # evaluated once, at its end
    assert short.resolved_eval() == (300, 10)
    given = RunConfig(env_id="ipd-v0", iterations=300, eval_period=100, eval_episodes=3)
    assert given.resolved_eval() == (100, 3)


# --- the display order of conditions comes from the attack registry ---------------------


def test_condition_order_is_the_built_in_attacks_in_registration_order():
    assert attacks.CONDITION_ORDER == (
        "clean",
        "self_centered",
        "fake_incentive",
        "bypass",
        "reverse",
        "admo_stealthy",
        "admo_disrupt",
        "admo_code_stealthy",
        "admo_code_disrupt",
        "negated_env_reward",
    )
    built_in = [
        n for n in attacks.registered() if attacks.attack_class(n).__module__.startswith("pimbot.")
    ]
    derived = [c for name in built_in for c in attacks.conditions(name)]
    assert tuple(derived) == attacks.CONDITION_ORDER[1:]


def test_the_command_lines_default_learner_is_the_registrys():
    from pimbot.cli import commands

    assert commands.Train.learner == learners.DEFAULT_LEARNER
