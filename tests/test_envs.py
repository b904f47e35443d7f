"""Environment tests: conformance over the registry, golden action sequences, bad parameters."""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from pimbot import envs
from pimbot.contracts.rollout import episode_metrics, rollout
from pimbot.envs import (
    EscapeRoom,
    EscapeRoomWithTransfer,
    InvalidParameter,
    MatrixGame,
    StagHunt,
    StagHuntMatrix,
)
from pimbot.envs.escape_room import DOOR, LEVER, START
from pimbot.envs.matrix_games import COOPERATE, DEFECT, HARE, IPD_PAYOFF, STAG
from pimbot.envs.stag_hunt import DOWN, LEFT, RIGHT, STAY, UP

KEY = jax.random.key(0)


@functools.cache
def _compiled(env):
    """Jitted reset and step, compiled once per distinct env in this module."""
    return jax.jit(env.reset), jax.jit(env.step)


@dataclasses.dataclass
class Step:
    obs: np.ndarray
    rewards: list[float]
    done: bool
    info: dict
    state: object


def play(env, joint_actions, state=None, key=KEY):
    """Steps `env` from a reset (or from `state`) through `joint_actions`; one Step per action."""
    reset, step = _compiled(env)
    if state is None:
        _, state = reset(key)
    steps = []
    for t, actions in enumerate(joint_actions):
        obs, state, rewards, done, info = step(
            jax.random.fold_in(key, t), state, jnp.asarray(actions, jnp.int32)
        )
        info = {name: np.asarray(value).tolist() for name, value in info.items()}
        steps.append(Step(np.asarray(obs), np.asarray(rewards).tolist(), bool(done), info, state))
    return steps


# --- conformance -------------------------------------------------------------------------


def test_registry_lists_every_env():
    # the built-ins (a plugin another test of this process loaded, e.g. test_extending's
    # public_goods_game-v0, stays registered in it)
    built_in = [
        e for e in envs.registered() if envs.spec(e).constructor.__module__.startswith("pimbot.")
    ]
    assert built_in == [
        "escape_room-v0",
        "escape_room_transfer-v0",
        "ipd-v0",
        "stag_hunt-v0",
        "stag_hunt_matrix-v0",
    ]
    for env_id in envs.registered():
        assert envs.spec(env_id).description
    assert envs.spec("ipd-v0").parameters() == {"n_players": 2, "max_steps": 5}
    assert envs.spec("stag_hunt_matrix-v0").parameters() == {"n_players": 2, "max_steps": 10}
    assert envs.spec("stag_hunt-v0").parameters() == {
        "n_players": 2,
        "grid_size": 5,
        "max_steps": 50,
        "n_hares": 0,
        "stag_random_action_prob": 0.5,
        "stag_moves_first": True,
    }


def test_env_entries_hold_how_runs_are_evaluated_and_the_action_names():
    room, ipd = envs.spec("escape_room-v0"), envs.spec("ipd-v0")
    assert (room.eval_period, room.eval_episodes) == (100, 10)  # the original ER configs
    for env_id in ("escape_room_transfer-v0", "ipd-v0", "stag_hunt-v0", "stag_hunt_matrix-v0"):
        entry = envs.spec(env_id)  # none declared: the registry's fallback
        assert (entry.eval_period, entry.eval_episodes) == (1000, 10), env_id
    assert [room.action_names[a] for a in (LEVER, START, DOOR)] == ["lever", "start", "door"]
    assert [ipd.action_names[a] for a in (COOPERATE, DEFECT)] == ["C", "D"]
    for env_id in envs.registered():
        names = envs.spec(env_id).action_names
        assert not names or len(names) == envs.make(env_id).num_actions, env_id
    assert envs.ids_of(EscapeRoom) == ["escape_room-v0"]


def test_register_refuses_an_evaluation_that_is_no_positive_integer():
    with pytest.raises(InvalidParameter, match="^eval_period: must be an integer ≥ 1, got 0"):
        envs.register("bad_eval-v0", EscapeRoom, "never registered", eval_period=0)
    with pytest.raises(InvalidParameter, match="^eval_episodes: must be an integer ≥ 1"):
        envs.register("bad_eval-v0", EscapeRoom, "never registered", eval_episodes=2.5)
    assert "bad_eval-v0" not in envs.registered()


@pytest.mark.parametrize("env_id", envs.registered())
def test_check_env_registered(env_id):
    envs.check_env(envs.make(env_id))


@pytest.mark.parametrize(
    "params",
    [
        {"n_agents": 4, "min_at_lever": 2},
        {"n_agents": 4, "min_at_lever": 3},
        {"randomize_start": True},
    ],
)
def test_check_env_escape_room_variants(params):
    envs.check_env(envs.make("escape_room-v0", **params))


def test_check_env_three_player_matrix_game():
    envs.check_env(envs.make("ipd-v0", n_players=3))


class _TooTightBounds(EscapeRoom):
    def obs_bounds(self):
        return 0.0, 0.5


class _ClaimsDeterministic(EscapeRoom):
    @property
    def stochastic(self):
        return False


class _OneReward(EscapeRoom):
    def step(self, key, state, actions):
        obs, state, rewards, done, info = super().step(key, state, actions)
        return obs, state, rewards[:1], done, info


class _TracesAShape(EscapeRoom):
    traced_fields = ("n_agents",)  # N is a shape: it cannot be traced


def test_check_env_catches_a_traced_field_used_as_a_shape():
    with pytest.raises(AssertionError, match=r"traced_fields \('n_agents',\): reset or step"):
        envs.check_env(_TracesAShape())


class _DeclaresTracedButIsNoPytree(envs.IteratedPrisonersDilemma):
    traced_fields = ("max_steps",)  # a value in `step`, but no `TracedFields` env


def test_an_env_written_for_0_1_with_traced_fields_but_no_pytree_is_compiled_in():
    """0.1 let an env declare `traced_fields` without subclassing `TracedFields`: it still
    passes, with a deprecation warning, and the program closes over it (its numbers are
    compiled in, so two values never share a program)."""
    from pimbot.envs.core import program_env
    from pimbot.moved import PimbotDeprecationWarning
    from pimbot.training.programs import _env_structure

    with pytest.warns(PimbotDeprecationWarning, match=r"without subclassing .*TracedFields"):
        envs.check_env(_DeclaresTracedButIsNoPytree())
    assert program_env(_DeclaresTracedButIsNoPytree()) is None
    five, six = _DeclaresTracedButIsNoPytree(max_steps=5), _DeclaresTracedButIsNoPytree(max_steps=6)
    assert _env_structure(five) != _env_structure(six)


@pytest.mark.parametrize(
    "env",
    [EscapeRoom(4, 3), EscapeRoomWithTransfer(n_agents=4, min_at_lever=2, transfer=0.3)],
    ids=["escape_room", "escape_room_transfer"],
)
def test_an_escape_room_is_a_pytree_of_its_traced_fields(env):
    """The leaves are the traced fields (M), the treedef is the class and every other field;
    rebuilding one does not rerun the validation (a tracer or placeholder for M would fail
    it): the numbers are checked once, when the env is made."""
    leaves, treedef = jax.tree.flatten(env)
    assert leaves == [env.min_at_lever]
    other = dataclasses.replace(env, min_at_lever=1)
    assert jax.tree.structure(other) == treedef  # M is no part of the structure
    assert jax.tree.unflatten(treedef, [1]) == other
    assert hash(jax.tree.unflatten(treedef, [1])) == hash(other)
    assert jax.tree.map(lambda _: None, env).min_at_lever is None  # not validated
    assert jax.jit(lambda e: e.min_at_lever * 2)(env) == 2 * env.min_at_lever
    assert jax.tree.leaves(jax.tree.map(jnp.asarray, env))[0].dtype == jnp.int32
    with pytest.raises(InvalidParameter, match="min_at_lever"):
        dataclasses.replace(env, min_at_lever=env.n_agents)  # made: validated


def test_check_env_catches_wrong_reward_shape():
    with pytest.raises(AssertionError, match=r"rewards must have shape \(2,\), got \(1,\)"):
        envs.check_env(_OneReward())


def test_check_env_catches_observations_outside_bounds():
    with pytest.raises(AssertionError, match="obs_bounds"):
        envs.check_env(_TooTightBounds())


def test_check_env_catches_undeclared_randomness():
    with pytest.raises(AssertionError, match="stochastic is False"):
        envs.check_env(_ClaimsDeterministic(randomize_start=True))


# --- Escape Room golden tests ------------------------------------------------------------


def test_escape_room_reset_observation():
    obs, _ = _compiled(EscapeRoom())[0](KEY)
    np.testing.assert_array_equal(obs, [[0, 1, 0, 0, 1, 0, 0]] * 2)


def test_escape_room_both_stay_at_start():
    (s,) = play(EscapeRoom(), [(START, START)])
    assert s.rewards == [0.0, 0.0]
    assert not s.info["door_open"] and not s.done and not s.info["success"]


def test_escape_room_lever_and_door_from_start_succeeds():
    (s,) = play(EscapeRoom(), [(LEVER, DOOR)])
    assert s.rewards == [-1.0, 10.0]
    assert s.info["door_open"] and s.done and s.info["success"]


def test_escape_room_door_stays_closed_without_lever():
    first, second = play(EscapeRoom(), [(DOOR, DOOR), (DOOR, DOOR)])
    assert first.rewards == [-1.0, -1.0]
    assert not first.info["door_open"] and not first.done
    assert second.rewards == [0.0, 0.0]  # staying at the door costs nothing
    assert not second.info["door_open"] and not second.done


def test_escape_room_staying_at_lever_keeps_door_open_for_free():
    first, second = play(EscapeRoom(), [(LEVER, START), (LEVER, DOOR)])
    assert first.rewards == [-1.0, 0.0]
    assert first.info["door_open"] and not first.done  # open, but nobody went through
    assert second.rewards == [0.0, 10.0]
    assert second.info["door_open"] and second.done and second.info["success"]


def test_escape_room_four_two_pays_door_goers():
    (s,) = play(EscapeRoom(4, 2), [(LEVER, LEVER, DOOR, DOOR)])
    assert s.rewards == [-1.0, -1.0, 10.0, 10.0]
    assert s.info["door_open"] and s.done and s.info["success"]


def test_escape_room_four_three_needs_three_at_lever():
    (s,) = play(EscapeRoom(4, 3), [(LEVER, LEVER, DOOR, DOOR)])
    assert s.rewards == [-1.0] * 4
    assert not s.info["door_open"] and not s.done


@pytest.mark.parametrize(("n", "m"), [(2, 1), (3, 2), (4, 2), (4, 3)])
def test_escape_room_one_step_plan_reaches_optimal_team_return(n, m):
    env = EscapeRoom(n, m)
    (s,) = play(env, [(LEVER,) * m + (DOOR,) * (n - m)])
    assert s.done and s.info["success"]
    assert sum(s.rewards) == env.optimal_team_return


def test_escape_room_truncates_at_max_steps_without_success():
    env = EscapeRoom()
    steps = play(env, [(START, START)] * env.max_steps)
    assert [s.done for s in steps] == [False] * 4 + [True]
    assert not any(s.info["success"] for s in steps)
    assert env.episode_success(jnp.int32(0), jnp.int32(5), jnp.zeros(2)) == 0.0
    assert env.episode_success(jnp.int32(1), jnp.int32(2), jnp.zeros(2)) == 1.0


# --- the counterfactual Escape Room with a transfer (pay-back) action --------------------

GIVE = 3  # actions GIVE + move: the same move, giving `transfer` of a positive step reward


def test_escape_room_transfer_pays_back_the_lever_puller():
    env = EscapeRoomWithTransfer(transfer=0.5)
    assert env.num_actions == 6 and env.idle_action == START
    (kept,) = play(env, [(LEVER, DOOR)])
    assert kept.rewards == [-1.0, 10.0] and kept.info["transferred"] == [0.0, 0.0]
    (paid,) = play(env, [(LEVER, GIVE + DOOR)])
    assert paid.rewards == [4.0, 5.0] and paid.info["transferred"] == [0.0, 5.0]
    assert paid.done and paid.info["success"] and paid.info["exit_success"] == [False, True]
    # a negative or zero step reward is never transferred; the move is the action's
    first, second = play(env, [(GIVE + LEVER, GIVE + START), (GIVE + LEVER, START)])
    assert first.rewards == [-1.0, 0.0] and first.info["transferred"] == [0.0, 0.0]
    assert int(second.state.positions[0]) == LEVER and not second.done


def test_escape_room_transfer_splits_among_the_others_and_keeps_the_team_return():
    env = EscapeRoomWithTransfer(n_agents=4, min_at_lever=2, transfer=0.3)
    (s,) = play(env, [(LEVER, LEVER, GIVE + DOOR, DOOR)])
    np.testing.assert_allclose(s.rewards, [-1.0 + 1.0, -1.0 + 1.0, 7.0, 10.0 + 1.0], atol=1e-6)
    assert sum(s.rewards) == pytest.approx(env.optimal_team_return)


@pytest.mark.parametrize("transfer", [0.0, -0.5, 1.5, True, "half"])
def test_escape_room_transfer_must_be_a_fraction(transfer):
    with pytest.raises(InvalidParameter, match="transfer: must be a number in"):
        envs.make("escape_room_transfer-v0", transfer=transfer)


def test_escape_room_observation_order():
    (s,) = play(EscapeRoom(3, 2), [(LEVER, DOOR, START)])
    assert s.rewards == [-1.0, -1.0, 0.0]  # one at the lever is not enough
    # Agent 1: own position (door), agent 0 (lever), agent 2 (start), two incentive slots.
    np.testing.assert_array_equal(s.obs[1], [0, 0, 1, 1, 0, 0, 0, 1, 0, 0, 0])


# --- matrix games golden tests -----------------------------------------------------------


@pytest.mark.parametrize(("a0", "a1"), [(0, 0), (0, 1), (1, 0), (1, 1)])
def test_ipd_two_player_payoffs_and_observation(a0, a1):
    expected = {
        (0, 0): [-1.0, -1.0],
        (0, 1): [-3.0, 0.0],
        (1, 0): [0.0, -3.0],
        (1, 1): [-2.0, -2.0],
    }
    env = envs.make("ipd-v0")
    (s,) = play(env, [(a0, a1)])
    assert s.rewards == expected[(a0, a1)]
    assert s.rewards[0] == IPD_PAYOFF[a0, a1]
    np.testing.assert_array_equal(s.obs, [np.eye(5)[2 * a0 + a1]] * 2)
    assert s.info["success"] == (a0 == a1 == COOPERATE)


def test_ipd_two_player_reset_observation():
    obs, _ = _compiled(envs.make("ipd-v0"))[0](KEY)
    np.testing.assert_array_equal(obs, [[0, 0, 0, 0, 1]] * 2)


def test_ipd_three_players_mean_pairwise_payoff():
    env = envs.make("ipd-v0", n_players=3)
    obs, _ = _compiled(env)[0](KEY)
    np.testing.assert_array_equal(obs, [[0, 0, 0, 0, 0, 0, 1]] * 3)
    ccd, ddd, ccc = play(
        env,
        [(COOPERATE, COOPERATE, DEFECT), (DEFECT, DEFECT, DEFECT), (COOPERATE,) * 3],
    )
    assert ccd.rewards == [-2.0, -2.0, 0.0]  # mean(-1, -3), mean(-1, -3), mean(0, 0)
    np.testing.assert_array_equal(ccd.obs, [[1, 0, 1, 0, 0, 1, 0]] * 3)
    assert not ccd.info["success"]
    assert ddd.rewards == [-2.0] * 3
    assert ccc.rewards == [-1.0] * 3 and ccc.info["success"]


def test_ipd_runs_exactly_max_steps_and_scores_cooperation_rate():
    env = envs.make("ipd-v0")
    steps = play(env, [(COOPERATE, COOPERATE)] * 3 + [(COOPERATE, DEFECT)] * 2)
    assert [s.done for s in steps] == [False] * 4 + [True]
    assert sum(s.info["success"] for s in steps) == 3
    assert env.idle_action == DEFECT and not env.incentive_obs
    assert env.episode_success(jnp.int32(3), jnp.int32(5), jnp.zeros(2)) == pytest.approx(0.6)


def test_stag_hunt_matrix_three_players():
    env = envs.make("stag_hunt_matrix-v0", n_players=3)
    all_stag, two_stag, all_hare = play(env, [(STAG,) * 3, (STAG, STAG, HARE), (HARE,) * 3])
    assert all_stag.rewards == [5.0] * 3 and all_stag.info["success"]
    assert two_stag.rewards == [0.0, 0.0, 1.0] and not two_stag.info["success"]
    np.testing.assert_array_equal(two_stag.obs, [[1, 0, 1, 0, 0, 1, 0]] * 3)
    assert all_hare.rewards == [1.0] * 3
    assert env.idle_action == HARE


def test_stag_hunt_matrix_two_players_observation_and_horizon():
    env = envs.make("stag_hunt_matrix-v0")
    steps = play(env, [(STAG, HARE)] * env.max_steps)
    assert steps[0].rewards == [0.0, 1.0]
    np.testing.assert_array_equal(steps[0].obs, [[1, 0, 0, 1, 0]] * 2)
    assert [s.done for s in steps] == [False] * 9 + [True]


def test_matrix_games_are_one_class_with_payoff_data():
    for env_id in ("ipd-v0", "stag_hunt_matrix-v0"):
        env = envs.make(env_id, n_players=4)
        assert isinstance(env, MatrixGame) and type(env).step is MatrixGame.step
        assert env.payoffs.shape == (2, 4)
    np.testing.assert_array_equal(
        StagHuntMatrix(n_players=4).payoffs, MatrixGame("stag_hunt", n_players=4).payoffs
    )


# --- Stag Hunt gridworld golden tests ----------------------------------------------------

STILL_STAG = StagHunt(stag_random_action_prob=0.0)
RESTLESS_STAG = StagHunt(stag_random_action_prob=1.0)


def _hand_state(env, hunters, stag, hares):
    _, state = _compiled(env)[0](KEY)
    return state.replace(
        hunters=jnp.asarray(hunters, jnp.int32),
        stag=jnp.asarray(stag, jnp.int32),
        hares=jnp.asarray(hares, jnp.int32),
    )


def _after_one_step(env, state, actions, num_keys):
    """The first step from `state` under `num_keys` different keys."""
    return [play(env, [actions], state, jax.random.key(k))[0] for k in range(num_keys)]


def _cell(array):
    return tuple(np.asarray(array).tolist())


def test_stag_hunt_has_one_hare_per_hunter_unless_told():
    for n in (2, 3, 4):
        env = StagHunt(n_players=n)
        _, state = jax.eval_shape(env.reset, KEY)
        assert state.hares.shape == (n, 2) and env.obs_dim == 2 * (2 * n + 1)
    assert jax.eval_shape(StagHunt(n_players=3, n_hares=2).reset, KEY)[1].hares.shape == (2, 2)


def test_stag_hunt_all_hunters_on_stag_capture_it():
    state = _hand_state(STILL_STAG, [[2, 2], [2, 1]], [2, 2], [[2, 2], [4, 4]])
    outcomes = _after_one_step(STILL_STAG, state, (STAY, DOWN), 8)
    for s in outcomes:
        assert s.rewards == [5.0, 5.0]  # no extra hare reward on a stag capture
        assert s.info["success"] and s.info["stag_captures"] == 1
        assert s.info["return_over_stag_payoff"] == [1.0, 1.0]
        np.testing.assert_array_equal(s.state.hunters, [[2, 2], [2, 2]])
        np.testing.assert_array_equal(s.state.hares, [[2, 2], [4, 4]])  # hares left alone
    new_stags = {_cell(s.state.stag) for s in outcomes}
    assert len(new_stags) > 1, "the captured stag must respawn at a random cell"
    assert all(0 <= c < 5 for cell in new_stags for c in cell)


def test_stag_hunt_stag_acts_before_the_capture_check():
    # The hunters step onto the stag's cell; the stag acts first and may leave it.
    state = _hand_state(RESTLESS_STAG, [[2, 1], [1, 2]], [2, 2], [[0, 0], [4, 4]])
    outcomes = _after_one_step(RESTLESS_STAG, state, (DOWN, RIGHT), 40)
    for s in outcomes:
        if s.info["success"]:
            assert s.rewards == [5.0, 5.0]
        else:  # it stepped off: one cell away, no reward
            assert s.rewards == [0.0, 0.0]
            assert np.abs(np.asarray(s.state.stag) - [2, 2]).sum() == 1
    captured = sum(s.info["success"] for s in outcomes)
    assert 0 < captured < len(outcomes)  # it stays with probability 1/5
    # Waiting hunters catch a stag that walks onto their cell.
    state = _hand_state(RESTLESS_STAG, [[2, 2], [2, 2]], [2, 1], [[0, 0], [4, 4]])
    outcomes = _after_one_step(RESTLESS_STAG, state, (STAY, STAY), 40)
    assert any(s.info["success"] for s in outcomes)


def test_stag_hunt_capture_check_before_the_stag_acts_when_asked():
    env = StagHunt(stag_random_action_prob=1.0, stag_moves_first=False)
    state = _hand_state(env, [[2, 1], [1, 2]], [2, 2], [[0, 0], [4, 4]])
    assert all(s.info["success"] for s in _after_one_step(env, state, (DOWN, RIGHT), 20))
    state = _hand_state(env, [[2, 2], [2, 2]], [2, 1], [[0, 0], [4, 4]])
    assert not any(s.info["success"] for s in _after_one_step(env, state, (STAY, STAY), 20))


def test_stag_hunt_hunter_on_hare_gets_one():
    state = _hand_state(STILL_STAG, [[0, 1], [3, 3]], [2, 2], [[0, 0], [4, 4]])
    outcomes = _after_one_step(STILL_STAG, state, (UP, STAY), 8)
    for s in outcomes:
        assert s.rewards == [1.0, 0.0]
        assert not s.info["success"] and s.info["stag_captures"] == 0
        assert s.info["return_over_stag_payoff"] == pytest.approx([0.2, 0.0])
        np.testing.assert_array_equal(s.state.hares[1], [4, 4])
        np.testing.assert_array_equal(s.state.stag, [2, 2])  # the stag never acts here
    assert len({_cell(s.state.hares[0]) for s in outcomes}) > 1


def test_stag_hunt_two_hares_on_one_cell_pay_two():
    state = _hand_state(STILL_STAG, [[0, 1], [3, 3]], [2, 2], [[0, 0], [0, 0]])
    (s,) = play(STILL_STAG, [(UP, STAY)], state)
    assert s.rewards == [2.0, 0.0]


def test_stag_hunt_of_two_hunters_on_one_hare_the_lower_id_takes_it():
    # The hare respawns at once; hunter 1 gets it only if it respawns onto their cell.
    state = _hand_state(STILL_STAG, [[1, 0], [0, 1]], [2, 2], [[0, 0], [4, 4]])
    outcomes = _after_one_step(STILL_STAG, state, (LEFT, UP), 20)
    assert all(s.rewards[0] == 1.0 for s in outcomes)
    assert sum(s.rewards[1] for s in outcomes) < 5  # 1/25 per key
    for s in outcomes:
        if s.rewards[1] == 0.0:
            assert _cell(s.state.hares[0]) != (0, 0)


def test_stag_hunt_one_hunter_on_stag_gets_nothing():
    state = _hand_state(STILL_STAG, [[2, 2], [0, 4]], [2, 2], [[0, 0], [4, 4]])
    (s,) = play(STILL_STAG, [(STAY, STAY)], state)
    assert s.rewards == [0.0, 0.0] and not s.info["success"]


def test_stag_hunt_moves_are_clipped_at_walls():
    state = _hand_state(STILL_STAG, [[0, 0], [4, 4]], [2, 2], [[1, 3], [3, 1]])
    up_down, left_right, right_left = play(
        STILL_STAG, [(UP, DOWN), (LEFT, RIGHT), (RIGHT, LEFT)], state
    )
    np.testing.assert_array_equal(up_down.state.hunters, [[0, 0], [4, 4]])
    np.testing.assert_array_equal(left_right.state.hunters, [[0, 0], [4, 4]])
    np.testing.assert_array_equal(right_left.state.hunters, [[1, 0], [3, 4]])


def test_stag_hunt_still_stag_never_moves_and_episode_lasts_max_steps():
    state = _hand_state(STILL_STAG, [[0, 0], [4, 4]], [2, 2], [[1, 3], [3, 1]])
    steps = play(STILL_STAG, [(STAY, STAY)] * STILL_STAG.max_steps, state)
    assert all(np.array_equal(s.state.stag, [2, 2]) for s in steps)
    assert [s.done for s in steps] == [False] * 49 + [True]


def test_stag_hunt_stag_action_includes_staying():
    state = _hand_state(RESTLESS_STAG, [[0, 0], [4, 4]], [2, 2], [[1, 3], [3, 1]])
    distances = [
        np.abs(np.asarray(s.state.stag) - [2, 2]).sum()
        for s in _after_one_step(RESTLESS_STAG, state, (STAY, STAY), 40)
    ]
    assert set(distances) == {0, 1}


def test_stag_hunt_observation_order():
    env = StagHunt(n_players=3, stag_random_action_prob=0.0)
    state = _hand_state(env, [[0, 1], [2, 3], [4, 0]], [1, 1], [[3, 3], [0, 4], [2, 2]])
    (s,) = play(env, [(STAY, STAY, STAY)], state)
    # Hunter 1: own cell, hunters 0 and 2, the stag, the three hares; divided by the grid size.
    expected = np.array([2, 3, 0, 1, 4, 0, 1, 1, 3, 3, 0, 4, 2, 2], np.float32) / 5
    np.testing.assert_array_equal(s.obs[1], expected)
    assert s.obs.dtype == np.float32 and s.obs.shape == (3, env.obs_dim)


def test_stag_hunt_episode_success_is_clipped_stag_rate():
    env = StagHunt()
    score = functools.partial(env.episode_success, jnp.int32(0), jnp.int32(50))
    assert score(jnp.array([5.0, 5.0])) == 1.0
    assert score(jnp.array([2.0, 3.0])) == 0.5
    assert score(jnp.array([12.0, 11.0])) == 1.0
    assert score(jnp.array([0.0, 0.0])) == 0.0


# The original config_staghunt_lio (PIMbot code): LIO's Escape Room column.
STAG_HUNT_LIO_CONFIG = {
    "policy_hidden": (64, 32),
    "incentive_hidden": (64, 16),
    "lr_policy": 1e-4,
    "lr_incentive": 1e-3,
    "lr_cost": 1e-4,
    "incentive_max": 2.0,
    "entropy_coef": 0.01,
    "gamma": 0.99,
    "epsilon_start": 0.5,
    "epsilon_end": 0.1,
    "epsilon_decay_iters": 1000,
}


@pytest.mark.parametrize("learner", ["lio", "pg"])
def test_stag_hunt_learners_default_to_the_original_stag_hunt_config(learner):
    from pimbot.training.config import RunConfig, resolve

    resolved = resolve(RunConfig(env_id="stag_hunt-v0", learner=learner))
    config = dataclasses.asdict(resolved.learner_config)
    expected = {k: v for k, v in STAG_HUNT_LIO_CONFIG.items() if k in config}
    assert {k: config[k] for k in expected} == expected
    assert learner == "pg" or len(expected) == len(STAG_HUNT_LIO_CONFIG)


# --- per-step metrics declared by the envs -----------------------------------------------


@functools.cache
def _metrics_of_fixed_actions(env):
    """Jitted: the episode metrics when every agent plays the same action every step."""
    return jax.jit(lambda a: episode_metrics(env, rollout(env, KEY, lambda key, obs: a)))


@pytest.mark.parametrize(
    ("n", "m", "actions", "exits"),
    [
        (2, 1, (LEVER, DOOR), [0.0, 1.0]),
        (2, 1, (DOOR, DOOR), [0.0, 0.0]),  # door closed: truncated, nobody exits
        (4, 2, (LEVER, LEVER, DOOR, DOOR), [0.0, 0.0, 1.0, 1.0]),
        (4, 2, (LEVER, LEVER, START, DOOR), [0.0, 0.0, 0.0, 1.0]),
    ],
)
def test_escape_room_exit_success_is_per_agent(n, m, actions, exits):
    env = EscapeRoom(n_agents=n, min_at_lever=m)
    metrics = _metrics_of_fixed_actions(env)(jnp.asarray(actions, jnp.int32))
    np.testing.assert_array_equal(metrics["exit_success"], exits)
    assert metrics["success"] == float(any(exits))


def test_stag_hunt_episode_metrics_count_captures_and_the_codes_quantity():
    env = StagHunt(n_players=2, grid_size=2, max_steps=20)  # a small grid: captures happen
    play_many = jax.jit(jax.vmap(lambda k: rollout(env, k, _random_actions(env))))
    trajs = play_many(jax.random.split(KEY, 16))
    metrics = jax.vmap(lambda t: episode_metrics(env, t))(trajs)
    np.testing.assert_array_equal(metrics["stag_captures"], trajs.success.sum(axis=1))
    assert metrics["stag_captures"].sum() > 0
    np.testing.assert_allclose(
        metrics["return_over_stag_payoff"], metrics["return_env"] / 5.0, rtol=1e-6
    )
    assert (metrics["return_over_stag_payoff"][:, 0] > metrics["success"]).any()  # unclipped


def test_envs_without_step_metrics_report_only_the_common_metrics():
    env = envs.make("ipd-v0")
    metrics = jax.eval_shape(
        lambda k: episode_metrics(env, rollout(env, k, _random_actions(env))), KEY
    )
    assert set(metrics) == set(COMMON_METRICS)


def _random_actions(env):
    return lambda key, obs: jax.random.randint(key, (env.num_agents,), 0, env.num_actions)


COMMON_METRICS = ("success", "steps", "team_return", "return_env", "received", "given")
COMMON_METRICS += ("return_total",)


# --- bad parameters ----------------------------------------------------------------------


@pytest.mark.parametrize(
    ("env_id", "params", "field"),
    [
        ("escape_room-v0", {"n_agents": 2, "min_at_lever": 2}, "min_at_lever"),
        ("escape_room-v0", {"n_agents": 1}, "n_agents"),
        ("ipd-v0", {"n_players": 1}, "n_players"),
        ("ipd-v0", {"max_steps": 0}, "max_steps"),
        ("stag_hunt_matrix-v0", {"n_players": 2.0}, "n_players"),
        ("stag_hunt-v0", {"grid_size": 1}, "grid_size"),
        ("stag_hunt-v0", {"stag_random_action_prob": 1.5}, "stag_random_action_prob"),
        ("stag_hunt-v0", {"stag_random_action_prob": "0.5"}, "stag_random_action_prob"),
        ("stag_hunt-v0", {"n_hares": -1}, "n_hares"),
        ("stag_hunt-v0", {"stag_moves_first": "yes"}, "stag_moves_first"),
        ("stag_hunt_matrix-v0", {"game": "ipd"}, "game"),
        ("ipd-v0", {"colour": "red"}, "colour"),
    ],
)
def test_bad_parameter_names_the_field(env_id, params, field):
    with pytest.raises(InvalidParameter, match=field) as error:
        envs.make(env_id, **params)
    assert str(error.value).startswith(f"{field}:")


def test_unknown_game_names_the_allowed_games():
    with pytest.raises(InvalidParameter, match="game: must be one of ipd, stag_hunt"):
        MatrixGame("chess")


def test_unknown_env_id_lists_registered_ids():
    with pytest.raises(InvalidParameter) as error:
        envs.make("nope-v0")
    for env_id in envs.registered():
        assert env_id in str(error.value)


@pytest.mark.parametrize(
    "env_id", ["escape_room-v0", "ipd-v0", "stag_hunt-v0", "stag_hunt_matrix-v0"]
)
def test_every_built_in_env_names_its_observation_parts(env_id):
    """policy.json's layout: parts that tile obs_dim, each bounded where the env knows it."""
    from pimbot.envs.core import observation_parts

    parts = observation_parts(envs.make(env_id))
    assert len(parts) > 1 or env_id == "ipd-v0"
    assert all(p.meaning and p.units and p.low == 0.0 for p in parts)
    bounded = [p for p in parts if p.name != "incentives_given"]
    assert all(p.high is not None and p.high <= 1.0 for p in bounded)


def test_observation_parts_that_do_not_tile_the_observation_are_refused():
    from pimbot.envs.core import ObsPart, observation_parts

    class Short(EscapeRoom):
        def obs_parts(self):
            return (ObsPart("own_position", 3, "x", "one-hot", 0.0, 1.0),)

    with pytest.raises(InvalidParameter, match=r"Short.obs_parts: sizes \[3\] add up to 3, not"):
        observation_parts(Short())

    class Plain(EscapeRoom):  # as a plugin env that declares no parts
        obs_parts = None

    (plain,) = observation_parts(Plain())
    assert (plain.name, plain.size, plain.low, plain.high) == ("observation", 7, 0.0, None)
