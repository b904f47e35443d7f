"""Runs the PIMbot code's LIO (greedy_agent, TF 1.15) with its "reverse" policy attack on
Escape Room, one seed, and keeps the log.csv it writes.

    LIO_VENV/bin/python benchmarks/original/run_original_lio_reverse.py GREEDY_CHECKOUT
        --num K --out DIR [--iterations 25000] [--period 100] [--n-agents 2]
        [--min-at-lever 1] [--dir-name er2_1_policy_det] [--no-seed]

GREEDY_CHECKOUT is UCR-Intelligent-Robotics-Lab/greedy_agent (commit a750298: the folder
holding ``lio/alg/train_lio.py``). The script runs in the Python 3.7 venv that
setup_lio.sh makes (this file must stay Python 3.7 code). It calls the repository's own
``lio.alg.train_lio.train`` with its own ``config_room_lio.get_config()`` and changes only
what the repository's own entry point and module flags change between its runs:

* config values, as ``train_lio.py``'s ``__main__`` block does (at a750298 it is set to
  ER(4,3) and ``policy_test_toggle43``): ``env.n_agents``, ``env.min_at_lever``,
  ``main.dir_name``, ``main.exp_name`` = ``er<K>`` and ``main.seed`` = 12340 + K (the
  commented-out line of that block; the shipped ``er2_1_policy_det`` logs record exactly
  these seeds, 12341 … 12345 for er1 … er5); ``alg.n_episodes`` = ``--iterations`` (the
  config's 25 000 by default) and ``alg.period`` = ``--period`` (the config file says 500;
  every shipped ``er*_policy_det`` log has 100);
* the attack flags at the top of ``lio_agent_greedy.py``, which select the attack on
  agent_0 (the repository's runs edited them between settings): ``asc_to_dec = True``
  (the reverse attack: the greedy agent's policy-gradient steps ascend its loss),
  ``periodic_no_action = 0`` (committed as 1000, the toggling bypass of the
  ``policy_test_toggle*`` runs), ``greedy = False``, ``adversarial = 0``,
  ``random_action = False``, ``no_acion = False``. They are set as module attributes
  before ``train`` builds the graph; the file is not edited.

Seeding: ``train`` has its three seeding lines (``np.random.seed``, ``random.seed``,
``tf.set_random_seed`` with ``config.main.seed``) commented out at a750298, as the
original 011235813/lio has them active. Unless ``--no-seed`` is given, the script does
what those lines do, before ``train`` builds its graph, so a seed's run can be repeated.
It changes nothing else.

Shims: LOLA's ``lola.envs.prisoners_dilemma`` is stubbed if absent, as
time_original_lio.py does (ER never uses it); so is ``social_dilemmas`` (the SSD games:
greedy_agent's ``lio/env/__init__.py`` imports ``lio.env.ssd``, which imports
``CLEANUP_MAP`` and ``CleanupEnv`` from it; the stub's ``CleanupEnv`` raises if built);
the code writes ``../results/<exp>/<dir>/`` relative to its
working directory, so it runs in ``DIR/alg`` and its log lands in
``DIR/results/er<K>/<dir-name>/log.csv`` beside its config.json, the same layout as
the repository's ``lio/results``. Its final checkpoint is deleted afterwards (size).

Progress: every ``--period`` iterations the time is appended to ``DIR/progress.csv``
(iteration, wall s, CPU s since the start), by wrapping the module-level
``train_lio.run_episode`` (as time_original_lio.py does). It prints one line
``ORIGINAL_LIO_RUN {json}`` at the end and writes it to ``DIR/run.json``.
"""

import argparse
import glob
import json
import os
import random
import sys
import time

MARKER = "ORIGINAL_LIO_RUN "
ATTACK_FLAGS = {
    "asc_to_dec": True,
    "periodic_no_action": 0,
    "greedy": False,
    "adversarial": 0,
    "random_action": False,
    "no_acion": False,
}
"""lio_agent_greedy.py's module flags for the reverse attack (its `a2d`)."""


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


def install_social_dilemmas_stub():
    """Registers `social_dilemmas` (the SSD games) if absent: greedy_agent's
    `lio/env/__init__.py` imports `lio.env.ssd`, which imports `CLEANUP_MAP` and
    `CleanupEnv` from it at module level; Escape Room never uses them."""
    try:
        import social_dilemmas.envs.cleanup  # noqa: F401

        return
    except ImportError:
        pass
    import types

    class CleanupEnv:
        def __init__(self, *args, **kwargs):
            raise RuntimeError("social_dilemmas stub: Cleanup needs the SSD games installed")

    names = [
        "social_dilemmas",
        "social_dilemmas.constants",
        "social_dilemmas.envs",
        "social_dilemmas.envs.cleanup",
    ]
    modules = {name: types.ModuleType(name) for name in names}
    modules["social_dilemmas.constants"].CLEANUP_MAP = []
    modules["social_dilemmas.envs.cleanup"].CleanupEnv = CleanupEnv
    modules["social_dilemmas"].constants = modules["social_dilemmas.constants"]
    modules["social_dilemmas"].envs = modules["social_dilemmas.envs"]
    modules["social_dilemmas.envs"].cleanup = modules["social_dilemmas.envs.cleanup"]
    sys.modules.update(modules)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("checkout", help="checkout of UCR-Intelligent-Robotics-Lab/greedy_agent")
    parser.add_argument("--num", type=int, required=True, help="run number K: er<K>, seed 12340+K")
    parser.add_argument("--out", required=True)
    parser.add_argument("--iterations", type=int, default=None)
    parser.add_argument("--period", type=int, default=100)
    parser.add_argument("--n-agents", type=int, default=2)
    parser.add_argument("--min-at-lever", type=int, default=1)
    parser.add_argument("--dir-name", default="er2_1_policy_det")
    parser.add_argument("--no-seed", action="store_true")
    args = parser.parse_args()

    checkout = os.path.abspath(args.checkout)
    out = os.path.abspath(args.out)
    # train_lio does `from lio_agent_greedy import LIO as LIO_G` (it expects to run in
    # lio/alg), so both the checkout and its lio/alg folder go on the path.
    sys.path[:0] = [checkout, os.path.join(checkout, "lio", "alg")]
    os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "2")
    install_lola_stub()
    install_social_dilemmas_stub()

    import lio_agent_greedy
    import numpy as np
    import tensorflow as tf
    from lio.alg import config_room_lio, train_lio

    tf.compat.v1.logging.set_verbosity(tf.compat.v1.logging.ERROR)
    for name, value in ATTACK_FLAGS.items():
        assert hasattr(lio_agent_greedy, name), name
        setattr(lio_agent_greedy, name, value)

    config = config_room_lio.get_config()
    if args.iterations is not None:
        config.alg.n_episodes = args.iterations
    config.alg.period = args.period
    config.env.n_agents = args.n_agents
    config.env.min_at_lever = args.min_at_lever
    config.main.dir_name = args.dir_name
    config.main.exp_name = f"er{args.num}"
    config.main.seed = 12340 + args.num
    total = int(config.alg.n_episodes)
    config.main.save_period = total + 1
    if not args.no_seed:
        np.random.seed(config.main.seed)
        random.seed(config.main.seed)
        tf.set_random_seed(config.main.seed)

    alg_dir = os.path.join(out, "alg")
    os.makedirs(alg_dir, exist_ok=True)
    progress_path = os.path.join(out, "progress.csv")
    with open(progress_path, "w") as f:
        f.write("iteration,wall_s,cpu_s\n")
    count = [0]
    original_run_episode = train_lio.run_episode
    wall0, cpu0 = time.perf_counter(), time.process_time()

    def counted_run_episode(sess, env, list_agents, epsilon, prime=False):
        if not prime:
            if count[0] % args.period == 0:
                with open(progress_path, "a") as f:
                    wall_s, cpu_s = time.perf_counter() - wall0, time.process_time() - cpu0
                    f.write(f"{count[0]},{wall_s:.3f},{cpu_s:.3f}\n")
            count[0] += 1
        return original_run_episode(sess, env, list_agents, epsilon, prime)

    train_lio.run_episode = counted_run_episode
    cwd = os.getcwd()
    os.chdir(alg_dir)
    try:
        train_lio.train(config)
    finally:
        os.chdir(cwd)
    wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
    with open(progress_path, "a") as f:
        f.write(f"{count[0]},{wall:.3f},{cpu:.3f}\n")

    log_dir = os.path.join(out, "results", config.main.exp_name, config.main.dir_name)
    for path in glob.glob(os.path.join(log_dir, "model.ckpt*")) + glob.glob(
        os.path.join(log_dir, "checkpoint")
    ):
        os.remove(path)
    result = {
        "num": args.num,
        "seed": config.main.seed,
        "seeded": not args.no_seed,
        "iterations": count[0],
        "period": args.period,
        "env": f"ER({args.n_agents},{args.min_at_lever})",
        "attack_flags": ATTACK_FLAGS,
        "wall_s": wall,
        "cpu_s": cpu,
        "ms_per_iteration": 1e3 * wall / max(count[0], 1),
        "cpu_ms_per_iteration": 1e3 * cpu / max(count[0], 1),
        "log": os.path.join(log_dir, "log.csv"),
        "tensorflow": tf.__version__,
        "python": sys.version.split()[0],
        "affinity": sorted(os.sched_getaffinity(0)),
    }
    with open(os.path.join(out, "run.json"), "w") as f:
        json.dump(result, f, indent=2)
    print(MARKER + json.dumps(result), flush=True)


if __name__ == "__main__":
    main()
