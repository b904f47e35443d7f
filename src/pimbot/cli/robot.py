"""`pimbot robot eval|render`: trained Escape Room runs played by robots in MuJoCo.

pimbot robot eval RUN_DIR --episodes K [--rosbag OUT] [--json OUT] [--nominal-room]
pimbot robot render RUN_DIR --out episode.gif|mp4 [--seed-index S] [--episode E]
                    [--renderer auto|mujoco|matplotlib] [--frame FRAME.png]
"""

from __future__ import annotations

from pathlib import Path

RENDERERS = ("auto", "mujoco", "matplotlib")


def _count(name: str, text: str, low: int) -> int:
    from pimbot.envs.core import InvalidParameter

    try:
        value = int(text)
    except ValueError:
        raise InvalidParameter(f"{name}: must be an integer ≥ {low}, got {text!r}") from None
    if value < low:
        raise InvalidParameter(f"{name}: must be an integer ≥ {low}, got {value}")
    return value


def _check_run_dir(text: str) -> Path:
    from pimbot.envs.core import InvalidParameter

    path = Path(text)
    if not (path / "config.json").exists():
        raise InvalidParameter(f"run_dir: {path} is not a pimbot run directory (no config.json)")
    return path


def cmd_eval(args) -> int:
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
    from pimbot import statistics
    from pimbot.robot import evaluate
    from pimbot.training import store

    if args.json:  # before the evaluation, not after it
        from pimbot.cli.handlers import check_writable

        check_writable("json", Path(args.json), directory=False)
    overrides = evaluate.parse_physics_overrides(list(args.physics))
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
        interval = statistics.mean_interval(s["per_seed"])
        text = statistics.text(s["mean"], interval.lo, interval.hi, interval.kind, digits=2)
        print(f"{result.label}: {name} success {text}")
    print(statistics.interval_text([len(result.seeds)]))
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
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)  # checked creatable above
        store.write_json(Path(args.json), summary)
        print(f"wrote {args.json}")
    return 0


def cmd_render(args) -> int:
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
