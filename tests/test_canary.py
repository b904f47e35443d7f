"""`pimbot check FILE.py`: a plugin's hooks counted where the compiled program runs them, and
compared with doing nothing; exit 0 when every hook ran and did something, 1 with one line
per problem, 2 for bad input."""

from __future__ import annotations

import re
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import pytest

from pimbot import attacks, cli
from pimbot.training import canary_probes

EXAMPLES = Path(__file__).resolve().parents[1] / "examples" / "plugins"
TINY = ["--seeds", "1", "--iterations", "10"]

QUIET_ATTACK = """
from typing import ClassVar

from flax import struct

from pimbot.attacks import Attack, register


@register
@struct.dataclass
class QuietBypass(Attack):
    \"\"\"Meant to make the adversary idle; its act returns the actions it was given.\"\"\"

    name: ClassVar[str] = "quiet_bypass"
    lever: ClassVar[str] = "policy"
    hooks: ClassVar[tuple[str, ...]] = ("act",)

    def act(self, state, key, actions, at):
        return actions
"""

LAZY_LEARNER = """
import dataclasses

from pimbot import learners
from pimbot.learners import pg


def init(*args, **kwargs):
    return pg.init(*args, **kwargs)


learners.register(
    dataclasses.replace(
        learners.get("pg"),
        name="lazy_pg",
        init=init,
        attack_hooks=(*learners.get("pg").attack_hooks, "learning_rewards"),
    )
)
"""
"""A learner that declares a hook point (learning_rewards) its code never consults."""


@pytest.fixture(autouse=True)
def registries_as_they_were():
    """The plugins these tests load register in this process; the next test file in the
    same worker sees the registries as they were (its "allowed: ..." lists). The built-ins
    are registered first: saved before their first import, the registries would be
    restored empty, with the built-in modules already imported (never registering again)."""
    import pimbot.attacks  # noqa: F401
    import pimbot.defenses  # noqa: F401
    import pimbot.learners  # noqa: F401
    from pimbot import plugins
    from pimbot.contracts.attack import ATTACKS
    from pimbot.contracts.defense import DEFENSES
    from pimbot.contracts.learner import LEARNERS
    from pimbot.envs import core

    saved = [(r, dict(r._entries)) for r in (ATTACKS, DEFENSES, LEARNERS)]
    saved += [(plugins, dict(plugins._LOADED))]
    envs = dict(core._REGISTRY)
    yield
    loaded = saved.pop()[1]
    for key, module in plugins._LOADED.items():  # a plugin loaded again registers again
        if key not in loaded:
            sys.modules.pop(getattr(module, "__name__", ""), None)
    plugins._LOADED.clear()
    plugins._LOADED.update(loaded)
    for registry, entries in saved:
        registry._entries.clear()
        registry._entries.update(entries)
    core._REGISTRY.clear()
    core._REGISTRY.update(envs)


def _rows(text: str) -> dict[str, list[str]]:
    """hook -> the cells of its table row (split on runs of two spaces)."""
    rows = [re.split(r"\s{2,}", line.strip()) for line in text.splitlines()]
    return {row[2]: row for row in rows if len(row) > 4 and row[0] != "part"}


def test_a_counted_hook_reports_calls_and_answers_the_no_op_when_off():
    attack = attacks.make("fake_incentive", 2)
    tally = canary_probes.Tally()
    given = jnp.zeros((2, 2))
    key = jax.random.PRNGKey(0)
    outs = {}
    for on in (True, False):
        counted = canary_probes.instrument(attack, ("emit",), tally, "fake", on)
        outs[on] = jax.jit(lambda a: a.emit({}, key, given))(counted)
    jax.effects_barrier()
    assert tally.of("fake", "emit", True) == (1, 1)
    assert tally.of("fake", "emit", False) == (1, 1)  # the hook still ran; its output unused
    assert jnp.array_equal(outs[True][1], attack.emit({}, key, given)[1])
    assert jnp.array_equal(outs[False][0], jnp.ones((2, 2)))
    assert jnp.array_equal(outs[False][1], jnp.zeros((2, 2)))


def test_a_working_plugin_has_every_hook_called_and_effective(capsys):
    plugin = EXAMPLES / "adaptive_fake_incentive.py"
    assert cli.main(["check", str(plugin), *TINY]) == 0, capsys.readouterr()
    out = capsys.readouterr().out
    rows = _rows(out)
    for hook in ("emit", "observe"):
        part, setting, _, calls, changed, differs = rows[hook][:6]
        assert part == "attack adaptive_fake_incentive"
        assert setting.startswith("escape_room-v0 · lio")
        assert int(calls) > 0 and int(changed) > 0
        assert differs == "yes"
    assert "problem:" not in out


def test_a_hook_that_does_nothing_is_reported_with_exit_1(tmp_path, capsys):
    plugin = tmp_path / "quiet.py"
    plugin.write_text(QUIET_ATTACK)
    assert cli.main(["check", str(plugin), "--learner", "pg", *TINY]) == 1
    out = capsys.readouterr().out
    _, setting, _, calls, changed, differs = _rows(out)["act"][:6]
    assert setting.startswith("escape_room-v0 · pg")
    assert int(calls) > 0 and changed == "0" and differs == "no"
    problems = [line for line in out.splitlines() if line.startswith("problem:")]
    assert len(problems) == 1
    assert "attack quiet_bypass: hook act ran" in problems[0]
    assert "never differed from doing nothing" in problems[0]


def test_a_learner_hook_point_never_consulted_is_reported(tmp_path, capsys):
    plugin = tmp_path / "lazy.py"
    plugin.write_text(LAZY_LEARNER)
    argv = ["check", str(plugin), "--seeds", "1", "--iterations", "5"]
    assert cli.main(argv) == 1
    out = capsys.readouterr().out
    rows = _rows(out)
    assert rows["learning_rewards"][3] == "0"
    assert int(rows["act"][3]) > 0 and int(rows["observe"][3]) > 0
    assert "parameters moved" in out
    problems = [line for line in out.splitlines() if line.startswith("problem:")]
    assert problems == [
        "problem: learner lazy_pg: declares hook point learning_rewards but never consulted it"
    ]


SIGN_LINE = "    sign = attack.policy_sign(state.attack_state, n)\n"


def _actor_critic(tmp_path, sign_used: bool) -> Path:
    """examples/plugins/actor_critic.py, or the same learner asking `policy_sign` and
    dropping its answer (every agent then steps with sign +1)."""
    source = (EXAMPLES / "actor_critic.py").read_text()
    assert source.count(SIGN_LINE) == 1
    if not sign_used:
        ignored = "    attack.policy_sign(state.attack_state, n)\n    sign = jnp.ones((n,))\n"
        source = source.replace(SIGN_LINE, ignored)
    plugin = tmp_path / f"actor_critic_{'used' if sign_used else 'ignored'}.py"
    plugin.write_text(source)
    return plugin


@pytest.mark.parametrize("sign_used", [True, False])
def test_a_learner_that_ignores_a_hook_output_is_reported(tmp_path, capsys, sign_used):
    plugin = _actor_critic(tmp_path, sign_used)
    argv = ["check", str(plugin), "--seeds", "1", "--iterations", "5"]
    assert cli.main(argv) == (0 if sign_used else 1)
    out = capsys.readouterr().out
    rows = _rows(out)
    assert int(rows["policy_sign"][3]) > 0  # consulted either way
    assert rows["policy_sign"][6] == ("yes" if sign_used else "no")
    for hook in ("act", "learning_rewards", "adversary_step", "observe"):
        assert rows[hook][6] == "yes", rows[hook]
    problems = [line for line in out.splitlines() if line.startswith("problem:")]
    if sign_used:
        assert problems == []
        assert "ok: learner actor_critic: trained" in out
        assert "each one's output perturbed" in out
    else:
        assert problems == [
            "problem: learner actor_critic: consults hook point policy_sign but ignores what "
            "it returns: with its output perturbed (the adversary's sign flipped) the "
            "learner's state and metrics after 5 iterations are the same, bit for bit"
        ]


def test_a_part_with_nothing_counted_gets_no_ok_line():
    """A defense whose every setting was skipped checked nothing: no ok line for it."""
    from pimbot.training import canary

    skipped = canary.Row("defense d", "escape_room-v0 · under attack a", "-", note="skipped")
    result = canary._hook_result("defense d", (skipped,))
    assert result.problems == () and result.checked == ()


@pytest.mark.parametrize(
    ("source", "expected"),
    [(None, "no such file"), ("x = 1\n", "registers no env, learner, attack or defense")],
)
def test_bad_input_is_one_line_and_exit_2(tmp_path, capsys, source, expected):
    plugin = tmp_path / "plugin.py"
    if source is not None:
        plugin.write_text(source)
    assert cli.main(["check", str(plugin)]) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and expected in lines[0]
    assert sorted(p.name for p in tmp_path.iterdir()) == (["plugin.py"] if source else [])
