"""What `pimbot export` writes of a learner: each agent's policy (and incentives) as a
function of that agent's inputs alone, with its trained parameters.

A learner is exportable where its `LearnerDef.acting` has a `PolicyExport` here
(`register_export`): pimbot's own learners are registered below, built from the same
network modules their `acting` uses (`pimbot.nets`, `pimbot.learners.reciprocator_nets`,
`pimbot.learners.lio.incentive_input`); a plugin learner registers its own. The export
checks every one against the learner's actor (`pimbot.robot.export_check`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from pimbot import learners, nets
from pimbot.contracts.attack import agent_row
from pimbot.errors import InvalidParameter
from pimbot.learners import lio, pg, reciprocator, reciprocator_nets
from pimbot.training import runs

OBSERVATION, ACTIONS = "observation", "actions"
"""The ONNX models' input names."""
LOGITS, PROBABILITIES, INCENTIVES = "logits", "probabilities", "incentives"
"""The ONNX models' output names."""


def policy_file(agent: int) -> str:
    return f"agent_{agent}_policy.onnx"


def incentive_file(agent: int) -> str:
    return f"agent_{agent}_incentive.onnx"


@dataclasses.dataclass(frozen=True)
class PolicyExport:
    """How a learner's trained agents become functions of one agent's inputs."""

    policy: Callable[[Any, Any, Any, int], Callable[[jax.Array], jax.Array]]
    """policy(env, cfg, state, i) -> logits(obs [B, obs_dim]) -> [B, num_actions]: agent i's
    action logits; its `acting` samples from their softmax."""
    incentive: Callable[[Any, Any, Any, int], Callable[[jax.Array, jax.Array], jax.Array]] | None
    """incentive(env, cfg, state, i) -> give(obs [B, obs_dim], actions int32 [B, N]) -> [B, N]:
    what agent i gives each agent after the joint action (row i of `Actor.give`); None:
    the learner has no incentive channel."""


EXPORTS: dict[Callable, PolicyExport] = {}
"""`LearnerDef.acting` -> its `PolicyExport` (the learners sharing an `acting` share it)."""


def register_export(acting: Callable, export: PolicyExport) -> None:
    """Makes every learner whose `LearnerDef.acting` is `acting` exportable."""
    EXPORTS[acting] = export


def mlp_policy(env, cfg, state, agent: int):
    """Agent `agent`'s logits from `nets.policy_module` (PG's and LIO's policy network)."""
    module = nets.policy_module(cfg.policy_hidden, env.num_actions)
    params = agent_row(state.policy, agent)
    return lambda obs: module.apply(params, obs)


def reciprocator_policy(env, cfg, state, agent: int):
    """Agent `agent`'s logits from the Reciprocator's policy network (`reciprocator_nets`)."""
    module, _ = reciprocator_nets.modules(env, cfg.policy_hidden, cfg.net_input, cfg.policy_head)
    params = agent_row(state.policy, agent)
    return lambda obs: module.apply(params, obs)


def lio_incentive(env, cfg, state, agent: int):
    """Giver `agent`'s incentives R_max·sigmoid(η_i(o_i, a_−i)), its own entry 0, from LIO's
    incentive network and input (`lio.incentive_input`)."""
    module = nets.incentive_module(cfg.incentive_hidden, env.num_agents)
    params = agent_row(state.incentive, agent)
    n = env.num_agents
    others_only = np.float32(1.0 - np.eye(n)[agent])

    def give(obs, actions):
        joint = jnp.broadcast_to(obs[:, None, :], (obs.shape[0], n, obs.shape[1]))
        x = lio.incentive_input(joint, actions, env.num_actions)[:, agent]
        return cfg.incentive_max * jax.nn.sigmoid(module.apply(params, x)) * others_only

    return give


register_export(pg.acting, PolicyExport(mlp_policy, None))
register_export(lio.acting, PolicyExport(mlp_policy, lio_incentive))
register_export(reciprocator.acting, PolicyExport(reciprocator_policy, None))


@dataclasses.dataclass(frozen=True)
class Agent:
    """One agent's exported functions (traceable: JAX arrays in, JAX arrays out)."""

    index: int
    logits: Callable[[jax.Array], jax.Array]
    give: Callable[[jax.Array, jax.Array], jax.Array] | None

    def policy(self, obs: jax.Array) -> tuple[jax.Array, jax.Array]:
        """(logits, probabilities) [B, num_actions] of observations [B, obs_dim]."""
        logits = self.logits(obs)
        return logits, jax.nn.softmax(logits, axis=-1)


def exported_agents(loaded: runs.LoadedRun, seed_index: int) -> list[Agent]:
    """The agents of one seed as functions ONNX can hold; InvalidParameter (one line) for a
    learner without a `PolicyExport`."""
    r = loaded.resolved
    export = EXPORTS.get(r.learner.acting)
    if export is None:
        raise InvalidParameter(
            f"learner: {r.run.learner}'s policy cannot be exported to ONNX (no PolicyExport "
            f"is registered for its acting function; see docs/robot.md, exported policies); "
            f"exportable: {', '.join(exportable_learners()) or 'none'}"
        )
    state = loaded.seed_state(seed_index)
    env, cfg = r.env, r.learner_config
    return [
        Agent(
            i,
            export.policy(env, cfg, state, i),
            export.incentive(env, cfg, state, i) if export.incentive else None,
        )
        for i in range(env.num_agents)
    ]


def exportable_learners() -> list[str]:
    """The registered learners whose policies `export_run` writes."""
    return [n for n in learners.registered() if learners.get(n).acting in EXPORTS]
