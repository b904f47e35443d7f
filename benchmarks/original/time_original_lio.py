"""Times the original LIO code (011235813/lio, TF 1.15) on Escape Room ER(N, M).

    LIO_VENV/bin/python benchmarks/original/time_original_lio.py LIO_CHECKOUT
        [--iterations 1000] [--warmup 100] [--n-agents 2] [--min-at-lever 1] [--seed 12340]

Runs in the Python 3.7 venv made by setup_lio.sh (this file must stay Python 3.7 code).
It imports the original's own training function, `lio.alg.train_lio.train`, and
calls it with the original's ER config (`config_room_lio.get_config()`), changing
only config values, never its logic:

* `alg.n_episodes` = warmup + iterations (the run's length);
* `env.n_agents`, `env.min_at_lever` (ER(2,1) by default, as in the config file);
* `main.save_period` past the end (no intermediate checkpoints; the final save,
  after the timed loop, is kept), `main.seed` (the config's 12340 by default).

One iteration = one `idx_episode` of the original's loop: an episode, the policy
updates, the "prime" episode, the incentive (reward) updates, `update_main`, and
every `alg.period` (100) iterations the original's evaluation (`n_eval` = 10 test
episodes), as in its training. To time iterations without editing the loop, the
module-level `train_lio.run_episode` is wrapped: the wrapper records the time at
each non-prime call (the start of an iteration) and then calls the original.
ms per iteration = (start of the last iteration − start of iteration `warmup`) /
the number of iterations between them; the first `warmup` iterations (session
start, first runs of each op) are excluded. The final checkpoint save comes after
the last iteration's start and is not timed. The same span is also measured in
process CPU time (`time.process_time`, all threads), which is less distorted than
wall time when the core is shared with other processes.

`train_lio` imports `lio.env.ipd_wrapper`, which imports LOLA's
(alshedivat/lola) `lola.envs.prisoners_dilemma` at module level; ER never uses it.
When `lola` is not installed, this script registers a stub module under that name
whose `IteratedPrisonersDilemma` raises if it is ever constructed (the only shim).

The original writes `../results/er/<dir_name>/` relative to its working directory
(it expects to run in `lio/alg`); this script runs it in a temporary directory.
It prints one line `ORIGINAL_LIO_RESULT {json}`.
"""

import argparse
import json
import os
import sys
import tempfile
import time

MARKER = "ORIGINAL_LIO_RESULT "


def install_lola_stub():
    """Registers `lola.envs.prisoners_dilemma` if LOLA is absent (ER does not use it)."""
    try:
        import lola.envs.prisoners_dilemma  # noqa: F401

        return
    except ImportError:
        pass
    import types

    class IteratedPrisonersDilemma:
        def __init__(self, *args, **kwargs):
            raise RuntimeError("LOLA stub: the IPD wrapper needs alshedivat/lola installed")

    names = ["lola", "lola.envs", "lola.envs.prisoners_dilemma"]
    modules = [types.ModuleType(name) for name in names]
    modules[2].IteratedPrisonersDilemma = IteratedPrisonersDilemma
    modules[0].envs, modules[1].prisoners_dilemma = modules[1], modules[2]
    for module in modules:
        sys.modules[module.__name__] = module


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("checkout", help="checkout of 011235813/lio (with the import fix)")
    parser.add_argument("--iterations", type=int, default=1000)
    parser.add_argument("--warmup", type=int, default=100)
    parser.add_argument("--n-agents", type=int, default=2)
    parser.add_argument("--min-at-lever", type=int, default=1)
    parser.add_argument("--seed", type=int, default=None)
    args = parser.parse_args()

    checkout = os.path.abspath(args.checkout)
    # train_lio does `from lio_agent import LIO` (it expects to run inside lio/alg),
    # so both the checkout and its lio/alg folder go on the path.
    sys.path[:0] = [checkout, os.path.join(checkout, "lio", "alg")]
    os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "2")

    install_lola_stub()

    import tensorflow as tf
    from lio.alg import config_room_lio, train_lio

    tf.compat.v1.logging.set_verbosity(tf.compat.v1.logging.ERROR)

    config = config_room_lio.get_config()
    total = args.warmup + args.iterations
    config.alg.n_episodes = total
    config.env.n_agents = args.n_agents
    config.env.min_at_lever = args.min_at_lever
    config.main.save_period = total + 1
    if args.seed is not None:
        config.main.seed = args.seed
    config.main.dir_name = f"er_n{args.n_agents}_m{args.min_at_lever}_lio_timing"

    starts = []
    cpu_starts = []
    steps = [0]
    original_run_episode = train_lio.run_episode

    def timed_run_episode(sess, env, list_agents, epsilon, prime=False):
        if not prime:
            starts.append(time.perf_counter())
            cpu_starts.append(time.process_time())
        buffers = original_run_episode(sess, env, list_agents, epsilon, prime)
        steps[0] += len(buffers[0].obs)
        return buffers

    train_lio.run_episode = timed_run_episode

    work = tempfile.mkdtemp(prefix="lio_timing_")
    alg_dir = os.path.join(work, "alg")
    os.makedirs(alg_dir)
    cwd = os.getcwd()
    os.chdir(alg_dir)
    t0 = time.perf_counter()
    try:
        train_lio.train(config)
    finally:
        os.chdir(cwd)
    wall = time.perf_counter() - t0

    assert len(starts) == total, (len(starts), total)
    # iterations warmup .. total-2 are complete between recorded starts
    timed = starts[-1] - starts[args.warmup]
    n_timed = total - 1 - args.warmup
    ms = 1e3 * timed / n_timed
    cpu_ms = 1e3 * (cpu_starts[-1] - cpu_starts[args.warmup]) / n_timed
    result = {
        "iterations_timed": n_timed,
        "warmup": args.warmup,
        "ms_per_iteration": ms,
        "seed_iterations_per_s": 1e3 / ms,
        "cpu_ms_per_iteration": cpu_ms,
        "seed_iterations_per_cpu_s": 1e3 / cpu_ms,
        "setup_and_warmup_s": starts[args.warmup] - t0,
        "wall_s": wall,
        "env_steps_total": steps[0],
        "config": f"ER({args.n_agents},{args.min_at_lever})",
        "tensorflow": tf.__version__,
        "python": sys.version.split()[0],
        "affinity": sorted(os.sched_getaffinity(0)),
        "log_dir": os.path.join(work, "results", "er", config.main.dir_name),
    }
    print(MARKER + json.dumps(result), flush=True)


if __name__ == "__main__":
    main()
