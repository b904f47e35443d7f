"""`pimbot robot eval|render|serve|world`: trained Escape Room runs played by robots.

pimbot robot eval RUN_DIR --episodes K [--rosbag OUT] [--bag-storage mcap|sqlite3]
                  [--ros-distro humble|jazzy] [--json OUT] [--nominal-room]
pimbot robot render RUN_DIR --out episode.gif|mp4 [--seed-index S] [--episode E]
                    [--renderer auto|mujoco|matplotlib] [--frame FRAME.png]
pimbot robot serve RUN_DIR [--ros-distro humble|jazzy] [--domain-id D] [--layout FILE.json]
                   [--attack NAME --adversary K] [--authenticated] [--audit-log PATH]
                   [--odometry-timeout S] [--timeout S]
pimbot robot world [--robots N --min-at-lever M] [--domain-id D] [--speed X | --lockstep] [--seed S]
"""

from __future__ import annotations

from pathlib import Path

from pimbot.cli.interrupts import Terminated

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
    if args.rosbag:
        from pimbot.robot import rosbag

        rosbag.check_bag_target(Path(args.rosbag))
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

        path = rosbag.write_bag(
            result.recorded, args.rosbag, storage=args.bag_storage, distro=args.ros_distro
        )
        print(f"wrote ROS 2 bag {path} ({args.bag_storage}, {args.ros_distro} message types)")
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


def _need_cyclonedds() -> None:
    import importlib.util

    from pimbot.envs.core import InvalidParameter

    if importlib.util.find_spec("cyclonedds") is None:
        raise InvalidParameter(
            "ros: the ROS 2 wire needs the cyclonedds package; pip install 'pimbot[ros]'"
        )


def _write_json(path: str | None, summary: dict) -> None:
    if path:
        from pimbot.training import store

        Path(path).parent.mkdir(parents=True, exist_ok=True)  # checked creatable before
        store.write_json(Path(path), summary)
        print(f"wrote {path}")


def _check_json(path: str | None) -> None:
    if path:
        from pimbot.cli.handlers import check_writable

        check_writable("json", Path(path), directory=False)


def cmd_world(args) -> int:
    import numpy as np

    _need_cyclonedds()
    _check_json(args.json)
    from pimbot.robot import evaluate
    from pimbot.robot.episode import PhysicsConfig
    from pimbot.robot.ros_world import WireConfig, play_world

    overrides = evaluate.parse_physics_overrides(list(args.physics))
    if args.nominal_room:
        overrides["randomize_layout"] = False
    cfg = PhysicsConfig(n_robots=args.robots, min_at_lever=args.min_at_lever, **overrides)
    wire = WireConfig(
        args.ros_distro,
        args.domain_id,
        0.0 if args.lockstep else args.speed,
        args.command_timeout,
        args.timeout,
    )
    print(
        f"world: {cfg.n_robots} robots on DDS domain {wire.domain_id} ({wire.distro}), "
        "waiting for a controller",
        flush=True,
    )
    summary = play_world(cfg, wire, np.random.default_rng([20261, args.seed])).summary()
    print(
        f"world: {summary['ended']} after {summary['ticks']} control periods "
        f"({summary['sim_seconds']:.1f} s simulated, {summary['wall_s']:.1f} s wall); "
        f"messages sent {summary['messages']['sent']}, received "
        f"{summary['messages']['received']}; command answer {summary['answer_ms_median']:.2f} "
        f"ms median, {summary['answer_ms_p95']:.2f} ms p95"
    )
    _write_json(args.json, summary)
    return 0 if summary["ended"] == "controller done" else 1


def _audit_log(args, run_dir: Path):
    """The serve command's audit log (its first record written), or None."""
    if args.audit_log is None:
        if args.audit_key is not None:
            from pimbot.envs.core import InvalidParameter

            raise InvalidParameter("audit_key: given without --audit-log PATH")
        return None
    from pimbot.defenses.audit import AuditError, AuditLog, writer_key
    from pimbot.envs.core import InvalidParameter

    try:
        key, _ = writer_key(args.audit_log, args.audit_key)
        log = AuditLog(args.audit_log, key)
        log.append(
            "serve",
            run_dir=str(run_dir),
            seed_index=args.seed_index,
            ros_distro=args.ros_distro,
            domain_id=args.domain_id,
            authenticated=args.authenticated,
            attack=args.attack,
            adversary=args.adversary if args.attack else None,
        )
    except AuditError as error:
        raise InvalidParameter(str(error)) from None
    return log


def cmd_serve(args) -> int:
    from pimbot.envs.core import InvalidParameter

    _need_cyclonedds()
    run_dir = _check_run_dir(args.run_dir)
    _check_json(args.json)
    from pimbot import jax_setup

    jax_setup.enable_compilation_cache()  # before JAX compiles the run's programs
    from pimbot.robot import evaluate, serve
    from pimbot.robot.ros_world import WireConfig, layout_from_json

    wire = WireConfig(args.ros_distro, args.domain_id)
    layout = layout_from_json(_read_layout(args.layout)) if args.layout else None
    loaded = evaluate.load_run(run_dir)
    if args.seed_index >= len(loaded.seeds):
        raise InvalidParameter(
            f"seed_index: must be in [0, {len(loaded.seeds) - 1}], got {args.seed_index}"
        )
    if args.attack:
        loaded = serve.with_attack(loaded, args.attack, args.adversary)
    cfg = evaluate.physics_config(
        loaded.resolved, **evaluate.parse_physics_overrides(list(args.physics))
    )
    audit = _audit_log(args, run_dir)
    try:
        policy = serve.trained_policy(loaded, args.seed_index)
    except KeyboardInterrupt as interrupt:  # compiling: no robot was driven yet
        if audit is not None:
            audit.close()
        print("serve: interrupted before any robot was driven")
        return 143 if isinstance(interrupt, Terminated) else 130
    label = evaluate.run_label(loaded.resolved)
    print(
        f"serve: {label}, seed {loaded.seeds[args.seed_index]}, on DDS domain "
        f"{wire.domain_id} ({wire.distro})",
        flush=True,
    )
    timing = serve.ServeConfig(
        args.authenticated, odometry_timeout=args.odometry_timeout, timeout=args.timeout
    )
    try:
        report = serve.serve_episode(policy, cfg, wire, timing, layout, audit)
    except KeyboardInterrupt as interrupt:  # the robots are stopped, and it said so
        report = getattr(interrupt, "serve_report", None)
        if report is not None:
            _write_json(args.json, report.summary())
        return 143 if isinstance(interrupt, Terminated) else 130
    finally:
        if audit is not None:
            audit.close()
    summary = report.summary()
    if report.ended != "done":
        print(f"serve: ended early ({report.ended}), the robots stopped")  # why: the stop line
    else:
        outcome = "success" if report.success else "no success"
        print(f"serve: {summary['steps']} decision steps, {outcome}; actions {report.actions}")
    print(
        f"serve: decision latency {summary['decision_ms_mean']:.1f} ms mean, "
        f"{summary['decision_ms_max']:.1f} ms max; incentive messages {report.incentives_sent} "
        f"sent, {report.incentives_accepted} accepted, rejected {report.rejected or 0}; "
        f"DDS messages sent {report.messages['sent']}, received {report.messages['received']}; "
        f"{report.sim_seconds:.1f} s simulated, {report.wall_s:.1f} s wall"
    )
    if report.dropped or report.commands_limited:
        print(f"serve: {_counters_text(report)}")
    _write_json(args.json, summary)
    return 0 if report.ended == "done" else 1


def _read_layout(path: str) -> str:
    """A layout file's text, read within the JSON bound (one line if it is not text)."""
    from pimbot.envs.core import InvalidParameter
    from pimbot.robot.ros_wire import MAX_JSON_BYTES

    try:
        with open(path, "rb") as file:
            data = file.read(MAX_JSON_BYTES + 1)
    except OSError as error:
        raise InvalidParameter(f"layout: {path}: {error.strerror}") from None
    if len(data) > MAX_JSON_BYTES:
        raise InvalidParameter(f"layout: {path}: larger than {MAX_JSON_BYTES} bytes")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        raise InvalidParameter(f"layout: {path}: not UTF-8 text") from None


def _counters_text(report) -> str:
    """The messages dropped on the way in and the commands made safe, in one line."""
    parts = []
    for topic, reasons in report.dropped.items():
        counts = ", ".join(f"{count} {reason}" for reason, count in reasons.items())
        parts.append(f"{topic} {counts}")
    dropped = "; ".join(parts) if parts else "none"
    limited = ", ".join(f"{n} {why}" for why, n in report.commands_limited.items()) or "none"
    return f"dropped messages: {dropped}; commands made safe: {limited}"
