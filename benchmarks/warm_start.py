"""A plugin learner's first `pimbot train`, cold and warm, and `pimbot check` on its file.

    python benchmarks/warm_start.py [--plugin FILE.py] [--learner NAME] [--repeats 3]

Each row is a fresh `pimbot` process (as a user runs it), timed from outside (wall
seconds and the CPU seconds of the process and its threads) and split with the
summary.json it writes (`wall_s_this_session`: from the start of training, with
`compile_s`: tracing, lowering and compiling, or loading from the persistent cache):

* start-up  = wall − wall_s_this_session (Python, imports, the plugin, the checks before
  the run starts);
* compile   = compile_s;
* first it. = start-up + compile: when the first chunk of iterations starts;
* training  = wall_s_this_session − compile_s.

"cold" runs with an empty compilation cache ($PIMBOT_CACHE_DIR pointed at a new folder),
"warm" runs the same command again on the cache the cold run filled (the median of
`--repeats`). `pimbot check` is timed the same way, cold and warm. "compiled" counts the
programs XLA compiled in the process rather than loaded from the persistent cache (from
JAX's compile log, `JAX_LOG_COMPILES=1`): 0 for a warm command that compiles nothing.
One sitting, so the rows compare; the machine's load average is printed before and
after: on a shared machine the absolute times are upper bounds and the cold/warm ratios
are what count.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
DEFAULT_PLUGIN = ROOT / "examples" / "plugins" / "actor_critic.py"


def timed(argv: list[str], env: dict[str, str]) -> tuple[float, float, int]:
    """(wall seconds, CPU seconds, programs compiled rather than loaded from the cache) of
    one `pimbot` process; fails loudly on an error."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    env = {**env, "JAX_LOG_COMPILES": "1"}
    done = subprocess.run(argv, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode != 0:
        sys.exit(f"{' '.join(argv)} failed ({done.returncode}):\n{done.stderr[-2000:]}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    finished = done.stderr.count("Finished XLA compilation of ")  # cache hits too
    loaded = done.stderr.count("Persistent compilation cache hit for ")
    return wall, cpu, finished - loaded


def pimbot(*args: str) -> list[str]:
    return [sys.executable, "-m", "pimbot.cli", *args]


def train_once(args, out: Path, env: dict[str, str]) -> dict[str, float]:
    """One first train into a new directory `out`: its wall, CPU and split seconds."""
    argv = pimbot(
        "train",
        "--plugin",
        str(args.plugin),
        args.env_id,
        "--learner",
        args.learner,
        "--seeds",
        str(args.seeds),
        "--iterations",
        str(args.iterations),
        "--out",
        str(out),
        "--quiet",
    )
    wall, cpu, compiled = timed(argv, env)
    summary = json.loads((out / "summary.json").read_text())
    session, compile_s = summary["wall_s_this_session"], summary["compile_s"]
    startup = wall - session
    return {
        "wall": wall,
        "cpu": cpu,
        "start-up": startup,
        "compile": compile_s,
        "first it.": startup + compile_s,
        "training": session - compile_s,
        "compiled": compiled,
    }


def check_once(args, env: dict[str, str]) -> dict[str, float]:
    wall, cpu, compiled = timed(pimbot("check", str(args.plugin)), env)
    return {"wall": wall, "cpu": cpu, "compiled": compiled}


def median_of(runs: list[dict[str, float]]) -> dict[str, float]:
    return {key: statistics.median(run[key] for run in runs) for key in runs[0]}


COLUMNS = ("first it.", "start-up", "compile", "training", "wall", "cpu", "compiled")


def _cell(row: dict[str, float], column: str) -> str:
    if column not in row:
        return f"{'-':>11}"
    if column == "compiled":
        return f"{row[column]:>11.0f}"
    return f"{row[column]:>10.2f}s"


def table(rows: list[tuple[str, dict[str, float]]]) -> str:
    head = f"{'':<22}" + "".join(f"{c:>11}" for c in COLUMNS)
    lines = [head]
    for name, row in rows:
        cells = "".join(_cell(row, c) for c in COLUMNS)
        lines.append(f"{name:<22}{cells}")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--plugin", type=Path, default=DEFAULT_PLUGIN)
    parser.add_argument("--learner", default="actor_critic")
    parser.add_argument("--env-id", default="escape_room-v0")
    parser.add_argument("--seeds", type=int, default=2)
    parser.add_argument("--iterations", type=int, default=3000)
    parser.add_argument("--repeats", type=int, default=3, help="warm runs (their median)")
    parser.add_argument("--no-check", action="store_true", help="skip `pimbot check`")
    args = parser.parse_args()

    work = Path(tempfile.mkdtemp(prefix="pimbot-warm-start-"))
    env = {**os.environ, "PIMBOT_CACHE_DIR": str(work / "cache")}
    load_before = os.getloadavg()
    try:
        rows = [("train, cold", train_once(args, work / "cold", env))]
        warm = [train_once(args, work / f"warm{i}", env) for i in range(args.repeats)]
        rows.append((f"train, warm (med {args.repeats})", median_of(warm)))
        if not args.no_check:
            shutil.rmtree(work / "cache")  # check, cold: an empty cache again
            rows.append(("check, cold", check_once(args, env)))
            checks = [check_once(args, env) for _ in range(args.repeats)]
            rows.append((f"check, warm (med {args.repeats})", median_of(checks)))
    finally:
        shutil.rmtree(work, ignore_errors=True)
    load_after = os.getloadavg()
    what = f"{args.learner} ({args.plugin.name}) on {args.env_id}"
    print(f"{what}: {args.seeds} seeds x {args.iterations} iterations; {os.cpu_count()} CPUs")
    print(table(rows))
    print(
        "load average (1, 5, 15 min): "
        f"before {', '.join(f'{x:.2f}' for x in load_before)}; "
        f"after {', '.join(f'{x:.2f}' for x in load_after)}"
    )


if __name__ == "__main__":
    main()
