"""Plugins are checked for what their code does, not what they declare: each broken plugin
below (a one-file plugin written to tmp_path) ends `pimbot train` with one line naming its
file, line and what was expected, exit status 2, and no run directory; the built-ins and
the documented examples pass the same checks."""

from __future__ import annotations

import dataclasses
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import jax
import jax.numpy as jnp
import pytest

from pimbot import attacks, cli, defenses, envs, learners, plugins
from pimbot.contracts import attack as attack_contract
from pimbot.contracts import conformance, preflight
from pimbot.contracts import defense as defense_contract
from pimbot.contracts import learner as learner_contract
from pimbot.errors import InvalidParameter

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = sorted((ROOT / "examples" / "plugins").glob("*.py"))
TINY = ["--seeds", "2", "--iterations", "20", "--eval-period", "10", "--eval-episodes", "2"]

HEADER = """\
from typing import ClassVar

import jax.numpy as jnp
from flax import struct

from pimbot.attacks import Attack, register
from pimbot.contracts.defense import Defense
from pimbot.contracts.defense import register as register_defense
"""


def write(directory: Path, name: str, body: str) -> Path:
    """A plugin file `name`.py: the imports above, then `body`."""
    path = directory / f"{name}.py"
    path.write_text(HEADER + textwrap.dedent(body))
    return path


def line_of(path: Path, text: str) -> int:
    """The number of the first line of `path` containing `text`."""
    return next(i for i, line in enumerate(path.read_text().splitlines(), 1) if text in line)


def refused(capsys, argv: list[str], out: Path) -> str:
    """Runs `pimbot train ... --out out` in this process: exit 2, one line, no run
    directory. Returns the line (without the `pimbot: error: ` prefix)."""
    code = cli.main([*argv, "--quiet", "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2, err
    assert err.startswith("pimbot: error: ") and len(err.strip().splitlines()) == 1, err
    assert not out.exists()
    return err.strip().removeprefix("pimbot: error: ")


def refused_in_subprocess(argv: list[str], out: Path, cwd: Path) -> str:
    """The same in a fresh `python -m pimbot.cli` (for a plugin env that stays registered)."""
    command = [sys.executable, "-m", "pimbot.cli", *argv, "--quiet", "--out", str(out)]
    env = {**os.environ, "PIMBOT_PLUGINS": ""}
    done = subprocess.run(command, capture_output=True, text=True, cwd=cwd, env=env)
    assert done.returncode == 2, done.stderr
    err = done.stderr
    assert err.startswith("pimbot: error: ") and len(err.strip().splitlines()) == 1, err
    assert not out.exists()
    return err.strip().removeprefix("pimbot: error: ")


# --- at registration: declared hooks ⇔ overridden methods, static text fields -----------

EMIT = """
    def emit(self, state, key, given_so_far):
        n = given_so_far.shape[0]
        return jnp.ones((n, n)), jnp.full((n, n), 5.0)
"""

REGISTRATION_CASES = {
    "misspelt": (
        '    hooks: ClassVar[tuple[str, ...]] = ("emit", "observe")\n'
        + EMIT
        + "\n    def observe_(self, state, key, outcome):\n        return state\n",
        "hooks: ClassVar",
        "hooks lists 'observe' but the class does not override observe(); its method "
        "observe_() is misspelt: rename it observe",
    ),
    "listed_only": (
        '    hooks: ClassVar[tuple[str, ...]] = ("emit", "policy_sign")\n' + EMIT,
        "hooks: ClassVar",
        "hooks lists 'policy_sign' but the class does not override policy_sign()",
    ),
    "unlisted": (
        '    hooks: ClassVar[tuple[str, ...]] = ("act",)\n'
        "\n    def act(self, state, key, actions, at):\n        return actions\n" + EMIT,
        "def emit",
        "emit() overrides the hook point 'emit', which hooks does not list: add it to hooks",
    ),
    "near_miss": (
        '    hooks: ClassVar[tuple[str, ...]] = ("act",)\n'
        "\n    def act(self, state, key, actions, at):\n        return actions\n"
        + EMIT.replace("def emit", "def emit2"),
        "def emit2",
        "method emit2() is no hook point and would never be called: did you mean emit()?",
    ),
    "text_field": (
        '    label: str = "loud"\n    hooks: ClassVar[tuple[str, ...]] = ("emit",)\n' + EMIT,
        "label: str",
        "field label (str) is a traced pytree leaf; mark it label: str = "
        "struct.field(pytree_node=False",
    ),
}


@pytest.mark.parametrize("case", sorted(REGISTRATION_CASES))
def test_an_attack_whose_code_breaks_what_it_declares_is_refused_at_registration(
    case, tmp_path, capsys
):
    body, marker, expected = REGISTRATION_CASES[case]
    name = f"contract_{case}"
    source = "@register\n@struct.dataclass\nclass Broken(Attack):\n"
    path = write(tmp_path, name, f"{source}    name: ClassVar[str] = {name!r}\n{body}")
    argv = ["train", "escape_room-v0", "--plugin", str(path), "--attack", name, *TINY]
    line = refused(capsys, argv, tmp_path / "run")
    assert line.startswith(f"{path}:{line_of(path, marker)}: attack {name}: {expected}"), line
    assert name not in attacks.registered()


def test_a_defense_hook_listed_under_another_name_is_refused(tmp_path):
    path = write(
        tmp_path,
        "contract_defense_typo",
        """
        @struct.dataclass
        class Capped(Defense):
            name: ClassVar[str] = "contract_defense_typo"
            hooks: ClassVar[tuple[str, ...]] = ("learning_incentive",)
        """,
    )
    module = plugins.load(str(path))
    with pytest.raises(conformance.ContractError) as caught:
        defense_contract.register(module.Capped)
    message = str(caught.value)
    assert message.startswith(f"{path}:{line_of(path, 'hooks: ClassVar')}: defense ")
    assert "unknown hook point 'learning_incentive' (did you mean 'learning_incentives'?)" in (
        message
    )


# --- at trace time: each hook's output against the contract, before anything is written -


def test_a_defense_returning_t_n_instead_of_t_n_n_is_refused_before_training(tmp_path, capsys):
    path = write(
        tmp_path,
        "contract_flat_cap",
        """
        @register_defense
        @struct.dataclass
        class FlatCap(Defense):
            cap: float = 1.0
            name: ClassVar[str] = "contract_flat_cap"
            hooks: ClassVar[tuple[str, ...]] = ("learning_incentives",)

            def learning_incentives(self, state, ctx):
                return jnp.minimum(ctx.accepted, self.cap).sum(axis=1), state, {}
        """,
    )
    argv = ["train", "escape_room-v0", "--plugin", str(path), "--defense", "contract_flat_cap"]
    line = refused(capsys, [*argv, *TINY], tmp_path / "run")
    assert line == (
        f"{path}:{line_of(path, 'def learning_incentives')}: defense contract_flat_cap: "
        "learning_incentives returned accepted float32[5, 2]; expected float32[5, 2, 2] "
        "([T, N giver, N recipient])"
    )


def test_an_exception_inside_a_hook_is_one_line_at_the_plugins_line(tmp_path, capsys):
    path = write(
        tmp_path,
        "contract_boom",
        """
        @register
        @struct.dataclass
        class Boom(Attack):
            name: ClassVar[str] = "contract_boom"
            hooks: ClassVar[tuple[str, ...]] = ("emit",)

            def emit(self, state, key, given_so_far):
                n = given_so_far.shape[0]
                offset = jnp.zeros((n, n)) + {"amount": 1.0}["amuont"]
                return jnp.ones((n, n)), offset
        """,
    )
    argv = ["train", "escape_room-v0", "--plugin", str(path), "--attack", "contract_boom"]
    line = refused(capsys, [*argv, *TINY], tmp_path / "run")
    assert line == (
        f"{path}:{line_of(path, 'amuont')}: KeyError: 'amuont' (in attack contract_boom, "
        "emit(); PIMBOT_DEBUG=1 shows the traceback)"
    )


def test_an_exception_in_init_state_is_one_line_before_anything_is_written(tmp_path, capsys):
    path = write(
        tmp_path,
        "contract_bad_state",
        """
        @register
        @struct.dataclass
        class BadState(Attack):
            name: ClassVar[str] = "contract_bad_state"
            hooks: ClassVar[tuple[str, ...]] = ("observe",)

            def init_state(self, key, num_agents, adversary):
                return {"count": jnp.zeros(num_agents)[num_agents + 1 :].item()}

            def observe(self, state, key, outcome):
                return state
        """,
    )
    argv = ["train", "ipd-v0", "--plugin", str(path), "--attack", "contract_bad_state", *TINY]
    line = refused(capsys, argv, tmp_path / "run")
    assert line.startswith(f"{path}:{line_of(path, '.item()')}: "), line
    assert line.endswith(
        "(in attack contract_bad_state, init_state(); PIMBOT_DEBUG=1 shows the traceback)"
    )


def test_a_plugin_that_raises_on_import_names_its_line(tmp_path, capsys):
    path = tmp_path / "contract_import_error.py"
    path.write_text("import math\n\nRATE = math.log(0)\n")
    line = refused(capsys, ["train", "ipd-v0", "--plugin", str(path), *TINY], tmp_path / "run")
    assert line == f"plugin: cannot import {path}: {path}:3: ValueError: math domain error"


def test_a_plugin_error_keeps_the_full_traceback_for_debug(tmp_path, monkeypatch):
    path = write(
        tmp_path,
        "contract_boom_debug",
        """
        def amount():
            return 1 / 0

        @register
        @struct.dataclass
        class BoomDebug(Attack):
            name: ClassVar[str] = "contract_boom_debug"
            hooks: ClassVar[tuple[str, ...]] = ("policy_sign",)

            def policy_sign(self, state, num_agents):
                return jnp.ones((num_agents,)) * amount()
        """,
    )
    boom = plugins.load(str(path)).BoomDebug()
    with pytest.raises(conformance.PluginCodeError) as caught:
        boom.policy_sign({}, 2)
    assert str(caught.value).startswith(f"{path}:{line_of(path, '1 / 0')}: ZeroDivisionError")
    text = plugins.full_traceback(caught.value)
    assert "ZeroDivisionError: division by zero" in text and f'File "{path}"' in text
    monkeypatch.setenv(plugins.DEBUG_VAR, "")
    assert not plugins.debug_enabled() and plugins.debug_enabled(True)
    monkeypatch.setenv(plugins.DEBUG_VAR, "1")
    assert plugins.debug_enabled()
    assert plugins.failure_line(caught.value.__cause__).startswith(f"{path}:")


# --- environments and learner defaults --------------------------------------------------


def tiny_env_variant(directory: Path, env_id: str, *edits: tuple[str, str]) -> Path:
    """examples/plugins/tiny_env.py under another id, with `edits` (old, new) made."""
    text = (ROOT / "examples" / "plugins" / "tiny_env.py").read_text()
    text = text.replace("public_goods_game-v0", env_id)
    for old, new in edits:
        assert old in text
        text = text.replace(old, new)
    path = directory / f"{env_id.replace('-', '_')}.py"
    path.write_text(text)
    return path


def test_an_env_missing_a_method_is_refused_when_its_plugin_loads(tmp_path):
    start = "    def episode_success"
    text = (ROOT / "examples" / "plugins" / "tiny_env.py").read_text()
    method = text[text.index(start) : text.index("SMALL = ")]
    path = tiny_env_variant(tmp_path, "no_success_game-v0", (method, ""))
    argv = ["train", "no_success_game-v0", "--plugin", str(path), *TINY]
    line = refused_in_subprocess(argv, tmp_path / "run", tmp_path)
    assert line == (
        f"{path}:{line_of(path, 'class PublicGoods')}: env no_success_game-v0: no method "
        "episode_success; the Env protocol (pimbot.envs.core.Env) needs "
        "episode_success(success_steps, num_steps, env_return) -> score"
    )


def test_env_learner_defaults_of_a_wrong_type_are_refused(tmp_path):
    edit = ('"policy_hidden": (16,)', '"policy_hidden": 16')
    path = tiny_env_variant(tmp_path, "bad_defaults_game-v0", edit)
    argv = ["train", "bad_defaults_game-v0", "--plugin", str(path), *TINY]
    line = refused_in_subprocess(argv, tmp_path / "run", tmp_path)
    assert line == (
        "policy_hidden: lio's default on bad_defaults_game-v0 must be a tuple of ints, as "
        f"(64, 32), got 16 (int) (declared by env bad_defaults_game-v0, "
        f"{path}:{line_of(path, 'class PublicGoods')})"
    )


def test_learner_defaults_of_a_wrong_type_are_refused_where_declared(tmp_path, capsys):
    path = tmp_path / "contract_bad_hparam.py"
    declaration = 'learners.set_env_defaults("lio", "ipd-v0", lr_policy="fast")'
    path.write_text(f"from pimbot import learners\n\n{declaration}\n")
    argv = ["train", "ipd-v0", "--plugin", str(path), *TINY]
    line = refused(capsys, argv, tmp_path / "run")
    assert line == (
        "lr_policy: lio's default on ipd-v0 must be a number, got 'fast' (str) "
        f"(declared at {path}:3)"
    )
    assert learners.default_config("lio", "ipd-v0").lr_policy != "fast"


def test_a_learner_entry_declares_defaults_of_its_hyperparameters_types():
    lio = learners.get("lio")
    bad = dataclasses.replace(lio, name="contract_lio", env_defaults={"ipd-v0": {"gamma": "0.9"}})
    with pytest.raises(InvalidParameter, match=r"^gamma: contract_lio's default on ipd-v0 must be"):
        learner_contract.register(bad)
    wrong = dataclasses.replace(lio, name="contract_lio", base_overrides=(("lr_cost", True),))
    with pytest.raises(InvalidParameter, match=r"^lr_cost: base_overrides must be a number, got"):
        learner_contract.register(wrong)
    assert "contract_lio" not in learners.registered()


def test_a_learner_listing_a_misspelt_hook_point_is_refused_at_registration():
    lio = learners.get("lio")
    misspelt = dataclasses.replace(
        lio, name="contract_lio", attack_hooks=(*lio.attack_hooks, "adversary_stepp")
    )
    with pytest.raises(
        InvalidParameter,
        match=r"^attack_hooks: 'adversary_stepp' is no attack hook point "
        r"\(did you mean 'adversary_step'\?\); allowed: act, emit, .* \(learner contract_lio, "
        r"declared at .*test_plugin_contracts\.py:\d+\)$",
    ):
        learner_contract.register(misspelt)
    elsewhere = dataclasses.replace(lio, name="contract_lio", defense_hooks=("emit",))
    with pytest.raises(InvalidParameter, match=r"^defense_hooks: 'emit' is no defense hook"):
        learner_contract.register(elsewhere)
    one_string = dataclasses.replace(lio, name="contract_lio", defense_hooks="acting_epsilon")
    with pytest.raises(InvalidParameter, match=r"^defense_hooks: contract_lio's must be a tuple"):
        learner_contract.register(one_string)
    assert "contract_lio" not in learners.registered()


# --- what passes: the built-ins, the documented examples, and their values unchanged ----


def test_the_built_ins_keep_their_contracts():
    for name in attacks.registered():
        cls = attacks.attack_class(name)
        optional = cls.optional_hooks
        conformance.check_hooked_class(
            cls, attack_contract.Attack, attack_contract.HOOKS, "a", optional
        )
    for name in defenses.registered():
        cls = defenses.defense_class(name)
        conformance.check_hooked_class(cls, defense_contract.Defense, defense_contract.HOOKS, "d")


@pytest.mark.parametrize("example", EXAMPLES, ids=lambda p: p.stem)
def test_the_documented_examples_pass_every_check(example):
    module = plugins.load(str(example)).__name__
    preflight.check_plugins()  # tiny_env: check_env on its default instance, its defaults
    learner = learners.get("lio")
    env = envs.make("escape_room-v0")
    config = learner.default_config(envs.spec("escape_room-v0"))
    for name in attacks.registered():
        if attacks.attack_class(name).__module__ == module:
            attack = attacks.make(name, env.num_agents)
            preflight.check_run(learner, env, config, attack, (), 2)
    for name in defenses.registered():
        if defenses.defense_class(name).__module__ == module:
            run_defenses = (defenses.make(name, env.num_agents),)
            preflight.check_run(learner, env, config, attacks.NO_ATTACK, run_defenses, 2)


def test_checked_hooks_return_the_plugins_values_unchanged():
    fake = attacks.make("fake_incentive", 3, amount=7.0)
    method = type(fake).emit
    assert method.checked_hook == "emit" and method.__wrapped__ is not method
    given = jnp.zeros((3, 3))
    key = jax.random.PRNGKey(0)
    checked, unchecked = fake.emit({}, key, given), method.__wrapped__(fake, {}, key, given)
    for got, want in zip(checked, unchecked, strict=True):
        assert (got == want).all()
    assert type(attacks.make("admo", 2)).init_state is not attack_contract.Attack.init_state


def test_a_learner_with_an_incentive_channel_must_consult_emit():
    """`has_incentives` is read: its rollouts pass `give`, so `emit` acts on what it pays;
    a learner declaring the channel without the hook is refused at registration."""
    lio = learners.get("lio")
    hooks = tuple(h for h in lio.attack_hooks if h != "emit")
    silent = dataclasses.replace(lio, name="contract_lio", attack_hooks=hooks)
    with pytest.raises(InvalidParameter, match=r"^attack_hooks: learner contract_lio declares"):
        learner_contract.register(silent)
    assert "contract_lio" not in learners.registered()
