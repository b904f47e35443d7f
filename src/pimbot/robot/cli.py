"""`pimbot robot eval|render`: trained Escape Room runs played by robots in MuJoCo.

pimbot robot eval RUN_DIR --episodes K [--rosbag OUT] [--json OUT] [--nominal-room]
pimbot robot render RUN_DIR --out episode.gif|mp4 [--seed-index S] [--episode E]
                    [--renderer auto|mujoco|matplotlib] [--frame FRAME.png]
"""

from __future__ import annotations

import argparse
from pathlib import Path

RENDERERS = ("auto", "mujoco", "matplotlib")


def add_parser(commands) -> None:
    """Adds `robot` with its `eval` and `render` subcommands to the `pimbot` parser."""
    robot = commands.add_parser(
        "robot", help="trained Escape Room policies on TurtleBot3-sized robots in MuJoCo"
    )
    sub = robot.add_subparsers(dest="robot_command", required=True, parser_class=type(robot))
    evaluate = sub.add_parser("eval", help="physics success next to abstract success, per seed")
    evaluate.add_argument("run_dir", help="a pimbot run directory of escape_room-v0")
    evaluate.add_argument("--episodes", default="10", help="episodes per seed (default 10)")
    evaluate.add_argument("--rosbag", help="write the first seed's first episode as a ROS 2 bag")
    evaluate.add_argument("--json", help="write the results as JSON to this file")
    evaluate.add_argument(
        "--nominal-room", action="store_true", help="the fixed room instead of random layouts"
    )
    evaluate.add_argument(
        "--physics",
        nargs="*",
        default=[],
        metavar="name=value",
        help="physics settings, e.g. actuation_noise=0.2 decision_time_limit=15",
    )
    render = sub.add_parser("render", help="top-down video of one physics episode")
    render.add_argument("run_dir", help="a pimbot run directory of escape_room-v0")
    render.add_argument("--out", required=True, help="video file: .gif, or .mp4 (needs ffmpeg)")
    render.add_argument("--seed-index", default="0", help="which seed of the run (default 0)")
    render.add_argument("--episode", default="0", help="which episode of that seed (default 0)")
    render.add_argument("--renderer", default="auto", help="auto, mujoco or matplotlib")
    render.add_argument("--frame", help="also write the episode's last frame as this PNG")
    render.add_argument(
        "--nominal-room", action="store_true", help="the fixed room instead of random layouts"
    )


def _count(name: str, text: str, low: int) -> int:
    from pimbot.envs.core import InvalidParameter

    try:
        value = int(text)
    except ValueError:
        raise InvalidParameter(f"{name}: must be an integer ≥ {low}, got {text!r}") from None
    if value < low:
        raise InvalidParameter(f"{name}: must be an integer ≥ {low}, got {value}")
    return value


def run(args: argparse.Namespace) -> int:
    if args.robot_command == "eval":
        return _eval(args)
    return _render(args)


def _check_run_dir(text: str) -> Path:
    from pimbot.envs.core import InvalidParameter

    path = Path(text)
    if not (path / "config.json").exists():
        raise InvalidParameter(f"run_dir: {path} is not a pimbot run directory (no config.json)")
    return path


def _eval(args) -> int:
    from pimbot.envs.core import InvalidParameter

    episodes = _count("episodes", args.episodes, 1)
    run_dir = _check_run_dir(args.run_dir)
    if (
        args.rosbag
        and Path(args.rosbag).exists()
        and not (Path(args.rosbag) / "metadata.yaml").exists()
    ):
        raise InvalidParameter(f"rosbag: {args.rosbag} exists and is not a ROS 2 bag")
    if args.rosbag:
        import importlib.util

        if importlib.util.find_spec("rosbags") is None:
            raise InvalidParameter(
                "rosbag: writing ROS 2 bags needs the rosbags package; pip install 'pimbot[rosbag]'"
            )
    from pimbot.experiment import store
    from pimbot.robot import evaluate

    overrides = evaluate.parse_physics_overrides(args.physics)
    if args.nominal_room:
        overrides["randomize_layout"] = False
    print(f"{run_dir}: {episodes} physics and {episodes} abstract episodes per seed")
    print(f"{'seed':>6}  {'physics':>8}  {'abstract':>8}")
    result = evaluate.evaluate_run(
        run_dir,
        episodes,
        overrides,
        record_first=bool(args.rosbag),
        on_seed=lambda seed, p, a: print(f"{seed:>6}  {p:>8.2f}  {a:>8.2f}", flush=True),
    )
    summary = result.summary()
    for name in ("physics", "abstract"):
        s = summary[name]
        lo, hi = s["ci95"]
        print(f"{result.label}: {name} success {s['mean']:.2f} (95 % CI {lo:.2f}–{hi:.2f})")
    print(
        f"robots reaching their slot in time: {result.arrived:.1%}; decision steps per "
        f"episode {result.decision_steps:.2f}; {result.physics_steps:,} physics steps; "
        f"wall {result.wall_s:.1f} s"
    )
    if args.rosbag:
        from pimbot.robot import rosbag

        path = rosbag.write_bag(result.recorded, args.rosbag)
        print(f"wrote ROS 2 bag {path}")
    if args.json:
        store.write_json(Path(args.json), summary)
        print(f"wrote {args.json}")
    return 0


def _render(args) -> int:
    from pimbot.envs.core import InvalidParameter

    run_dir = _check_run_dir(args.run_dir)
    seed_index = _count("seed_index", args.seed_index, 0)
    episode = _count("episode", args.episode, 0)
    if args.renderer not in RENDERERS:
        raise InvalidParameter(
            f"renderer: unknown renderer {args.renderer!r}; allowed: {', '.join(RENDERERS)}"
        )
    if args.frame and Path(args.frame).suffix.lower() != ".png":
        raise InvalidParameter(f"frame: must end in .png, got {args.frame!r}")
    renderer = args.renderer
    if renderer != "matplotlib":
        from pimbot.robot import gl

        backend = gl.select_backend()  # before mujoco is imported
        if backend is None:
            if renderer == "mujoco":
                raise InvalidParameter(
                    "renderer: mujoco needs OpenGL (MUJOCO_GL=egl or osmesa) and none works "
                    "here; use --renderer matplotlib"
                )
            print("no OpenGL backend for MuJoCo here: using the matplotlib renderer")
            renderer = "matplotlib"
        else:
            renderer = "mujoco"
    from pimbot.robot import evaluate, render

    out = render.check_output_path(args.out)
    loaded = evaluate.load_run(run_dir)
    if seed_index >= len(loaded.seeds):
        raise InvalidParameter(
            f"seed_index: must be in [0, {len(loaded.seeds) - 1}], got {seed_index}"
        )
    overrides = {"randomize_layout": False} if args.nominal_room else {}
    cfg = evaluate.physics_config(loaded.resolved, **overrides)
    result = evaluate.physics_episodes(loaded, seed_index, episode + 1, cfg)[episode]
    title = f"{evaluate.run_label(loaded.resolved)}, seed {loaded.seeds[seed_index]}"
    adversary = render.run_adversary(run_dir)
    used = render.render_episode(result, out, renderer=renderer, title=title, adversary=adversary)
    outcome = "success" if result.success else "no success"
    print(f"episode: {result.steps} decision steps, {outcome}; actions {result.actions.tolist()}")
    print(f"wrote {out} ({used} renderer)")
    if args.frame:
        last = render.frame_indices(result, 10, 4.0)[-1:]
        frames = (
            render.mujoco_frames(result, last, adversary=adversary, title=title)
            if used == "mujoco"
            else render.matplotlib_frames(result, last, title=title, adversary=adversary)
        )
        render.write_png(frames[0], Path(args.frame))
        print(f"wrote {args.frame}")
    return 0
