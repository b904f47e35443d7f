"""The original LIO and Reciprocator code timed beside pimbot on one pinned core.

    python benchmarks/original/compare.py --lio LIO_CHECKOUT --reciprocator REC_CHECKOUT
        [--core 0] [--only lio reciprocator] [--rounds 1] [--json OUT]
        [--lio-venv DIR] [--reciprocator-venv DIR] [--pimbot-python PY] [--pimbot-src DIR]
        [--lio-iterations 1000] [--lio-warmup 100] [--pimbot-lio-seeds 1 10]
        [--rec-updates 12] [--rec-warmup 3] [--rec-presets original general]
        [--rec-hp NAME=VALUE ...]

Run `setup_lio.sh` and `setup_reciprocator.sh` first (same checkouts, same venv
folders, or pass --lio-venv / --reciprocator-venv). Every measurement is a separate
process started as `taskset -c CORE ...`, one after the other:

(a) original LIO, ER(2,1): `time_original_lio.py` in the TF 1.15 venv — ms per
    iteration after warm-up, i.e. 1000/ms seed-iterations/s (one seed per process);
(b) pimbot LIO, ER(2,1), same config: `time_pimbot.py lio --seeds S` for each S of
    --pimbot-lio-seeds — seed-iterations/s of `pimbot train`'s runner;
(c) original Reciprocator, 2-player IPD, 2048 games × 32 steps:
    `time_original_reciprocator.py` in the torch venv — s per update;
(d) pimbot Reciprocator at that batch: `time_pimbot.py reciprocator --preset P`
    for each P of --rec-presets (`original`: the original's IPD agent — width-2
    policy, exact VoI, one-step grudge; `general`: pimbot's general agent — 64×64
    networks, learned VoI; `defaults`: this version's ipd-v0 defaults), each with
    --rec-hp added; only hyperparameters this pimbot version has are passed.

The table gives each figure by wall time and by process CPU time (less distorted
when the core is shared) and the ratio pimbot / original per core (LIO: seed-
iterations/s; Reciprocator: original s per update / pimbot s per update). With
--rounds R the whole sequence runs R times and each figure is the median.
The stderr of every process goes to --log-dir.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
CACHE = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "pimbot-original"
MARKERS = ("ORIGINAL_LIO_RESULT ", "ORIGINAL_RECIPROCATOR_RESULT ", "PIMBOT_RESULT ")
SHOWN = (  # the figures echoed to stderr as each process ends
    "ms_per_iteration",
    "cpu_ms_per_iteration",
    "seed_iterations_per_s",
    "seed_iterations_per_cpu_s",
    "s_per_update",
    "cpu_s_per_update",
    "compile_s",
    "process_s",
)
REFERENCE = {  # the figures of issue 13, for comparison only (not used in any ratio)
    "original_lio_ms": 8.35,
    "pimbot_lio_seed_it_s": 12_600,
    "original_rec_s": 0.85,
    "pimbot_rec_defaults_s": 1.85,
    "pimbot_rec_width2_s": 0.32,
}


def run_pinned(name: str, argv: list[str], core: int, log_dir: Path, env: dict) -> dict:
    """Runs argv under `taskset -c core`; its result line as a dict."""
    cmd = ["taskset", "-c", str(core), *argv]
    log = log_dir / f"{name}.log"
    print(f"  {name}: {' '.join(cmd)}", file=sys.stderr, flush=True)
    t0 = time.perf_counter()
    with open(log, "a") as err:
        proc = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=err, text=True, env=env)
    elapsed = time.perf_counter() - t0
    for line in proc.stdout.splitlines():
        for marker in MARKERS:
            if line.startswith(marker):
                result = json.loads(line[len(marker) :])
                result["process_s"] = elapsed
                shown = {k: result[k] for k in SHOWN if result.get(k) is not None}
                print(f"    -> {json.dumps(shown)}", file=sys.stderr, flush=True)
                return result
    tail = log.read_text().splitlines()[-15:]
    raise RuntimeError(f"{name} failed (exit {proc.returncode}); end of {log}:\n" + "\n".join(tail))


def median_of(results: list[dict], key: str):
    values = [r[key] for r in results if r.get(key) is not None]
    return statistics.median(values) if values else None


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--lio", type=Path, help="checkout of 011235813/lio (setup_lio.sh applied)")
    p.add_argument("--reciprocator", type=Path, help="checkout of johnlyzhou/reciprocator")
    p.add_argument(
        "--only", nargs="+", choices=["lio", "reciprocator"], default=["lio", "reciprocator"]
    )
    p.add_argument("--core", type=int, default=0, help="the one core everything is pinned to")
    p.add_argument("--rounds", type=int, default=1)
    p.add_argument("--lio-venv", type=Path, default=CACHE / "lio-venv")
    p.add_argument("--reciprocator-venv", type=Path, default=CACHE / "reciprocator-venv")
    p.add_argument("--pimbot-python", default=sys.executable)
    p.add_argument(
        "--pimbot-src",
        type=Path,
        default=None,
        help="put this pimbot src/ first on PYTHONPATH (time another checkout)",
    )
    p.add_argument("--lio-iterations", type=int, default=1000)
    p.add_argument("--lio-warmup", type=int, default=100)
    p.add_argument("--pimbot-lio-seeds", type=int, nargs="+", default=[1, 10])
    p.add_argument("--pimbot-lio-chunks", type=int, default=4)
    p.add_argument("--pimbot-lio-chunk-iterations", type=int, default=2000)
    p.add_argument("--rec-updates", type=int, default=12)
    p.add_argument("--rec-warmup", type=int, default=3)
    p.add_argument(
        "--rec-presets",
        nargs="+",
        choices=["original", "general", "defaults"],
        default=["original", "general"],
    )
    p.add_argument("--rec-hp", nargs="*", default=[], metavar="NAME=VALUE")
    p.add_argument("--pimbot-rec-chunks", type=int, default=3)
    p.add_argument("--pimbot-rec-updates-per-chunk", type=int, default=4)
    p.add_argument("--log-dir", type=Path, default=Path("/tmp/pimbot-original-logs"))
    p.add_argument("--json", type=Path, default=None)
    args = p.parse_args()
    if "lio" in args.only and args.lio is None:
        p.error("--lio CHECKOUT is needed (or --only reciprocator)")
    if "reciprocator" in args.only and args.reciprocator is None:
        p.error("--reciprocator CHECKOUT is needed (or --only lio)")
    args.log_dir.mkdir(parents=True, exist_ok=True)

    pimbot_env = dict(os.environ)
    if args.pimbot_src is not None:
        src = str(args.pimbot_src.resolve())
        pimbot_env["PYTHONPATH"] = os.pathsep.join(
            x for x in (src, pimbot_env.get("PYTHONPATH")) if x
        )
    plain_env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}

    jobs: list[tuple[str, list[str], dict]] = []
    if "lio" in args.only:
        jobs.append(
            (
                "original_lio",
                [
                    str(args.lio_venv / "bin" / "python"),
                    str(HERE / "time_original_lio.py"),
                    str(args.lio.resolve()),
                    "--iterations",
                    str(args.lio_iterations),
                    "--warmup",
                    str(args.lio_warmup),
                ],
                plain_env,
            )
        )
        for seeds in args.pimbot_lio_seeds:
            jobs.append(
                (
                    f"pimbot_lio_s{seeds}",
                    [
                        args.pimbot_python,
                        str(HERE / "time_pimbot.py"),
                        "lio",
                        "--seeds",
                        str(seeds),
                        "--chunks",
                        str(args.pimbot_lio_chunks),
                        "--chunk-iterations",
                        str(args.pimbot_lio_chunk_iterations),
                    ],
                    pimbot_env,
                )
            )
    if "reciprocator" in args.only:
        jobs.append(
            (
                "original_reciprocator",
                [
                    str(args.reciprocator_venv / "bin" / "python"),
                    str(HERE / "time_original_reciprocator.py"),
                    str(args.reciprocator.resolve()),
                    "--updates",
                    str(args.rec_updates),
                    "--warmup",
                    str(args.rec_warmup),
                ],
                plain_env,
            )
        )
        for preset in args.rec_presets:
            jobs.append(
                (
                    f"pimbot_reciprocator_{preset}",
                    [
                        args.pimbot_python,
                        str(HERE / "time_pimbot.py"),
                        "reciprocator",
                        "--preset",
                        preset,
                        "--chunks",
                        str(args.pimbot_rec_chunks),
                        "--updates-per-chunk",
                        str(args.pimbot_rec_updates_per_chunk),
                        *(["--hp", *args.rec_hp] if args.rec_hp else []),
                    ],
                    pimbot_env,
                )
            )

    results: dict[str, list[dict]] = {name: [] for name, _, _ in jobs}
    for r in range(args.rounds):
        print(f"round {r + 1}/{args.rounds} on core {args.core}", file=sys.stderr, flush=True)
        for name, argv, env in jobs:
            results[name].append(run_pinned(name, argv, args.core, args.log_dir, env))

    print_table(results, args)
    if args.json is not None:
        args.json.write_text(
            json.dumps({"results": results, "reference": REFERENCE}, indent=1, default=str)
        )


def fmt(x, spec: str) -> str:
    return "—" if x is None else format(x, spec)


def ratio(a, b):
    return None if a is None or b is None or b == 0 else a / b


def print_table(results: dict[str, list[dict]], args: argparse.Namespace) -> None:
    print(
        f"\nAll on core {args.core} (taskset), one process after another, "
        f"{args.rounds} round(s), medians."
    )
    print(f"{'case':44} {'wall':>12} {'CPU time':>12} {'×orig wall':>10} {'×orig CPU':>10}  extra")
    if "original_lio" in results:
        o = results["original_lio"]
        o_wall = median_of(o, "seed_iterations_per_s")
        o_cpu = median_of(o, "seed_iterations_per_cpu_s")
        print("LIO, ER(2,1): seed-iterations/s")
        print(
            f"{'  original (TF ' + o[0]['tensorflow'] + '), 1 seed':44} {fmt(o_wall, '12.1f')} "
            f"{fmt(o_cpu, '12.1f')} {'1':>10} {'1':>10}  "
            f"{median_of(o, 'ms_per_iteration'):.2f} ms/iteration "
            f"({median_of(o, 'cpu_ms_per_iteration'):.2f} CPU-ms)"
        )
        for name, rs in results.items():
            if not name.startswith("pimbot_lio_s"):
                continue
            w = median_of(rs, "seed_iterations_per_s")
            c = median_of(rs, "seed_iterations_per_cpu_s")
            print(
                f"{'  pimbot, ' + str(rs[0]['seeds']) + ' seed(s)':44} {fmt(w, '12.1f')} "
                f"{fmt(c, '12.1f')} {fmt(ratio(w, o_wall), '10.1f')} "
                f"{fmt(ratio(c, o_cpu), '10.1f')}  compile {median_of(rs, 'compile_s'):.1f} s"
            )
    if "original_reciprocator" in results:
        o = results["original_reciprocator"]
        o_wall, o_cpu = median_of(o, "s_per_update"), median_of(o, "cpu_s_per_update")
        print("Reciprocator, IPD 2048 games × 32 steps: s per update")
        print(
            f"{'  original (torch ' + o[0]['torch'] + ')':44} {fmt(o_wall, '12.3f')} "
            f"{fmt(o_cpu, '12.3f')} {'1':>10} {'1':>10}  "
            f"episodes {median_of(o, 'min_episode_s'):.2f}–{median_of(o, 'max_episode_s'):.2f} s"
        )
        for name, rs in results.items():
            if not name.startswith("pimbot_reciprocator_"):
                continue
            w = median_of(rs, "s_per_update")
            c_rate = median_of(rs, "seed_iterations_per_cpu_s")
            c = None if c_rate is None else 1.0 / c_rate
            hp = ",".join(f"{k}={v}" for k, v in rs[0]["hparams_given"].items() if k != "num_envs")
            print(
                f"{'  pimbot ' + rs[0]['preset']:44} {fmt(w, '12.3f')} {fmt(c, '12.3f')} "
                f"{fmt(ratio(o_wall, w), '10.2f')} {fmt(ratio(o_cpu, c), '10.2f')}  "
                f"compile {median_of(rs, 'compile_s'):.1f} s; {hp or 'defaults'}"
            )
    ref = REFERENCE
    print(
        f"Issue 13's reference figures (quiet machine): original LIO {ref['original_lio_ms']} "
        f"ms/iteration, pimbot {ref['pimbot_lio_seed_it_s']} seed-it/s; original Reciprocator "
        f"{ref['original_rec_s']} s/update, pimbot {ref['pimbot_rec_defaults_s']} s (defaults), "
        f"{ref['pimbot_rec_width2_s']} s (width 2)."
    )


if __name__ == "__main__":
    main()
