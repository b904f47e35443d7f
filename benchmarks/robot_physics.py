"""Robot case study throughput: MuJoCo steps per second and the time of a 10-episode evaluation.

    python benchmarks/robot_physics.py [--runs-dir runs/attacks] [--json OUT]

Reports, for N = 2 and N = 4 robots:
- raw physics: `mj_step` with the wheels commanded, no Python in the loop;
- closed loop: whole scripted episodes (controller, topic bus, noise, gate servo,
  ER rules), physics steps divided by wall time;
and, for a trained clean run of ER(2,1) and ER(4,2) (if present under
--runs-dir), the wall time of 10 physics episodes of one seed's policy, after
one warm-up episode (the JAX decision function compiles on first use).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

import mujoco
import numpy as np

from pimbot.robot import controller as ctl
from pimbot.robot import episode as ep
from pimbot.robot.world import build_world, sample_layout

# Five decisions that never succeed (ER(2,1): the lever and the door are never both
# taken; ER(4,2): one robot at the lever), so every episode drives all five.
SCRIPTS = {
    2: np.array([[0, 1], [1, 0], [2, 1], [1, 2], [0, 0]]),
    4: np.array([[0, 1, 2, 2], [2, 2, 0, 1], [1, 0, 1, 2], [0, 2, 2, 1], [2, 1, 0, 2]]),
}


def raw_physics(n: int, steps: int = 20_000) -> float:
    world = build_world(sample_layout(np.random.default_rng(0), n, randomize=False))
    world.data.ctrl[world.wheel_ctrl] = ctl.wheel_speeds(np.full(n, 0.05), np.full(n, 0.3))
    mujoco.mj_step(world.model, world.data, nstep=200)
    start = time.perf_counter()
    mujoco.mj_step(world.model, world.data, nstep=steps)
    return steps / (time.perf_counter() - start)


def closed_loop(n: int, episodes: int = 5) -> dict:
    cfg = ep.PhysicsConfig(n_robots=n, min_at_lever=n // 2, max_steps=5)
    steps, seconds, simulated = 0, 0.0, 0.0
    for k in range(episodes):
        start = time.perf_counter()
        result = ep.run_episode(ep.ScriptedPolicy(SCRIPTS[n]), cfg, np.random.default_rng(k))
        assert result.steps == 5 and not result.success
        seconds += time.perf_counter() - start
        steps += result.physics_steps
        simulated += result.world.data.time
    return {
        "steps_per_s": steps / seconds,
        "real_time_factor": simulated / seconds,
        "episode_s": seconds / episodes,
    }


def ten_episode_eval(run_dir: Path) -> dict:
    from pimbot.robot import evaluate

    loaded = evaluate.load_run(run_dir)
    cfg = evaluate.physics_config(loaded.resolved)
    decision = evaluate.decision_function(loaded)
    evaluate.physics_episodes(loaded, 0, 1, cfg, decision=decision)  # compile
    start = time.perf_counter()
    results = evaluate.physics_episodes(loaded, 0, 10, cfg, decision=decision)
    wall = time.perf_counter() - start
    return {
        "run": str(run_dir),
        "wall_s": wall,
        "success": float(np.mean([r.success for r in results])),
        "physics_steps": int(sum(r.physics_steps for r in results)),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--runs-dir", type=Path, default=Path("runs/attacks"))
    parser.add_argument("--json", type=Path, help="write the results as JSON")
    args = parser.parse_args()
    out: dict = {
        "machine": platform.processor() or platform.machine(),
        "cpus": os.cpu_count(),
        "load_average_1min_before": os.getloadavg()[0],
        "mujoco": mujoco.__version__,
    }
    for n in (2, 4):
        raw = raw_physics(n)
        loop = closed_loop(n)
        out[f"n{n}"] = {"raw_steps_per_s": raw, **loop}
        print(
            f"N = {n}: raw physics {raw:,.0f} steps/s; closed loop {loop['steps_per_s']:,.0f} "
            f"steps/s ({loop['real_time_factor']:.0f}× real time, {loop['episode_s']:.2f} s "
            "per 5-decision scripted episode)"
        )
    for name in ("er21_clean", "er42_clean"):
        run_dir = args.runs_dir / name
        if (run_dir / "checkpoint").exists():
            result = ten_episode_eval(run_dir)
            out[f"eval10_{name}"] = result
            print(
                f"{name}: 10 physics episodes of seed 0 in {result['wall_s']:.2f} s "
                f"(success {result['success']:.1f}, {result['physics_steps']:,} physics steps)"
            )
    out["load_average_1min_after"] = os.getloadavg()[0]
    print(
        f"load average (1 min) {out['load_average_1min_before']:.1f} before, "
        f"{out['load_average_1min_after']:.1f} after, on {out['cpus']} CPUs"
    )
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(out, indent=2) + "\n")


if __name__ == "__main__":
    main()
