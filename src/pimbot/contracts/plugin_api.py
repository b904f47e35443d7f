"""Every name a plugin uses, from one module: what docs/extending.md documents.

    from pimbot.contracts.plugin_api import Attack, register_attack, check_number

A plugin written against these names keeps working across minor releases: a name that
moves elsewhere in pimbot stays here, and a name removed from here keeps an alias that
warns (`pimbot.moved.PimbotDeprecationWarning`) for one release, listed in CHANGELOG.md.
The defining modules stay importable as before (`pimbot.contracts.attack`, ...); this
one only gathers them. The three `register` functions and two `HOOKS` tuples get the
kind in their names here; every other name is the defining module's own.

Not here, because they sit above the contracts: a learner's ONNX export
(`pimbot.robot.exportable.register_export`, `PolicyExport`) and the attacks' helper for a
mode read through a sign (`pimbot.attacks.signed_modes.with_traced_sign`).
tests/test_plugin_names.py imports every name of `__all__`.
"""

from __future__ import annotations

from pimbot import nets
from pimbot.contracts import learner_kit
from pimbot.contracts.attack import HOOKS as ATTACK_HOOKS
from pimbot.contracts.attack import (
    NO_ATTACK,
    AdversaryView,
    AgentParams,
    Attack,
    Decision,
    Outcome,
    UpdateSchedule,
    agent_row,
    attack_key,
    with_agent_row,
)
from pimbot.contracts.attack import register as register_attack
from pimbot.contracts.defense import HOOKS as DEFENSE_HOOKS
from pimbot.contracts.defense import (
    NO_DEFENSE,
    Defense,
    EpsilonContext,
    IncentiveContext,
    PolicyStepContext,
    acting_epsilon,
    after_policy_step,
    honest_agents,
    init_states,
    learning_incentives,
)
from pimbot.contracts.defense import register as register_defense
from pimbot.contracts.learner import (
    Actor,
    LearnerDef,
    program_config,
    set_env_defaults,
    set_env_params,
)
from pimbot.contracts.learner import register as register_learner
from pimbot.contracts.params import check_number
from pimbot.contracts.rollout import (
    ActFn,
    GiveFn,
    Trajectory,
    discounted_returns,
    episode_metrics,
    fill_incentive_obs,
    received,
    rollout,
)
from pimbot.envs import check_env, make
from pimbot.envs import register as register_env
from pimbot.envs.core import Env, EnvSpec, TracedFields, check_traced_numbers
from pimbot.envs.matrix_games import MatrixGameState
from pimbot.errors import InvalidParameter, check_choice, check_int

__all__ = [
    # errors and parameter checks (one line naming the field)
    "InvalidParameter",
    "check_choice",
    "check_int",
    "check_number",
    # environments
    "Env",
    "EnvSpec",
    "MatrixGameState",
    "TracedFields",
    "check_env",
    "check_traced_numbers",
    "make",
    "register_env",
    # attacks
    "ATTACK_HOOKS",
    "NO_ATTACK",
    "AdversaryView",
    "AgentParams",
    "Attack",
    "Decision",
    "Outcome",
    "UpdateSchedule",
    "agent_row",
    "attack_key",
    "register_attack",
    "with_agent_row",
    # defenses
    "DEFENSE_HOOKS",
    "NO_DEFENSE",
    "Defense",
    "EpsilonContext",
    "IncentiveContext",
    "PolicyStepContext",
    "acting_epsilon",
    "after_policy_step",
    "honest_agents",
    "init_states",
    "learning_incentives",
    "register_defense",
    # learners and the episode
    "ActFn",
    "Actor",
    "GiveFn",
    "LearnerDef",
    "Trajectory",
    "discounted_returns",
    "episode_metrics",
    "fill_incentive_obs",
    "learner_kit",
    "nets",
    "program_config",
    "received",
    "register_learner",
    "rollout",
    "set_env_defaults",
    "set_env_params",
]
