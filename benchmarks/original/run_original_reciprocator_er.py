"""Runs the PIMbot code's Reciprocator Escape Room script (greedy_agent
``reciprocators/run_er.py``) for one seed, and evaluates it every ``--eval-period``
episodes without changing its training.

    REC_VENV/bin/python benchmarks/original/run_original_reciprocator_er.py TREE
        --seed S --out DIR [--episodes 5000] [--eval-period 100] [--eval-episodes 10]

TREE is the folder that setup_greedy_reciprocators.sh assembles: ``TREE/reciprocators``
(the script and its ``src``) beside ``TREE/lio`` (greedy_agent's LIO package, whose
``room_symmetric.Env`` and ``config_room_lio`` the script uses). It runs in the venv that
setup_reciprocator.sh makes. The script's own ``main()`` runs unchanged, with its own
defaults (``config_room_lio.get_config()``: ER(2,1), 5 steps; 5000 episodes, one
episode per update; ``--num`` = S, which the script parses and does not use; ``--device
cpu``). What the harness adds, all from outside:

* **Seeding.** The script seeds nothing. The harness calls ``torch.manual_seed(S)``,
  ``numpy.random.seed(S)`` and ``random.seed(S)`` before ``main()``.
* **Import stubs.** ``lio/alg/__init__.py`` and ``lio/env/__init__.py`` import every LIO
  module at package import: TensorFlow, scipy, gym (0.10's ``gym.spaces.prng``), LOLA and
  the SSD games (``social_dilemmas``). The Escape Room path uses none of them (its env
  is plain numpy). Each one that does not import is registered as a stub module whose
  every attribute is a placeholder class that raises when it is built or called.
* **Training-episode outcomes.** ``room_symmetric.Env.step`` is wrapped at class level to
  record its own ``done`` code (greedy_agent's env returns 1 when the door is open and an
  agent is at the door, 2 at ``max_steps``, 0 otherwise); the script's ``EnvWrapper``
  turns it into a bool, so the code is read before that. ``train_success`` per
  evaluation row = the share of the training episodes since the previous row that ended
  with code 1.
* **Evaluation.** The script never evaluates. After every ``--eval-period``-th episode
  (hooked on ``ValueOfInfluence.episode_reset``, the last call of the script's episode
  loop), the harness plays ``--eval-episodes`` episodes with the script's own
  ``EnvWrapper`` instance and its agents' ``ppo.policy_old.actor`` (the network
  ``Reciprocator.act`` samples from): once with actions sampled from it (pimbot's
  evaluation; a separate ``torch.Generator`` seeded with S, so the global torch stream
  of the training is not touched), once with the argmax (what greedy_agent
  ``reciprocators/evaluate.py`` ``test_er`` does). Nothing is stored in the agents'
  memories and no parameter changes, so training runs exactly as without the
  evaluation. ``success`` = the share of evaluation episodes that end with ``done``
  code 1, i.e. the team escaped (pimbot's ``eval/success``).

* **What the updates do.** The script's ``PPO.update`` normalises an episode's returns
  by their standard deviation; an episode that ends after one step has one return, whose
  ``std()`` is NaN, so the loss, the gradients and Adam's moments become NaN, and the
  script's own ``nan_to_num(0.0)`` after each step sets every weight the loss reaches to
  0. The moments stay NaN, so every later step does the same: from then on each agent
  acts uniformly at random. After every episode's updates the harness reads (changing
  nothing) whether any agent's Adam moments hold a NaN, and, at each evaluation, how far
  the acting policies are from uniform at the start of an episode (``policy_off_uniform``:
  the largest |π_i(a|s₀) − 1/|A||). ``run.json`` records the first one-step training
  episode and the first episode after which the moments were NaN.

Writes ``DIR/eval.csv`` (one row per evaluation: ``episode``, ``success``,
``success_argmax``, ``steps``, ``return_env_i``, ``steps_argmax``,
``return_env_argmax_i``, ``train_success``, ``policy_off_uniform``, ``wall_s``,
``cpu_s``) and ``DIR/run.json``,
and prints one line ``ORIGINAL_RECIPROCATOR_ER_RUN {json}``. The script's own prints
(VoI and reciprocal-reward statistics every episode) go to ``DIR/stdout.log.gz``.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import gzip
import importlib
import importlib.machinery
import io
import json
import os
import random
import sys
import time
import types
from pathlib import Path

MARKER = "ORIGINAL_RECIPROCATOR_ER_RUN "
STUBBED = (
    "tensorflow",
    "scipy",
    "scipy.stats",
    "gym",
    "gym.spaces",
    "lola",
    "lola.envs",
    "lola.envs.prisoners_dilemma",
    "social_dilemmas",
    "social_dilemmas.constants",
    "social_dilemmas.envs",
    "social_dilemmas.envs.cleanup",
)
"""Modules the LIO packages import at package import and the Escape Room path never uses."""


class _PlaceholderType(type):
    """Attributes of a placeholder are placeholders (``tf.nn.sigmoid`` as a default value)."""

    def __getattr__(cls, name):
        if name.startswith("__"):
            raise AttributeError(name)
        return _PlaceholderType(name, (_Placeholder,), {"__module__": cls.__module__})


class _Placeholder(metaclass=_PlaceholderType):
    """Stands for any attribute of a stub module; raises when built or called."""

    def __init__(self, *args, **kwargs):
        raise RuntimeError(f"{type(self).__module__} is a stub: not used on the Escape Room path")


class _StubModule(types.ModuleType):
    def __getattr__(self, name):
        if name.startswith("__"):
            raise AttributeError(name)
        return _PlaceholderType(name, (_Placeholder,), {"__module__": self.__name__})


def install_stubs() -> list[str]:
    """Registers a stub for each module of `STUBBED` that does not import; returns them."""
    stubbed = []
    for name in STUBBED:
        try:
            importlib.import_module(name)
        except ImportError:
            sys.modules[name] = _StubModule(name)
            sys.modules[name].__spec__ = importlib.machinery.ModuleSpec(name, None)
            parent, _, child = name.rpartition(".")
            if parent:
                setattr(sys.modules[parent], child, sys.modules[name])
            stubbed.append(name)
    return stubbed


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("tree", help="folder holding reciprocators/ and lio/")
    parser.add_argument("--seed", type=int, required=True)
    parser.add_argument("--episodes", type=int, default=5000)
    parser.add_argument("--eval-period", type=int, default=100)
    parser.add_argument("--eval-episodes", type=int, default=10)
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args()

    tree = os.path.abspath(args.tree)
    script_dir = os.path.join(tree, "reciprocators")
    sys.path[:0] = [script_dir, tree]
    os.environ["TQDM_DISABLE"] = "1"
    stubbed = install_stubs()

    import numpy as np
    import torch

    torch.set_num_threads(len(os.sched_getaffinity(0)))
    torch.manual_seed(args.seed)
    np.random.seed(args.seed)
    random.seed(args.seed)

    import run_er
    from lio.env import room_symmetric
    from src.agents.reciprocator import Reciprocator
    from src.agents.voi import ValueOfInfluence

    args.out.mkdir(parents=True, exist_ok=True)
    state = {"evaluating": False, "episodes": 0, "env": None, "agents": []}
    moments_seen = {"nan_from": None}
    train_codes: list[int] = []
    train_steps: list[int] = []
    eval_codes: list[int] = []
    rows: list[dict] = []
    generator = torch.Generator().manual_seed(args.seed)
    wall0, cpu0 = time.perf_counter(), time.process_time()

    original_step = room_symmetric.Env.step

    def recorded_step(self, actions, given_rewards):
        obs, rewards, done = original_step(self, actions, given_rewards)
        if done:
            (eval_codes if state["evaluating"] else train_codes).append(int(done))
            if not state["evaluating"]:
                train_steps.append(self.steps)
        return obs, rewards, done

    original_wrapper_init = run_er.EnvWrapper.__init__

    def captured_wrapper_init(self, *a, **k):
        original_wrapper_init(self, *a, **k)
        state["env"] = self

    original_agent_init = Reciprocator.__init__

    def captured_agent_init(self, *a, **k):
        original_agent_init(self, *a, **k)
        state["agents"].append(self)

    def play(sample: bool) -> tuple[float, float, list[float]]:
        env, agents = state["env"], state["agents"]
        eval_codes.clear()
        steps, returns = 0, np.zeros(len(agents))
        for _ in range(args.eval_episodes):
            obs = env.reset()
            done = False
            while not done:
                actions = []
                with torch.no_grad():
                    for i, agent in enumerate(agents):
                        probs = agent.ppo.policy_old.actor(obs[i])[0]
                        if sample:
                            actions.append(int(torch.multinomial(probs, 1, generator=generator)))
                        else:
                            actions.append(int(torch.argmax(probs)))
                obs, rewards, done_tensor, _ = env.step(torch.tensor([actions]))
                returns += rewards.numpy()[0]
                steps += 1
                done = bool(done_tensor.any())
        n = args.eval_episodes
        success = sum(code == 1 for code in eval_codes) / n
        return success, steps / n, list(returns / n)

    def evaluate():
        state["evaluating"] = True
        try:
            success, steps, returns = play(sample=True)
            success_argmax, steps_argmax, returns_argmax = play(sample=False)
        finally:
            state["evaluating"] = False
        window = train_codes[-args.eval_period :]
        row = {
            "episode": state["episodes"],
            "success": success,
            "success_argmax": success_argmax,
            "steps": steps,
            **{f"return_env_{i}": r for i, r in enumerate(returns)},
            "steps_argmax": steps_argmax,
            **{f"return_env_argmax_{i}": r for i, r in enumerate(returns_argmax)},
            "train_success": sum(code == 1 for code in window) / max(len(window), 1),
            "policy_off_uniform": off_uniform(),
            "wall_s": time.perf_counter() - wall0,
            "cpu_s": time.process_time() - cpu0,
        }
        rows.append({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in row.items()})
        print(
            f"episode {row['episode']}: success {success:.2f} (argmax {success_argmax:.2f}), "
            f"train {row['train_success']:.2f}, {row['wall_s']:.0f} s",
            file=sys.stderr,
            flush=True,
        )

    original_episode_reset = ValueOfInfluence.episode_reset

    def read_moments():
        """Notes the first episode after whose updates an agent's Adam moments hold a NaN."""
        if moments_seen["nan_from"] is not None:
            return
        for agent in state["agents"]:
            for moments in agent.ppo.optimizer.state.values():
                if any(bool(torch.isnan(m).any()) for m in moments.values() if torch.is_tensor(m)):
                    moments_seen["nan_from"] = state["episodes"]
                    return

    def off_uniform() -> float:
        """max_i max_a |π_i(a | s₀) − 1/|A||, the acting policies at an episode's start."""
        obs = state["env"].reset()
        with torch.no_grad():
            probs = [
                agent.ppo.policy_old.actor(obs[i])[0] for i, agent in enumerate(state["agents"])
            ]
        return max(float((p - 1.0 / p.numel()).abs().max()) for p in probs)

    def hooked_episode_reset(self, *a, **k):
        result = original_episode_reset(self, *a, **k)
        state["episodes"] += 1
        read_moments()
        if state["episodes"] % args.eval_period == 0:
            evaluate()
        return result

    room_symmetric.Env.step = recorded_step
    run_er.EnvWrapper.__init__ = captured_wrapper_init
    Reciprocator.__init__ = captured_agent_init
    ValueOfInfluence.episode_reset = hooked_episode_reset

    sys.argv = ["run_er.py", "--episodes", str(args.episodes), "--num", str(args.seed)]
    sys.argv += ["--device", "cpu"]
    captured = io.StringIO()
    with contextlib.redirect_stdout(captured):
        run_er.main()
    wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
    with gzip.open(args.out / "stdout.log.gz", "wt") as f:
        f.write(captured.getvalue())

    with open(args.out / "eval.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]), lineterminator="\n")
        writer.writeheader()
        writer.writerows(rows)
    result = {
        "seed": args.seed,
        "episodes": state["episodes"],
        "training_episodes_escaped": sum(code == 1 for code in train_codes),
        "final_success": float(rows[-1]["success"]),
        "final_success_argmax": float(rows[-1]["success_argmax"]),
        "first_one_step_episode": next(
            (i + 1 for i, steps in enumerate(train_steps) if steps == 1), None
        ),
        "adam_moments_nan_from_episode": moments_seen["nan_from"],
        "final_policy_off_uniform": float(rows[-1]["policy_off_uniform"]),
        "eval_period": args.eval_period,
        "eval_episodes": args.eval_episodes,
        "n_agents": len(state["agents"]),
        "stubbed_modules": stubbed,
        "wall_s": wall,
        "cpu_s": cpu,
        "ms_per_episode": 1e3 * wall / max(state["episodes"], 1),
        "cpu_ms_per_episode": 1e3 * cpu / max(state["episodes"], 1),
        "torch": torch.__version__,
        "torch_threads": torch.get_num_threads(),
        "python": sys.version.split()[0],
        "affinity": sorted(os.sched_getaffinity(0)),
    }
    (args.out / "run.json").write_text(json.dumps(result, indent=2) + "\n")
    print(MARKER + json.dumps(result), flush=True)


if __name__ == "__main__":
    main()
