"""Imports the original-code runs made here (benchmarks/original/run_original_*.py) as
pimbot run directories beside the repository's shipped logs.

    .venv/bin/python benchmarks/original/import_runs.py [--runs /work/runs/original] [--out DIR]
        [--greedy-rec-tree /tmp/originals/greedy_rec]

`import_logs.py` converts the logs the PIMbot repository ships; this script converts
the logs that the original code wrote when it was run here, by the run scripts of this
folder, so the report reads them through the same `pimbot.analysis.original_code`
interface. Each becomes one run directory under ``DIR/made_here_*/`` (DIR defaults to
pimbot's packaged ``src/pimbot/data/original_code``) whose config.json has ``"source":
"original code"`` and an ``original`` block with ``"made_by"`` (who ran it, when),
``"made_here": true``, the repository and commit, the exact commands, the fixes and
shims, each seed's wall and CPU time, and where every pimbot column comes from.
manifest.json gets a ``made_here`` list; the shipped part of it is left as it is.

RUNS (default /work/runs/original) is where the run scripts wrote, as
benchmarks/original/README.md ("Runs imported as evidence") launches them:

* ``lio_reverse/er<K>/`` (run_original_lio_reverse.py): the PIMbot code's LIO with its
  reverse attack on ER(2,1), seed 12340 + K. Its ``results/er<K>/<dir>/log.csv`` is the
  code's own log, converted by `original_code.metrics_rows` exactly as the shipped
  ``er_25k/er2_1_policy_det`` logs are -> ``made_here_er_25k/er2_1_a2d``. A run that has
  not reached its configured horizon is left out and listed.
* ``rec_ipd/seed<S>/`` (run_original_reciprocator_ipd.py): johnlyzhou/reciprocator's
  IPDTrainer, ``configs/ipd.yaml`` -> ``made_here_reciprocator/ipd2``. Every 5th update is
  an evaluation row (pimbot's rec_ipd2 job evaluates every 5 of its 100 updates, so
  `summarize`'s final value, the mean of the last 10 evaluations, covers the same updates
  55-100); the full per-update log is kept beside it.
* ``rec_er/seed<S>/`` (run_original_reciprocator_er.py): greedy_agent's
  ``reciprocators/run_er.py`` -> ``made_here_reciprocator/er2_1_run_er``.

Each seed's own files (log.csv, updates.csv, eval.csv, run.json) are kept, gzipped, in
``logs/`` inside its run directory, with their SHA-256 in config.json.
"""

from __future__ import annotations

import argparse
import csv
import datetime
import gzip
import hashlib
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import import_logs  # noqa: E402  (this folder's shipped-log importer)

from pimbot import envs  # noqa: E402
from pimbot.analysis import original_code  # noqa: E402
from pimbot.analysis.runs import env_label  # noqa: E402
from pimbot.suites.presets import CODE_ER_RECIPROCATOR  # noqa: E402
from pimbot.training.config import RunConfig  # noqa: E402

RUNS = Path("/work/runs/original")
GREEDY_REC_TREE = Path("/tmp/originals/greedy_rec")
LIO_REPOSITORY = original_code.REPOSITORY
LIO_COMMIT = original_code.COMMIT
RECIPROCATOR_REPOSITORY = "johnlyzhou/reciprocator"
RECIPROCATOR_COMMIT = "0a9c30a"
"""johnlyzhou/reciprocator's commit of the IPD runs (its newest, README.md's "Measured")."""
GREEDY_RECIPROCATORS_COMMITS = {
    "reciprocators/run_er.py": "0c214796b341a9feaebfe7f9d0df0b6ab2794cae",
    "reciprocators/src/agents/components.py": "51a295e5ab9ca52bb063e13ea2deb1d840177519",
    "reciprocators/src/agents/memory.py": "51a295e5ab9ca52bb063e13ea2deb1d840177519",
    "reciprocators/src/agents/ppo.py": "51a295e5ab9ca52bb063e13ea2deb1d840177519",
    "reciprocators/src/agents/reciprocator.py": "51a295e5ab9ca52bb063e13ea2deb1d840177519",
    "reciprocators/src/agents/target_functions.py": "fa1881d6d16a433067880f7cbbb948a521256bcc",
}
"""greedy_agent's commit of each reciprocators/ file the ER runs used (the search index's
versions; setup_greedy_reciprocators.sh checks their SHA-256)."""
IPD_EVAL_PERIOD = 5
"""Updates between the evaluation rows of the IPD runs: pimbot's rec_ipd2 job's period."""
IPD_HPARAMS = (
    ("net_init", "fan_in_uniform"),
    ("num_envs", 2048),
    ("policy_head", "sigmoid"),
    ("voi_rewards", "after_earlier_agents"),
)
"""pimbot's Reciprocator options that docs/reciprocators.md names as the original IPD
agent's (PyTorch's initialisation, the Bernoulli actor, VoI read after the earlier agents'
in-place reciprocal reward), at the original's 2048 games per update; the other IPD
defaults are already the original's (width 2, exact VoI, one-step grudge)."""
ER_HPARAMS = tuple(sorted(CODE_ER_RECIPROCATOR))
"""The ER script's learner in pimbot's words: the suite's rec_er*_code_e1 rows, which
stand for this script (`pimbot.suites.presets.CODE_ER_RECIPROCATOR`): the registry's ER
settings (lr 1e-4, γ 0.99, K 10, clip 0.1, entropy 0.01, w 5, VoI lr 1e-3), its 'linear'
balance as ``grudge=petty``, one episode per update. So `runs.same_settings` pairs this run
with those rows. The script's own VoI refit (every episode, the last 5 episodes, minibatches
of 16, 10 epochs over at most 64 samples) has no exact pimbot equivalent (``ER_VOI_NOTE``)."""
ER_VOI_NOTE = (
    "identity = the suite's rec_er21_code_e1 row (pimbot.suites.presets."
    "CODE_ER_RECIPROCATOR), pimbot's stand-in for this script; the script's VoI refit "
    "differs from pimbot's voi_* options: every episode (target_period 1), on the last 5 "
    "episodes (target_buffer_size 5, shorter episodes zero-padded to the longest), 10 "
    "epochs (target_epochs) over at most 4 x 16 samples drawn without replacement, "
    "minibatches of 16; pimbot refits every voi_refit_period = 2 updates on voi_history = "
    "3 batches with voi_steps = 10 draws of voi_batch = 512"
)
GROUP_LIO = "made_here_er_25k"
GROUP_RECIPROCATOR = "made_here_reciprocator"


def er_finding(results: list[dict]) -> str | None:
    """What the harness saw the script's updates do (run_original_reciprocator_er.py, "What
    the updates do"), where every seed recorded it: None for runs made before it did."""
    nan_from = [r.get("adam_moments_nan_from_episode") for r in results]
    off = [r.get("final_policy_off_uniform") for r in results]
    if not results or any(x is None for x in nan_from + off):
        return None
    return (
        f"its agents stop learning at episode {min(nan_from)}–{max(nan_from)}: the first "
        "one-step episode has one return, whose std() (ppo.py) is NaN, so Adam's moments "
        "turn NaN and the script's nan_to_num(0.0) zeroes the weights at every later step; "
        f"at the last evaluation every agent acts uniformly at random (largest "
        f"|π(a|s₀) − 1/|A|| {max(off):.2g}); pimbot's normalisation (population std + 1e-8) "
        "stays finite"
    )


def sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def keep(run_dir: Path, name: str, data: bytes) -> dict[str, str]:
    """Writes `data` gzipped (reproducibly: no name, mtime 0) to ``run_dir/logs/name.gz``."""
    path = run_dir / "logs" / f"{name}.gz"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(gzip.compress(data, mtime=0))
    return {"file": path.relative_to(run_dir).as_posix(), "sha256": sha256(data)}


def made_by(date: str) -> str:
    return f"pimbot benchmarks/original, {date}"


def run_date(paths: list[Path]) -> str:
    stamp = max(p.stat().st_mtime for p in paths)
    return datetime.datetime.fromtimestamp(stamp, datetime.UTC).strftime("%Y-%m-%d")


def times(run_jsons: list[dict[str, Any]]) -> dict[str, Any]:
    wall = [float(r["wall_s"]) for r in run_jsons]
    cpu = [float(r["cpu_s"]) for r in run_jsons]
    return {
        "per_seed_wall_s": [round(w, 1) for w in wall],
        "per_seed_cpu_s": [round(c, 1) for c in cpu],
        "total_wall_s": round(sum(wall), 1),
        "total_cpu_s": round(sum(cpu), 1),
        "where": "one seed per process, one process at a time, pinned to core 1 of a 2-core "
        "machine shared with other work (wall > CPU time where the core was shared)",
    }


def env_columns(values: dict[str, float], n: int, optimum: float | None, adversary: int = 0):
    """Adds team return, return ratio and the env-return margin of agent `adversary`."""
    team = sum(values[f"eval/return_env/agent_{i}"] for i in range(n))
    values["eval/team_return"] = team
    if optimum:
        values["eval/return_ratio"] = team / optimum
    others = [values[f"eval/return_env/agent_{i}"] for i in range(n) if i != adversary]
    values["eval/adversary_margin_env"] = values[f"eval/return_env/agent_{adversary}"] - float(
        np.mean(others)
    )


def formatted(iteration: int, seed: int, values: dict[str, float]) -> dict[str, Any]:
    line: dict[str, Any] = {"iteration": iteration, "seed": seed}
    line.update({k: format(v, original_code.VALUE_FORMAT) for k, v in sorted(values.items())})
    return line


# --- the PIMbot code's LIO, reverse attack ---------------------------------------------------


def import_lio_reverse(runs: Path, out: Path) -> dict[str, Any] | None:
    base = runs / "lio_reverse"
    found = sorted(base.glob("er*/run.json"), key=lambda p: int(p.parent.name[2:]))
    if not found:
        return None
    complete, short = [], []
    for path in found:
        result = json.loads(path.read_text())
        log = next(path.parent.glob("results/*/*/log.csv"))
        config = json.loads((log.parent / "config.json").read_text())
        rows = original_code.read_log(log.read_text())
        last = int(rows[-1]["episode"]) if rows else 0
        horizon = int(config["alg"]["n_episodes"])
        entry = (path.parent, result, log, config, last, horizon)
        (complete if last == horizon else short).append(entry)
    if not complete:
        return None
    config = complete[0][3]
    horizon = int(config["alg"]["n_episodes"])
    short += [p for p in complete if p[5] != horizon]  # another horizon: another run
    complete = [p for p in complete if p[5] == horizon]
    env_id, env_params = import_logs.env_of(config)
    hparams = import_logs.lio_hparams(config, env_id)
    env = envs.make(env_id, **dict(env_params))
    run = RunConfig(
        env_id=env_id,
        env_params=env_params,
        learner="lio",
        hparams=hparams,
        seeds=len(complete),
        iterations=horizon,
        eval_period=int(config["alg"]["period"]),
        eval_episodes=int(config["alg"]["n_eval"]),
        attack="reverse",
        attack_params=(),
    )
    run_dir = out / GROUP_LIO / "er2_1_a2d"
    rows, sources, seeds, logs = [], {}, [], []
    for seed, (_, result, log, cfg, _, _) in enumerate(complete):
        data = log.read_bytes()
        seed_rows, sources = original_code.metrics_rows(data.decode(), env, seed)
        rows += seed_rows
        logs.append(data)
        kept = keep(run_dir, f"er{result['num']}.log.csv", data)
        seeds.append(
            {
                "seed": seed,
                "sha256": kept["sha256"],
                "paths": [kept["file"]],
                "config_seed": cfg["main"]["seed"],
                "exp_name": cfg["main"]["exp_name"],
                "opening_sha256": original_code.opening_digest(data),
                "reruns": [],
                "wall_s": round(result["wall_s"], 1),
                "cpu_s": round(result["cpu_s"], 1),
                "ms_per_iteration": round(result["ms_per_iteration"], 2),
                "cpu_ms_per_iteration": round(result["cpu_ms_per_iteration"], 2),
            }
        )
    label = env_label(env_id, import_logs.env_parameters(env))
    claims = import_logs.claims_for(label, "reverse")
    date = run_date([p[2] for p in complete])
    original = {
        "repository": LIO_REPOSITORY,
        "commit": LIO_COMMIT,
        "made_here": True,
        "made_by": made_by(date),
        "setting": config["main"]["dir_name"],
        "attack_evidence": (
            "lio_agent_greedy.py's module flags set by the harness before the graph is built: "
            "asc_to_dec = True (the reverse attack: agent_0's policy-gradient steps ascend its "
            "loss), periodic_no_action = 0 (committed as 1000, the toggle runs), greedy = "
            "False, adversarial = 0, random_action = False, no_acion = False"
        ),
        "attack_inferred": False,
        "command": (
            "taskset -c 1 LIO_VENV/bin/python benchmarks/original/run_original_lio_reverse.py "
            "GREEDY_CHECKOUT --num K --out /work/runs/original/lio_reverse/erK "
            f"(K = {', '.join(str(p[1]['num']) for p in complete)}; defaults --iterations "
            "25000 from config_room_lio.py, --period 100, --n-agents 2, --min-at-lever 1, "
            "--dir-name er2_1_policy_det)"
        ),
        "entry_point": "lio.alg.train_lio.train(config_room_lio.get_config()) of the checkout",
        "one_line_fix": None,
        "fixes_and_shims": [
            "none to the code: greedy_agent's lio_agent.py already has the import fix "
            "that setup_lio.sh applies to 011235813/lio",
            "config values as train_lio.py's __main__ sets them: env.n_agents 2, "
            "env.min_at_lever 1, main.dir_name, main.exp_name erK, main.seed 12340 + K; "
            "alg.period 100 (the config file has 500; the shipped er*_policy_det logs 100)",
            "seeding: np.random.seed, random.seed and tf.set_random_seed(main.seed) before "
            "train() builds the graph (the three lines train() has commented out)",
            "stubs for LOLA (lola.envs.prisoners_dilemma) and the SSD games "
            "(social_dilemmas), imported by lio/env/__init__.py, unused by Escape Room",
        ],
        "reproduces_shipped_log": (
            "a check before the runs: K = 1 (seed 12341) for 300 iterations gives the "
            "shipped lio/results/er1/er2_1_policy_det/log.csv's first three rows' "
            "episode steps (668, 1363, 2041), lever and door counts and win rates exactly, "
            "and its incentive values to 2-3 digits; so the shipped er2_1_policy_det logs "
            "were seeded 12340 + K and made with asc_to_dec on"
        ),
        "environment": "Python 3.7.16, tensorflow 1.15.5, numpy 1.18.5 (setup_lio.sh)",
        "run_time": times([p[1] for p in complete]),
        "files": len(complete),
        "distinct_files": len(complete),
        "copies_merged": 0,
        "reruns_merged": 0,
        "seeds": seeds,
        "left_out": [
            {"run": str(folder.relative_to(runs)), "ends_at": last, "of": of}
            for folder, _, _, _, last, of in short
        ],
        "shared_opening": original_code.shared_opening(logs),
        "read_by_plot_scripts": [],
        "claims": sorted(claims),
        "claim_roles": claims,
        "columns": sources,
        "not_in_log": [
            "eval/optimal_rate and eval/exit_success/agent_i (need per-episode outcomes)",
            "train/* and perf/* (not logged)",
        ],
        "config": config,
        "config_differences": import_logs.config_differences([p[3] for p in complete]),
    }
    metadata = original_code.run_metadata(run, original)
    original_code.write_run_dir(run_dir, metadata, list(rows[0]), rows)
    return summary_entry(run_dir, out, label, "reverse", original)


# --- the Reciprocator's IPD trainer -------------------------------------------------------------


def read_csv(path: Path) -> list[dict[str, str]]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def import_reciprocator_ipd(runs: Path, out: Path) -> dict[str, Any] | None:
    base = runs / "rec_ipd"
    found = sorted(base.glob("seed*/run.json"), key=lambda p: int(p.parent.name[4:]))
    results = [json.loads(p.read_text()) for p in found]
    complete = [(p.parent, r) for p, r in zip(found, results, strict=True) if r["updates"] >= 100]
    if not complete:
        return None
    updates = int(complete[0][1]["updates"])
    max_steps = int(complete[0][1]["max_steps"])
    env_params = (("max_steps", max_steps), ("n_players", 2))
    env = envs.make("ipd-v0", **dict(env_params))
    run = RunConfig(
        env_id="ipd-v0",
        env_params=env_params,
        learner="reciprocator",
        hparams=IPD_HPARAMS,
        seeds=len(complete),
        iterations=updates,
        eval_period=IPD_EVAL_PERIOD,
        eval_episodes=int(complete[0][1]["batch_size"]),
        attack=None,
    )
    run_dir = out / GROUP_RECIPROCATOR / "ipd2"
    optimum = getattr(env, "optimal_team_return", None)
    rows, seeds = [], []
    for seed, (folder, result) in enumerate(complete):
        data = (folder / "updates.csv").read_bytes()
        kept = keep(run_dir, f"seed{result['seed']}.updates.csv", data)
        trainer_log = sorted(folder.glob("out_*.json"))
        name = f"seed{result['seed']}.{trainer_log[-1].name}"
        kept_log = keep(run_dir, name, trainer_log[-1].read_bytes())
        for row in read_csv(folder / "updates.csv"):
            update = int(row["update"])
            if update % IPD_EVAL_PERIOD:
                continue
            values = {"eval/success": float(row["mutual_cooperation"])}
            for i in (0, 1):
                values[f"eval/return_env/agent_{i}"] = float(row[f"reward_{i}"]) * max_steps
                values[f"train/action_0_rate/agent_{i}"] = float(row[f"p_cooperate_{i}"])
            env_columns(values, 2, optimum)
            values["train/success"] = values["eval/success"]
            rows.append(formatted(update, seed, values))
        seeds.append(
            {
                "seed": seed,
                "torch_seed": result["seed"],
                "sha256": kept["sha256"],
                "paths": [kept["file"]],
                "trainer_log": kept_log,
                "final_mutual_cooperation_last_update": result["final_mutual_cooperation"],
                "wall_s": round(result["wall_s"], 1),
                "cpu_s": round(result["cpu_s"], 1),
            }
        )
    date = run_date([f / "run.json" for f, _ in complete])
    seeds_run = [r["seed"] for _, r in complete]
    original = {
        "repository": RECIPROCATOR_REPOSITORY,
        "commit": RECIPROCATOR_COMMIT,
        "made_here": True,
        "made_by": made_by(date),
        "setting": "configs/ipd.yaml",
        "attack_evidence": "clean: two Reciprocators, configs/ipd.yaml's agents.types",
        "attack_inferred": False,
        "command": (
            "taskset -c 1 REC_VENV/bin/python benchmarks/original/"
            "run_original_reciprocator_ipd.py RECIPROCATOR_CHECKOUT --seed S --updates "
            f"{updates} --out /work/runs/original/rec_ipd/seedS "
            f"(S = {', '.join(map(str, seeds_run))})"
        ),
        "entry_point": (
            "src.training.ipd_trainer.IPDTrainer(configs/ipd.yaml).train(100) of the checkout"
        ),
        "one_line_fix": None,
        "fixes_and_shims": [
            "none to the code",
            "config values: random_seed = S, name, logs.checkpoint_interval past the end",
            "seeding: torch.manual_seed(S) before the trainer is built (the trainer stores "
            "random_seed and never uses it)",
            "the mutual-cooperation rate is counted by wrapping the trainer's "
            "logs.update(actions) on the instance (rows of actions all 0)",
            "not via run.py, which imports src.training.cleanup_trainer (not in the repository)",
        ],
        "environment": (
            f"Python {complete[0][1]['python']}, torch {complete[0][1]['torch']} on the CPU, "
            f"{complete[0][1]['torch_threads']} thread (setup_reciprocator.sh; the original "
            "pins torch 2.1.2)"
        ),
        "run_time": times([r for _, r in complete]),
        "files": len(complete),
        "distinct_files": len(complete),
        "copies_merged": 0,
        "reruns_merged": 0,
        "seeds": seeds,
        "left_out": [
            str(f.relative_to(runs))
            for f, r in zip(found, results, strict=True)
            if r["updates"] < 100
        ],
        "shared_opening": original_code.shared_opening(
            [(f / "updates.csv").read_bytes() for f, _ in complete]
        ),
        "read_by_plot_scripts": [],
        "claims": ["C7"],
        "claim_roles": {"C7": "clean baseline"},
        "columns": {
            "iteration": "update (one episode of the trainer's loop: 2048 games × 32 steps, "
            f"then both agents' updates); every {IPD_EVAL_PERIOD}th update is a row",
            "eval/success": "mutual_cooperation: the share of the update's 2048 × 32 "
            "game-steps in which both players cooperate (counted by the harness from the "
            "training episode's own sampled actions; the original logs no evaluation)",
            "train/success": "the same as eval/success (pimbot's name for the training "
            "batch's rate)",
            "train/action_0_rate/agent_i": "the trainer's own log: player_i p(cooperate), "
            "the share of its actions that cooperate",
            "eval/return_env/agent_i": f"the trainer's own log: player_i reward × {max_steps} "
            "(it logs the mean reward per step)",
            "eval/team_return": "Σ_i return_env",
            "eval/return_ratio": "team_return / the env's optimal team return",
            "eval/adversary_margin_env": "return_env of agent 0 − agent 1's",
        },
        "not_in_log": [
            "separate evaluation episodes (the rows are the training batch of each update)",
            "eval/return_total (the reciprocal reward is not logged per step)",
        ],
        "config": "configs/ipd.yaml of the checkout, random_seed = S",
        "config_differences": {"random_seed": [str(s) for s in seeds_run]},
    }
    metadata = original_code.run_metadata(run, original)
    original_code.write_run_dir(run_dir, metadata, list(rows[0]), rows)
    return summary_entry(run_dir, out, "IPD(2)", "clean", original)


# --- the PIMbot code's Reciprocator ER script --------------------------------------------------


def import_reciprocator_er(runs: Path, out: Path, tree: Path) -> dict[str, Any] | None:
    base = runs / "rec_er"
    found = sorted(base.glob("seed*/run.json"), key=lambda p: int(p.parent.name[4:]))
    results = [json.loads(p.read_text()) for p in found]
    complete = [(p.parent, r) for p, r in zip(found, results, strict=True) if r["episodes"] >= 5000]
    if not complete:
        return None
    episodes = int(complete[0][1]["episodes"])
    env_id, env_params = "escape_room-v0", (("min_at_lever", 1), ("n_agents", 2))
    env = envs.make(env_id, **dict(env_params))
    run = RunConfig(
        env_id=env_id,
        env_params=tuple(
            (k, v) for k, v in env_params if import_logs.env_parameters(envs.make(env_id))[k] != v
        ),
        learner="reciprocator",
        hparams=ER_HPARAMS,
        seeds=len(complete),
        iterations=episodes,
        eval_period=int(complete[0][1]["eval_period"]),
        eval_episodes=int(complete[0][1]["eval_episodes"]),
        attack=None,
    )
    run_dir = out / GROUP_RECIPROCATOR / "er2_1_run_er"
    optimum = getattr(env, "optimal_team_return", None)
    rows, seeds = [], []
    for seed, (folder, result) in enumerate(complete):
        data = (folder / "eval.csv").read_bytes()
        kept = keep(run_dir, f"seed{result['seed']}.eval.csv", data)
        for row in read_csv(folder / "eval.csv"):
            values = {
                "eval/success": float(row["success"]),
                "eval/success_argmax": float(row["success_argmax"]),
                "eval/steps": float(row["steps"]),
            }
            for i in range(2):
                values[f"eval/return_env/agent_{i}"] = float(row[f"return_env_{i}"])
            env_columns(values, 2, optimum)
            values["train/success"] = float(row["train_success"])
            rows.append(formatted(int(row["episode"]), seed, values))
        seeds.append(
            {
                "seed": seed,
                "torch_seed": result["seed"],
                "sha256": kept["sha256"],
                "paths": [kept["file"]],
                "training_episodes_escaped": result["training_episodes_escaped"],
                "wall_s": round(result["wall_s"], 1),
                "cpu_s": round(result["cpu_s"], 1),
                "ms_per_episode": round(result["ms_per_episode"], 1),
            }
        )
    sources = []
    listing = tree / "SOURCES.txt"
    if listing.exists():
        for line in listing.read_text().splitlines():
            if line.startswith("#") or not line.strip():
                continue
            digest, path, origin = line.split("  ", 2)
            if "greedy_agent reciprocators/" in origin:
                origin = f"greedy_agent {GREEDY_RECIPROCATORS_COMMITS.get(path, '?')[:7]}"
            elif origin.startswith("greedy_agent"):
                origin = f"greedy_agent {LIO_COMMIT[:7]}"
            else:
                origin = f"{RECIPROCATOR_REPOSITORY} {RECIPROCATOR_COMMIT}"
            if path.startswith("reciprocators/src/agents/") or path in (
                "reciprocators/run_er.py",
                "lio/env/room_symmetric.py",
                "lio/env/room_agent.py",
                "lio/alg/config_room_lio.py",
            ):
                sources.append({"path": path, "sha256": digest, "from": origin})
    date = run_date([f / "run.json" for f, _ in complete])
    seeds_run = [r["seed"] for _, r in complete]
    first = complete[0][1]
    original = {
        "repository": LIO_REPOSITORY,
        "commit": GREEDY_RECIPROCATORS_COMMITS["reciprocators/run_er.py"],
        "made_here": True,
        "made_by": made_by(date),
        "setting": "reciprocators/run_er.py",
        "attack_evidence": "clean: the script trains two Reciprocators ('linear' balance)",
        "attack_inferred": False,
        "command": (
            "taskset -c 1 REC_VENV/bin/python benchmarks/original/"
            "run_original_reciprocator_er.py TREE --seed S --out /work/runs/original/rec_er/"
            f"seedS (S = {', '.join(map(str, seeds_run))}; defaults --episodes {episodes}, "
            f"--eval-period {first['eval_period']}, --eval-episodes {first['eval_episodes']}; "
            "TREE from setup_greedy_reciprocators.sh)"
        ),
        "entry_point": "run_er.main() of the tree, unchanged: python run_er.py --episodes "
        f"{episodes} --num S --device cpu",
        "one_line_fix": None,
        "fixes_and_shims": [
            "none to the code: the stored run_er.py (greedy_agent 0c21479) never evaluates, so "
            "nothing in it reads env.num_agents of the LIO env (reciprocators/evaluate.py's "
            "test_er does; the script's EnvWrapper has num_agents); the harness evaluates "
            "from outside",
            "seeding: torch.manual_seed(S), numpy.random.seed(S), random.seed(S) before "
            "main() (the script seeds nothing)",
            "import stubs for modules that lio/alg/__init__.py and lio/env/__init__.py import "
            f"and Escape Room never uses: {', '.join(first['stubbed_modules'])}",
            "the tree: greedy_agent's reciprocators/ files at the versions this workplace's "
            "search index holds, over johnlyzhou/reciprocator 0a9c30a for the files it does "
            "not (voi.py, naive_learner.py, agent.py, utils.py, …), beside greedy_agent "
            "a750298's lio/ (see sources)",
        ],
        "sources": sources,
        "learner_config_note": ER_VOI_NOTE,
        "finding": er_finding([r for _, r in complete]),
        "environment": (
            f"Python {first['python']}, torch {first['torch']} on the CPU, "
            f"{first['torch_threads']} thread (setup_reciprocator.sh's venv)"
        ),
        "run_time": times([r for _, r in complete]),
        "files": len(complete),
        "distinct_files": len(complete),
        "copies_merged": 0,
        "reruns_merged": 0,
        "seeds": seeds,
        "left_out": [
            {"run": str(f.relative_to(runs)), "episodes": r["episodes"]}
            for f, r in zip(found, results, strict=True)
            if r["episodes"] < 5000
        ],
        "shared_opening": original_code.shared_opening(
            [(f / "eval.csv").read_bytes() for f, _ in complete]
        ),
        "read_by_plot_scripts": [],
        "claims": ["C7"],
        "claim_roles": {"C7": "clean baseline"},
        "columns": {
            "iteration": "training episodes so far (one episode per update)",
            "eval/success": "share of the harness's evaluation episodes (actions sampled from "
            "each agent's ppo.policy_old.actor, as Reciprocator.act does; own torch "
            "Generator) that end with the env's done code 1: door open and an agent at the "
            "door, pimbot's success",
            "eval/success_argmax": "the same with the argmax action, as greedy_agent "
            "reciprocators/evaluate.py test_er plays",
            "eval/steps": "mean steps of the sampled evaluation episodes",
            "eval/return_env/agent_i": "mean env return of the sampled evaluation episodes",
            "eval/team_return": "Σ_i return_env",
            "eval/return_ratio": "team_return / the env's optimal team return",
            "eval/adversary_margin_env": "return_env of agent 0 − agent 1's",
            "train/success": "share of the training episodes since the previous row that "
            "ended with done code 1 (read from the env before the script's wrapper turns it "
            "into a bool)",
        },
        "not_in_log": ["the script logs nothing; every column is the harness's"],
        "config": "config_room_lio.get_config() of greedy_agent a750298: ER(2,1), 5 steps",
        "config_differences": {"seed": [str(s) for s in seeds_run]},
    }
    metadata = original_code.run_metadata(run, original)
    original_code.write_run_dir(run_dir, metadata, list(rows[0]), rows)
    return summary_entry(run_dir, out, "ER(2,1)", "clean", original)


def summary_entry(
    run_dir: Path, out: Path, env: str, condition: str, original: dict[str, Any]
) -> dict[str, Any]:
    summary = json.loads((run_dir / "summary.json").read_text())
    return {
        "run": run_dir.relative_to(out).as_posix(),
        "repository": original["repository"],
        "commit": original["commit"],
        "made_by": original["made_by"],
        "env": env,
        "condition": condition,
        "seeds": len(original["seeds"]),
        "claims": original["claims"],
        "final_success_per_seed": [
            round(v, 4) for v in summary["final"]["eval/success"]["per_seed"]
        ],
        "run_time": original["run_time"],
        "left_out": original["left_out"],
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=Path, default=RUNS)
    parser.add_argument("--out", type=Path, default=original_code.ROOT)
    parser.add_argument("--greedy-rec-tree", type=Path, default=GREEDY_REC_TREE)
    args = parser.parse_args()
    entries = [
        import_lio_reverse(args.runs, args.out),
        import_reciprocator_ipd(args.runs, args.out),
        import_reciprocator_er(args.runs, args.out, args.greedy_rec_tree),
    ]
    entries = [e for e in entries if e]
    manifest = original_code.manifest(args.out)
    made = {e["run"]: e for e in manifest.get(original_code.MADE_HERE, [])}
    made.update({e["run"]: e for e in entries})
    manifest[original_code.MADE_HERE] = [made[k] for k in sorted(made)]
    original_code.write_manifest(args.out, manifest)
    for e in entries:
        per_seed = " ".join(f"{v:.3f}" for v in e["final_success_per_seed"])
        print(
            f"{e['run']:36s} {e['env']:8s} {e['condition']:8s} seeds {e['seeds']:2d} "
            f"{e['run_time']['total_wall_s']:.0f} s wall  final success {per_seed}"
        )


if __name__ == "__main__":
    main()
