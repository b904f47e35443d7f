"""Robot case study: physics sanity, the gate, ER rules on zones, trained policies, bags, videos."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import textwrap

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from pimbot.cli import main
from pimbot.envs.escape_room import EscapeRoom
from pimbot.robot import controller as ctl
from pimbot.robot import episode as ep
from pimbot.robot import evaluate, render, rosbag
from pimbot.robot.messages import cmd_vel_topic, odom_topic
from pimbot.robot.world import (
    MAX_ANGULAR,
    MAX_LINEAR,
    WHEEL_RADIUS,
    WHEEL_SEPARATION,
    ZONE_NAMES,
    build_world,
    sample_layout,
)
from pimbot.training.config import RunConfig
from pimbot.training.runner import train

LEVER, START, DOOR = 0, 1, 2


def nominal_world(n: int):
    return build_world(sample_layout(np.random.default_rng(0), n, randomize=False))


def drive(world, wheels: np.ndarray, seconds: float) -> None:
    world.data.ctrl[world.wheel_ctrl] = wheels
    mujoco.mj_step(world.model, world.data, nstep=round(seconds / world.model.opt.timestep))


def test_wheel_mapping_is_the_differential_drive_kinematics():
    wheels = ctl.wheel_speeds(np.array([0.1, 0.0]), np.array([0.5, 1.0]))
    np.testing.assert_allclose(
        wheels[0], [(0.1 - 0.5 * WHEEL_SEPARATION / 2) / WHEEL_RADIUS, (0.1 + 0.04) / WHEEL_RADIUS]
    )
    np.testing.assert_allclose(ctl.body_twist(wheels), [[0.1, 0.5], [0.0, 1.0]], atol=1e-12)
    # Above the motor limit both wheels scale down together: curvature kept.
    fast = ctl.wheel_speeds(np.array([0.5]), np.array([1.0]))
    assert np.max(np.abs(fast)) == pytest.approx(MAX_LINEAR / WHEEL_RADIUS)
    v, w = ctl.body_twist(fast)[0]
    assert w / v == pytest.approx(1.0 / 0.5)


def test_robot_drives_the_kinematically_expected_distance_and_turns_in_place():
    world = nominal_world(2)
    speed, seconds = 0.2, 4.0
    straight = ctl.wheel_speeds(np.array([speed, 0.0]), np.array([0.0, 0.0]))
    drive(world, straight, 0.5)  # spin-up
    before = world.poses()
    drive(world, straight, seconds)
    after = world.poses()
    distance = np.linalg.norm(after[0, :2] - before[0, :2])
    assert distance == pytest.approx(speed * seconds, rel=0.03)
    assert abs(ctl.wrap_angle(after[0, 2] - before[0, 2])) < 0.03  # straight line
    heading = before[0, 2]
    travel = (after[0, :2] - before[0, :2]) / distance
    np.testing.assert_allclose(travel, [math.cos(heading), math.sin(heading)], atol=0.03)
    np.testing.assert_allclose(after[1], before[1], atol=1e-3)  # robot 1 got no command

    rate = 1.0
    spin = ctl.wheel_speeds(np.array([0.0, 0.0]), np.array([rate, 0.0]))
    drive(world, spin, 0.5)
    before = world.poses()
    drive(world, spin, 2.0)
    after = world.poses()
    turned = ctl.wrap_angle(after[0, 2] - before[0, 2])
    assert turned == pytest.approx(rate * 2.0, rel=0.06)
    assert np.linalg.norm(after[0, :2] - before[0, :2]) < 0.02  # in place
    assert ctl.body_twist(spin)[0, 1] <= MAX_ANGULAR


@pytest.mark.parametrize(("n", "m"), [(2, 1), (4, 2), (4, 3)])
def test_gate_opens_exactly_while_m_robots_are_in_the_lever_zone(n, m):
    for at_lever in range(n + 1):
        world = nominal_world(n)
        layout = world.layout
        for i in range(n):
            zone = LEVER if i < at_lever else START
            x, y = layout.slot(zone, i)
            world.set_pose(i, x, y, 0.0)
        mujoco.mj_forward(world.model, world.data)
        cfg = ep.PhysicsConfig(n_robots=n, min_at_lever=m)
        sim = ep.Simulation(world, cfg, np.random.default_rng(at_lever), record=False)
        assert np.sum(sim.zones() == LEVER) == at_lever
        for _ in range(30):  # 1.5 s
            sim.tick(np.zeros(n), np.zeros(n))
        opening = world.gate_opening()
        if at_lever >= m:
            assert opening >= ep.GATE_OPEN_FRACTION, (at_lever, opening)
        else:
            assert opening <= 0.02, (at_lever, opening)
        if at_lever >= m:  # leaving the lever zone closes it again
            for i in range(at_lever):
                world.set_pose(i, *layout.slot(START, i), 0.0)
            mujoco.mj_forward(world.model, world.data)
            for _ in range(30):
                sim.tick(np.zeros(n), np.zeros(n))
            assert world.gate_opening() <= 0.02


def abstract_episode(n: int, m: int, script: np.ndarray):
    """The abstract ER on the scripted joint actions: (obs, rewards, success) per step."""
    env = EscapeRoom(n_agents=n, min_at_lever=m)
    obs, state = env.reset(jax.random.PRNGKey(0))
    observations, rewards, success = [np.asarray(obs)], [], False
    for t in range(env.max_steps):
        actions = jnp.asarray(script[min(t, len(script) - 1)])
        obs, state, r, done, info = env.step(jax.random.PRNGKey(t), state, actions)
        observations.append(np.asarray(obs))
        rewards.append(np.asarray(r))
        if bool(done):
            success = bool(info["success"])
            break
    return observations, np.array(rewards), success


SCRIPTS = [
    (2, 1, [[LEVER, DOOR]]),  # the optimum: 9
    (2, 1, [[START, DOOR], [LEVER, DOOR]]),  # door closed first, then opened
    (2, 1, [[LEVER, START], [DOOR, LEVER]]),  # open with nobody at the door, then cross
    (4, 2, [[LEVER, DOOR, DOOR, START], [LEVER, LEVER, DOOR, DOOR]]),
    (4, 3, [[LEVER, LEVER, DOOR, DOOR], [DOOR, DOOR, LEVER, LEVER], [LEVER, LEVER, LEVER, DOOR]]),
    (4, 3, [[START, LEVER, START, START]]),  # never opens: truncated at 5 steps
]


@pytest.mark.parametrize(("n", "m", "script"), SCRIPTS)
def test_physics_rewards_match_the_abstract_rules(n, m, script):
    script = np.array(script)
    observations, rewards, success = abstract_episode(n, m, script)
    cfg = ep.PhysicsConfig(n_robots=n, min_at_lever=m)
    result = ep.run_episode(ep.ScriptedPolicy(script), cfg, np.random.default_rng(n * 10 + m))
    assert result.arrived.all(), result.arrived  # every robot reached its zone in time
    np.testing.assert_array_equal(result.rewards, rewards)
    assert result.success == success
    for t in range(result.steps + 1):
        np.testing.assert_array_equal(ep.observation(result.positions[t]), observations[t])
    np.testing.assert_array_equal(result.gate_open, np.sum(result.actions == LEVER, 1) >= m)


@pytest.fixture(scope="module")
def trained_er21(tmp_path_factory):
    """Clean LIO on ER(2,1), one seed, trained here: seed 3 solves it within 6000 iterations."""
    run_dir = tmp_path_factory.mktemp("robot") / "lio_er21_seed3"
    train(
        RunConfig("escape_room-v0", seeds=1, first_seed=3, iterations=6000, eval_period=500),
        run_dir,
        progress=False,
    )
    return run_dir


def test_trained_clean_er21_policy_succeeds_in_physics(trained_er21):
    # 5 episodes, as the CLI test below: the same compiled programs (persistent cache).
    result = evaluate.evaluate_run(trained_er21, episodes=5)
    assert result.abstract.tolist() == [1.0]
    assert result.physics.tolist() == [1.0]
    assert result.arrived == 1.0


def test_bypassed_adversary_idles_in_physics(trained_er21):
    # The same trained agents with the bypass hook on agent 0: it stays at the start.
    loaded = evaluate.load_run(trained_er21)
    from dataclasses import replace

    from pimbot.attacks import make

    resolved = replace(loaded.resolved, attack=make("bypass", 2, adversary=0))
    loaded = replace(loaded, resolved=resolved)
    cfg = evaluate.physics_config(resolved)
    for result in evaluate.physics_episodes(loaded, 0, 2, cfg):
        assert (result.actions[:, 0] == START).all()
        assert not result.success


def test_eval_cli_writes_a_ros2_bag_that_reads_back(trained_er21, tmp_path, capsys):
    bag = tmp_path / "episode_bag"
    out_json = tmp_path / "eval.json"
    code = main(
        ["robot", "eval", str(trained_er21), "--episodes", "5", "--rosbag", str(bag),
         "--json", str(out_json), "--bag-storage", "mcap", "--ros-distro", "jazzy"]
    )  # fmt: skip
    assert code == 0
    printed = capsys.readouterr().out
    # one seed: the range over seeds, never called a CI (pimbot.statistics)
    assert "physics success 1.00 (range 1.00 … 1.00)" in printed, printed
    assert "abstract success 1.00 (range 1.00 … 1.00)" in printed and "95 %" not in printed
    summary = json.loads(out_json.read_text())
    assert summary["physics"] == {"mean": 1.0, "per_seed": [1.0]}

    # The bag holds the first episode exactly as the decision loop published it.
    loaded = evaluate.load_run(trained_er21)
    cfg = evaluate.physics_config(loaded.resolved)
    replay = evaluate.physics_episodes(loaded, 0, 1, cfg, record_first=True)[0]
    messages = rosbag.read_bag(bag)
    assert (bag / "episode_bag.mcap").is_file() and "(mcap, jazzy message types)" in printed
    assert set(messages) == {
        cmd_vel_topic(0), cmd_vel_topic(1), odom_topic(0), odom_topic(1),
        rosbag.DECISIONS_TOPIC,
    }  # fmt: skip
    for i in range(2):
        log = [(s, m) for s, topic, m in replay.bus.log if topic == cmd_vel_topic(i)]
        got = [(s, m.twist) for s, m in messages[cmd_vel_topic(i)]]  # Jazzy: TwistStamped
        assert len(got) == len(log) > 10
        assert [s for s, _ in got] == [s for s, _ in log]
        np.testing.assert_allclose(
            [(m.linear.x, m.angular.z) for _, m in got],
            [(m.linear.x, m.angular.z) for _, m in log],
        )
        odom = messages[odom_topic(i)]
        last = [m for _, topic, m in replay.bus.log if topic == odom_topic(i)][-1]
        assert odom[-1][1].header.frame_id == "odom"
        assert odom[-1][1].child_frame_id == f"tb3_{i}/base_footprint"
        assert odom[-1][1].pose.pose.position.x == pytest.approx(last.pose.position.x)
        assert odom[-1][1].pose.pose.orientation.z == pytest.approx(last.pose.orientation.z)
        assert max(abs(m.linear.x) for _, m in got) <= MAX_LINEAR + 1e-9
    decisions = [json.loads(m.data) for _, m in messages[rosbag.DECISIONS_TOPIC]]
    assert [d["rewards"] for d in decisions] == replay.rewards.tolist()
    assert decisions[-1]["success"] is True and decisions[-1]["gate_open"] is True


def test_robot_cli_rejects_bad_input(trained_er21, tmp_path, capsys):
    assert main(["robot", "eval", str(trained_er21), "--episodes", "0"]) == 2
    assert "episodes: must be an integer ≥ 1" in capsys.readouterr().err
    assert main(["robot", "eval", str(tmp_path), "--episodes", "1"]) == 2
    assert "not a pimbot run directory" in capsys.readouterr().err
    bad = ["robot", "eval", str(trained_er21), "--physics", "control_period=0"]
    assert main(bad) == 2
    assert "control_period: must be a number > 0" in capsys.readouterr().err
    assert main(["robot", "render", str(trained_er21), "--out", str(tmp_path / "x.avi")]) == 2
    assert "out: must end in .gif or .mp4" in capsys.readouterr().err
    assert not (tmp_path / "x.avi").exists()


def test_render_cli_writes_a_video_and_a_frame(trained_er21, tmp_path, capsys):
    from PIL import Image

    gif, png = tmp_path / "episode.gif", tmp_path / "frame.png"
    code = main(
        ["robot", "render", str(trained_er21), "--out", str(gif), "--renderer", "matplotlib",
         "--frame", str(png)]
    )  # fmt: skip
    assert code == 0
    assert "success" in capsys.readouterr().out
    with Image.open(gif) as video:
        assert video.n_frames > 5
    with Image.open(png) as frame:
        assert frame.size == (640, 480)


def test_matplotlib_render_writes_a_gif_of_the_trajectory(tmp_path):
    from PIL import Image

    cfg = ep.PhysicsConfig(n_robots=2, min_at_lever=1)
    result = ep.run_episode(
        ep.ScriptedPolicy(np.array([[LEVER, DOOR]])), cfg, np.random.default_rng(1)
    )
    out = tmp_path / "episode.gif"
    assert render.render_episode(result, out, renderer="matplotlib", speedup=8.0) == "matplotlib"
    with Image.open(out) as gif:
        assert gif.n_frames == len(render.frame_indices(result, 10, 8.0)) > 5
        first = np.asarray(gif.convert("RGB"))
        gif.seek(gif.n_frames - 1)
        last = np.asarray(gif.convert("RGB"))
    assert first.shape == (480, 640, 3)
    assert np.abs(first.astype(int) - last).sum() > 0  # the robots moved


def test_frames_name_the_zones_mark_the_adversary_and_show_door_and_decision():
    cfg = ep.PhysicsConfig(n_robots=2, min_at_lever=1)
    result = ep.run_episode(
        ep.ScriptedPolicy(np.array([[LEVER, DOOR]])), cfg, np.random.default_rng(1)
    )
    last = render.frame_indices(result, 10, 8.0)[-1:]
    assert render.decision_at(result, 0) == 1
    assert render.decision_at(result, int(last[0])) == result.steps
    line, is_open = render.status(result, int(last[0]))
    assert line.startswith(f"decision {result.steps} of {result.steps}")
    assert ("door OPEN" in line) == is_open and ("door CLOSED" in line) != is_open
    assert render.robot_label(result, 1, 1, adversary=1) == "1 adversary → door"
    assert render.robot_label(result, 0, 1, adversary=1) == "0 → lever"
    assert set(render.ZONE_ROLES) == set(ZONE_NAMES)  # the legend names every zone

    def red(frame: np.ndarray) -> int:  # the adversary's colour, #d00000
        r, g, b = (frame[..., c].astype(int) for c in range(3))
        return int(((r > 190) & (g < 40) & (b < 40)).sum())

    marked = render.matplotlib_frames(result, last, title="t", adversary=1)[0]
    honest = render.matplotlib_frames(result, last, title="t")[0]
    assert marked.shape == honest.shape == (480, 640, 3)
    assert red(marked) > 200 and red(honest) == 0
    # The adversary comes from the run's attack parameters; a clean run has none.
    assert render.adversary_of({"identity": {"attack": None, "attack_params": {}}}) is None
    assert render.adversary_of({"identity": {"attack": "bypass", "attack_params": {}}}) == 0
    attacked = {"identity": {"attack": "bypass", "attack_params": {"adversary": 1}}}
    assert render.adversary_of(attacked) == 1


MUJOCO_RENDER = textwrap.dedent(
    """
    import sys
    import numpy as np
    from pimbot.robot import gl
    backend = gl.select_backend()
    if backend is None:
        print("NO-GL")
        sys.exit(0)
    from pimbot.robot import episode as ep, render
    cfg = ep.PhysicsConfig(n_robots=2, min_at_lever=1)
    result = ep.run_episode(ep.ScriptedPolicy(np.array([[0, 2]])), cfg, np.random.default_rng(1))
    indices = render.frame_indices(result, 10, 8.0)[[0, -1]]
    frames = render.mujoco_frames(result, indices, adversary=1, title="scripted")
    render.write_png(frames[-1], __import__("pathlib").Path(sys.argv[1]))
    first, last = (f.astype(int) for f in frames)
    assert last.shape == (480, 640, 3)  # the scene over the legend and status strip
    # Zone markers are red, blue and green patches; robots moved between the frames.
    red = (last[..., 0] > 150) & (last[..., 1] < 130) & (last[..., 2] < 130)
    assert red.sum() > 500, red.sum()
    assert np.abs(first - last).sum() > 0
    print("RENDERED", backend, last.shape)
    """
)


def test_mujoco_offscreen_render_where_opengl_works(tmp_path):
    png = tmp_path / "frame.png"
    env = {k: v for k, v in os.environ.items() if k != "MUJOCO_GL"}
    done = subprocess.run(
        [sys.executable, "-c", MUJOCO_RENDER, str(png)],
        env=env, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    if "NO-GL" in done.stdout:
        if os.environ.get("PIMBOT_REQUIRE_MUJOCO_GL"):
            pytest.fail("no MuJoCo OpenGL backend (egl, osmesa) works, and CI requires one")
        pytest.skip("no OpenGL backend for MuJoCo here (install libegl1/libosmesa6)")
    assert "RENDERED" in done.stdout
    assert png.stat().st_size > 10_000


def test_mp4_through_ffmpeg_where_installed(tmp_path):
    import shutil

    if shutil.which("ffmpeg") is None:
        pytest.skip("ffmpeg is not installed: .mp4 output is refused with a clear error")
    cfg = ep.PhysicsConfig(n_robots=2, min_at_lever=1)
    result = ep.run_episode(
        ep.ScriptedPolicy(np.array([[LEVER, DOOR]])), cfg, np.random.default_rng(1)
    )
    out = tmp_path / "episode.mp4"
    render.render_episode(result, out, renderer="matplotlib", speedup=8.0)
    probe = subprocess.run(
        ["ffprobe", "-v", "error", "-show_entries", "stream=codec_name,width,height",
         "-of", "csv=p=0", str(out)],
        capture_output=True, text=True, check=True,
    )  # fmt: skip
    assert probe.stdout.strip() == "h264,640,480"


def test_results_table_gives_a_ci_at_five_seeds_and_the_range_below(tmp_path):
    """The robot results' intervals are pimbot.statistics' (BCa CI at ≥ 5 seeds, else the
    range), computed from the per-seed values of the evaluation JSON files."""
    from pimbot import statistics
    from pimbot.robot.results import results_table

    paths = []
    for name, seeds in (("a", [0.2, 0.4, 0.6, 0.8, 1.0]), ("b", [0.0, 1.0])):
        row = {
            "label": f"lio ER(2,1) {'clean' if name == 'a' else 'bypass'}",
            "seeds": list(range(len(seeds))),
            "episodes_per_seed": 10,
            "arrived": 1.0,
            "decision_steps": 2.0,
            "wall_s": 1.0,
        }
        for part in ("physics", "abstract"):
            row[part] = {"mean": float(np.mean(seeds)), "per_seed": seeds}
        paths.append(tmp_path / f"{name}.json")
        paths[-1].write_text(json.dumps(row))
    table = results_table(paths)
    ci = statistics.mean_interval([0.2, 0.4, 0.6, 0.8, 1.0])
    assert ci.kind == statistics.CI and 0.2 < ci.lo < 0.6 < ci.hi <= 1.0
    assert f"0.60 [{ci.lo:.2f}, {ci.hi:.2f}]" in table
    assert "0.50 (range 0.00 … 1.00)" in table
    assert statistics.interval_text([5, 2]) in table
