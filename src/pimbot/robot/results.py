"""The robot results: every Escape Room run directory evaluated in physics, and the table.

    python -m pimbot.robot.results RUNS_DIR OUT_DIR [--episodes K] [--table TABLE.md]
                                   [--runs NAME ...] [--physics name=value ...]

evaluates every escape_room-v0 run under RUNS_DIR (K physics and K abstract
episodes per seed, `evaluate.evaluate_run`) into OUT_DIR/<run name>.json —
skipping runs whose JSON exists with the same K, so a killed regeneration
resumes — and writes the Markdown page (settings and the table of physics vs
abstract success, mean and its interval over seeds: pimbot.statistics) from those JSON
files alone.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from pimbot import envs, statistics
from pimbot.attacks import CONDITION_ORDER
from pimbot.training import store

ENV_ORDER = {"ER(2,1)": 0, "ER(4,2)": 1, "ER(4,3)": 2}


def escape_room_runs(runs_dir: Path) -> list[Path]:
    """Run directories under `runs_dir` (one level) trained on the Escape Room (the id
    `envs.EscapeRoom` is registered under: the robots play its rules), with a checkpoint."""
    found = []
    room_ids = envs.ids_of(envs.EscapeRoom)
    for config_path in sorted(Path(runs_dir).glob("*/config.json")):
        config = store.read_json(config_path)
        if (
            config.get("env", {}).get("id") in room_ids
            and (config_path.parent / store.CHECKPOINT_DIR).exists()
        ):
            found.append(config_path.parent)
    return found


def evaluate_all(
    runs_dir: Path, out_dir: Path, episodes: int, overrides=None, names=None, log=print
) -> list[Path]:
    """Evaluates every ER run of `runs_dir` (or those in `names`) into `out_dir`/<name>.json
    (resumable), with `PhysicsConfig` overrides."""
    from pimbot.robot.evaluate import evaluate_run, load_run, run_label

    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    for run_dir in escape_room_runs(runs_dir):
        if names and run_dir.name not in names:
            continue
        path = out_dir / f"{run_dir.name}.json"
        if path.exists():
            saved = store.read_json(path)
            if saved.get("episodes_per_seed") == episodes and saved.get(
                "physics_overrides", {}
            ) == (overrides or {}):
                label = run_label(load_run(run_dir).resolved)
                if saved.get("label") != label:  # labels made before ADMO's mode was shown
                    store.write_json(path, saved | {"label": label})
                written.append(path)
                continue
        result = evaluate_run(run_dir, episodes, overrides)
        summary = result.summary()
        summary["name"] = run_dir.name
        summary["physics_overrides"] = overrides or {}
        store.write_json(path, summary)
        log(
            f"{run_dir.name}: physics {summary['physics']['mean']:.2f} "
            f"abstract {summary['abstract']['mean']:.2f} ({result.wall_s:.0f} s)"
        )
        written.append(path)
    return written


def _attack_of(label: str) -> str:
    return label.split(" ", 2)[2]


def _env_of(label: str) -> str:
    return label.split(" ", 2)[1]


def results_table(json_paths: list[Path]) -> str:
    """Markdown: one row per run, physics vs abstract success with their intervals over
    seeds (a 95 % BCa CI at ≥ 5 seeds, the range below: pimbot.statistics)."""
    rows = [json.loads(Path(p).read_text()) for p in json_paths]
    rows.sort(
        key=lambda r: (
            ENV_ORDER.get(_env_of(r["label"]), 9),
            CONDITION_ORDER.index(_attack_of(r["label"]))
            if _attack_of(r["label"]) in CONDITION_ORDER
            else 99,
        )
    )
    lines = [
        "| env | attack | seeds × episodes | abstract success [interval] "
        "| physics success [interval] | robots in time | decision steps | eval wall s |",
        "| --- | --- | --- | --- | --- | --- | --- | --- |",
    ]

    def cell(stats) -> str:
        interval = statistics.mean_interval(stats["per_seed"])
        return statistics.text(stats["mean"], interval.lo, interval.hi, interval.kind, 2)

    for r in rows:
        lines.append(
            f"| {_env_of(r['label'])} | {_attack_of(r['label'])} "
            f"| {len(r['seeds'])} × {r['episodes_per_seed']} | {cell(r['abstract'])} "
            f"| {cell(r['physics'])} | {r['arrived']:.1%} | {r['decision_steps']:.2f} "
            f"| {r['wall_s']:.0f} |"
        )
    lines += ["", statistics.interval_text([len(r["seeds"]) for r in rows])]
    return "\n".join(lines) + "\n"


def results_document(json_paths: list[Path], command: str) -> str:
    """The Markdown page: what was run, then the table (everything from the JSON files)."""
    from pimbot.robot.episode import PhysicsConfig

    rows = [json.loads(Path(p).read_text()) for p in json_paths]
    overrides = {json.dumps(r.get("physics_overrides", {}), sort_keys=True) for r in rows}
    defaults = PhysicsConfig()
    settings = {
        "decision_time_limit": defaults.decision_time_limit,
        "odom_noise_position": defaults.odom_noise_position,
        "odom_noise_yaw": defaults.odom_noise_yaw,
        "actuation_noise": defaults.actuation_noise,
        "randomize_layout": defaults.randomize_layout,
    }
    if len(overrides) == 1:
        settings.update(json.loads(overrides.pop()))
    setting_text = ", ".join(f"{k} = {v}" for k, v in settings.items())
    return (
        "# Robot case study: trained Escape Room policies in physics\n\n"
        "Every seed's final policy (the run's checkpoint) plays K episodes with "
        "TurtleBot3-sized robots in MuJoCo and K episodes of the abstract ER, ε = 0 with "
        "sampled actions, the attack's hooks on (bypass idles the adversary). Success: the "
        "gate is open with a robot in the door zone within 5 decisions. Means over seeds "
        "with their intervals (below the table). *Robots in time*: driving robot-decisions "
        "that reached their slot within the time limit. Physics settings: " + setting_text + ".\n\n"
        "Regenerate from the run directories:\n\n```sh\n"
        + command
        + "\n```\n\n"
        + results_table(json_paths)
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("runs_dir", type=Path, help="folder of run directories")
    parser.add_argument("out_dir", type=Path, help="folder for the per-run JSON results")
    parser.add_argument("--episodes", type=int, default=10, help="episodes per seed")
    parser.add_argument("--table", type=Path, help="write the Markdown table here")
    parser.add_argument("--runs", nargs="*", help="only these run names")
    parser.add_argument(
        "--physics", nargs="*", default=[], metavar="name=value", help="physics settings"
    )
    args = parser.parse_args(argv)
    if args.episodes < 1:
        parser.error(f"episodes: must be an integer ≥ 1, got {args.episodes}")
    from pimbot.robot.evaluate import parse_physics_overrides

    overrides = parse_physics_overrides(args.physics)
    paths = evaluate_all(args.runs_dir, args.out_dir, args.episodes, overrides, args.runs)
    table = results_table(paths)
    print(table)
    if args.table:
        command = "python -m pimbot.robot.results " + " ".join(argv or sys.argv[1:])
        args.table.parent.mkdir(parents=True, exist_ok=True)
        store.write_atomic(args.table, results_document(paths, command).encode())
    return 0


if __name__ == "__main__":
    sys.exit(main())
