"""Converts the original PIMbot repository's log.csv files into pimbot run directories.

    .venv/bin/python benchmarks/original/import_logs.py REPO [--commit a750298…] [--out DIR]

REPO is the repository UCR-Intelligent-Robotics-Lab/greedy_agent at commit a750298:
either a checkout (its work tree) or its bare git directory, read with
``git cat-file`` at `--commit`. The output (default: pimbot's packaged
``src/pimbot/data/original_code``) is replaced: one run directory per setting,
``<game>_<horizon>k/<setting>/``, and manifest.json (see
`pimbot.analysis.original_code`); the runs made here by import_runs.py
(``made_here_*/``, manifest.json's ``made_here``) are kept. CI has no network, so the
output is committed; rerun this script only to regenerate it.

What it reads: every ``results/**/log.csv`` and ``lio/results/**/log.csv`` with the
config.json beside it, and the repository's plot scripts (``*.py``, ``*.ipynb`` at its
top level) for which settings they plot. What it decides, from the original's own
vocabulary (the tables below, each with its evidence):

* the env from config.json ``env`` (``er`` → escape_room-v0 with its n_agents and
  min_at_lever; ``ipd`` → ipd-v0), and pimbot's LIO hyperparameters from its ``lio`` and
  ``nn`` sections (a setting pimbot's LIO cannot express is left out, with the reason);
* the attack from the tokens of the setting's directory name (``er2_1_greedy_det`` →
  self_centered; the code itself was edited between runs, so the name is the record);
* seeds: byte-identical files count once (SHA-256), the copies are listed; a file whose
  bytes sit under several settings goes to the setting holding most of its copies;
  reruns of one random seed (logs of a setting whose opening rows are identical,
  `original_code.one_per_seed`) count once, the first in path order, the others listed
  as reruns; a log that stops before its configured horizon is left out and listed.
"""

from __future__ import annotations

import argparse
import collections
import json
import re
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

from pimbot import envs, learners
from pimbot.analysis import original_code
from pimbot.analysis.runs import condition_label, env_label, natural_key
from pimbot.training.config import RunConfig, env_parameters

GAMES = {"er": "escape_room-v0", "ipd": "ipd-v0"}
"""The original config's env.name -> pimbot env id."""

ATTACK_TOKENS: dict[str, tuple[str | None, tuple[tuple[str, Any], ...], str]] = {
    "pure": (None, (), "clean LIO: plot_conv.ipynb labels the *_pure_det logs 'LIO'"),
    "greedy": (
        "self_centered",
        (),
        "lio_agent_greedy.py's `greedy` flag feeds 0 for the incentives agent_0 received "
        "into its own policy update; plot_conv.ipynb labels *_greedy_det 'Partial "
        "Communication' (the paper's name)",
    ),
    "bignum": (
        "fake_incentive",
        (("amount", 10.0),),
        "lio_agent_greedy.py's adversarial == 2 ('bignum') gives 10 to every agent each step",
    ),
    "noaction": ("bypass", (), "lio_agent_greedy.py's no_acion: run_actor returns action 1"),
    "toggle": (
        "bypass",
        (("toggle_period", 1000),),
        "lio_agent_greedy.py's periodic_no_action = 1000: action 1 on alternate "
        "stretches of 1000 run_actor calls",
    ),
    "a2d": ("reverse", (), "lio_agent_greedy.py's asc_to_dec (ascent to descent)"),
}
"""Directory-name tokens of the original's settings -> (pimbot attack, parameters, evidence)."""
TOKEN_ALIASES = {"toggle43": "toggle", "bignum2": "bignum"}
"""ipd_bignum2 is a second set of fake-incentive IPD runs (train_lio.py's last IPD
dir_name); its logs do not say whether the amount differed from 10."""
PLAIN_LIO_TOKEN = "lio"
"""A name with no attack token but "lio" (er_n2_lio) is plain LIO: clean."""
POLICY_TOKEN = "policy"
POLICY_ATTACK = (
    "reverse",
    (),
    "'policy' alone (er*_policy_det): plot_a2d.ipynb reads these logs for its a2d "
    "(reverse) figures",
)
"""A name with "policy" and no attack token records the lever, not the attack: three
of lio_agent_greedy.py's module flags act on the policy (no_acion, periodic_no_action —
1000, i.e. on, in the committed file — and asc_to_dec), and no log records them. The
attack is inferred from plot_a2d.ipynb reading these logs; such a log is marked
"attack_inferred": the report shows it and names no cause on it."""

LIO_FLAGS_REQUIRED = {
    "use_actor_critic": False,
    "decentralized": False,
    "asymmetric": False,
    "include_cost_in_chain_rule": False,
    "separate_cost_optimizer": True,
    "optimizer": "adam",
    "reg": "l1",
}
"""The original LIO options pimbot's LIO implements (other values: left out)."""

CLAIM_SETTINGS = {
    "C1": ("self_centered", ("ER(2,1)", "ER(4,2)", "IPD(2)")),
    "C2": ("fake_incentive", None),
    "C3": ("bypass", ("ER(2,1)", "ER(4,3)", "ER(4,2)")),
    "C4": ("reverse", ("ER(2,1)", "ER(4,3)", "ER(4,2)")),
}
"""Claim -> (attack, env labels; None: every Escape Room) of docs/experiments.md's claims
table that these logs can speak to (C5–C8 need ADMO, Stag Hunt, Reciprocators or a
device profile: none of these logs). A clean run of a claim's env is its baseline."""

LOG_PATTERN = re.compile(r"^(?:lio/)?results/(?P<exp>[^/]+)/(?P<setting>[^/]+)/log\.csv$")
PLOT_REFERENCE = re.compile(r"lio/results/[^/'\"]+/(?P<setting>[^/'\"]+)/log\.csv")


class Repository:
    """Files of the repository at one commit: a bare git directory or a checkout."""

    def __init__(self, path: Path, commit: str):
        self.path, self.commit = Path(path), commit
        self.bare = (self.path / "HEAD").exists() and (self.path / "objects").is_dir()
        if not self.bare and (self.path / ".git").exists():
            head = self._git("-C", str(self.path), "rev-parse", "HEAD").decode().strip()
            if not head.startswith(commit[:7]) and not commit.startswith(head[:7]):
                sys.exit(f"{path}: checkout is at {head}, not {commit}")

    def _git(self, *args: str) -> bytes:
        return subprocess.run(["git", *args], check=True, capture_output=True).stdout

    def paths(self) -> list[str]:
        if self.bare:
            out = self._git(
                "--git-dir", str(self.path), "ls-tree", "-r", "-z", "--name-only", self.commit
            )
            return [p for p in out.decode().split("\0") if p]
        return [
            p.relative_to(self.path).as_posix()
            for p in self.path.rglob("*")
            if p.is_file() and ".git" not in p.relative_to(self.path).parts
        ]

    def read(self, path: str) -> bytes:
        if self.bare:
            return self._git(
                "--git-dir", str(self.path), "cat-file", "blob", f"{self.commit}:{path}"
            )
        return (self.path / path).read_bytes()


# --- the original's vocabulary -> pimbot's ------------------------------------------------


def attack_of(setting: str) -> tuple[str | None, tuple[tuple[str, Any], ...], str] | None:
    """The attack a setting's directory name records, or None if no token says."""
    tokens = [TOKEN_ALIASES.get(t, t) for t in setting.lower().split("_")]
    found = {ATTACK_TOKENS[t] for t in tokens if t in ATTACK_TOKENS}
    if len(found) > 1:
        return None
    if found:
        return found.pop()
    if POLICY_TOKEN in tokens:
        return POLICY_ATTACK
    if PLAIN_LIO_TOKEN in tokens:
        return ATTACK_TOKENS["pure"][:2] + ("plain LIO (no attack token in the name)",)
    return None


def env_of(config: dict[str, Any]) -> tuple[str, tuple[tuple[str, Any], ...]]:
    """(pimbot env id, explicit parameters that differ from the env's defaults)."""
    env_id = GAMES[config["env"]["name"]]
    e = config["env"]
    wanted = (
        {
            "n_agents": e["n_agents"],
            "min_at_lever": e["min_at_lever"],
            "max_steps": e["max_steps"],
            "randomize_start": e.get("randomize", False),
        }
        if env_id == GAMES["er"]
        else {"n_players": e["n_agents"], "max_steps": e["max_steps"]}
    )
    defaults = env_parameters(envs.make(env_id))
    return env_id, tuple(sorted((k, v) for k, v in wanted.items() if defaults.get(k) != v))


def lio_hparams(config: dict[str, Any], env_id: str) -> tuple[tuple[str, Any], ...]:
    """pimbot LIO hyperparameters that differ from its defaults for `env_id`.

    Raises:
        ValueError: the original used an option pimbot's LIO does not implement.
    """
    lio, nn = config["lio"], config["nn"]
    for key, value in LIO_FLAGS_REQUIRED.items():
        if lio.get(key, value) != value:
            raise ValueError(f"original lio.{key} = {lio.get(key)!r} (pimbot: {value!r})")
    if lio["reg_coeff"] not in (0.0, 1.0):
        raise ValueError(f"original lio.reg_coeff = {lio['reg_coeff']} (pimbot: cost on or off)")
    original = {
        "policy_hidden": (nn["n_h1"], nn["n_h2"]),
        "incentive_hidden": (nn["n_hr1"], nn["n_hr2"]),
        "lr_policy": lio["lr_actor"],
        "lr_incentive": lio["lr_reward"],
        "lr_cost": lio["lr_cost"] if lio["reg_coeff"] else 0.0,
        "incentive_max": config["env"]["r_multiplier"],
        "entropy_coef": lio["entropy_coeff"],
        "gamma": lio["gamma"],
        "epsilon_start": lio["epsilon_start"],
        "epsilon_end": lio["epsilon_end"],
        "epsilon_decay_iters": lio["epsilon_div"],
        "incentive_updates": "shared",  # the original's optimizers have no variable list
    }
    defaults = learners.get("lio").default_config(envs.spec(env_id))
    return tuple(sorted((k, v) for k, v in original.items() if getattr(defaults, k) != v))


def config_differences(configs: list[dict[str, Any]]) -> dict[str, list[Any]]:
    """Dotted keys whose values differ between the seeds' config.json files."""

    def flat(d: dict, prefix: str = "") -> dict[str, Any]:
        out = {}
        for k, v in d.items():
            out |= flat(v, f"{prefix}{k}.") if isinstance(v, dict) else {f"{prefix}{k}": v}
        return out

    flats = [flat(c) for c in configs]
    keys = sorted(set().union(*flats))
    return {
        k: sorted({json.dumps(f.get(k)) for f in flats})
        for k in keys
        if len({json.dumps(f.get(k)) for f in flats}) > 1
    }


def plot_references(repo: Repository, paths: list[str]) -> dict[str, list[str]]:
    """Setting -> the repository's top-level plot scripts that read its logs (not in comments)."""
    found: dict[str, set[str]] = collections.defaultdict(set)
    for path in paths:
        if "/" in path or not path.endswith((".py", ".ipynb")):
            continue
        text = repo.read(path).decode(errors="replace")
        if path.endswith(".ipynb"):
            cells = json.loads(text).get("cells", [])
            text = "\n".join("".join(c["source"]) for c in cells if c["cell_type"] == "code")
        for line in text.splitlines():
            if line.strip().startswith("#"):
                continue
            for match in PLOT_REFERENCE.finditer(line):
                found[match["setting"]].add(path)
    return {k: sorted(v) for k, v in found.items()}


def claims_for(env: str, condition: str | None) -> dict[str, str]:
    """Claim -> "attacked" or "clean baseline" for a run of `env` under `condition`."""
    out = {}
    for claim, (attack, settings) in CLAIM_SETTINGS.items():
        in_env = env.startswith("ER(") if settings is None else env in settings
        if in_env and condition in (attack, None):
            out[claim] = "clean baseline" if condition is None else "attacked"
    return out


# --- the import --------------------------------------------------------------------------


def import_logs(repo: Repository, out: Path) -> dict[str, Any]:
    paths = repo.paths()
    logs = {p: m for p in paths if (m := LOG_PATTERN.match(p))}
    files = {p: repo.read(p) for p in sorted(logs, key=natural_key)}
    distinct = original_code.distinct_logs(files.items())
    by_setting: dict[str, list[original_code.DistinctLog]] = collections.defaultdict(list)
    entries: dict[str, dict[str, Any]] = {}
    for log in distinct:
        settings = collections.Counter(logs[p]["setting"] for p in log.paths)
        home = max(settings, key=lambda s: (settings[s], s))
        by_setting[home].append(log)
        for p in log.paths:
            entries[p] = {"path": p, "sha256": log.sha256, "setting": logs[p]["setting"]}
            if logs[p]["setting"] != home:
                entries[p]["note"] = f"byte-identical to {log.paths[0]}: counted under {home}"
    for setting in sorted({m["setting"] for m in logs.values()} - set(by_setting)):
        for p in (p for p, m in logs.items() if m["setting"] == setting):
            entries[p] |= {"status": "left out", "reason": entries[p].get("note", "")}
    plots = plot_references(repo, paths)
    made_here = clear_shipped(out)
    runs = []
    for setting in sorted(by_setting, key=natural_key):
        runs.append(import_setting(repo, setting, by_setting[setting], plots, entries, out))
    content = {
        "repository": original_code.REPOSITORY,
        "commit": repo.commit,
        "log_files": len(files),
        "distinct_log_files": len(distinct),
        "runs": [r for r in runs if r],
        "settings_left_out": {
            s: entries[next(p for p, m in logs.items() if m["setting"] == s)]["reason"]
            for s in sorted({m["setting"] for m in logs.values()}, key=natural_key)
            if not any(r and r["setting"] == s for r in runs)
        },
        "files": [entries[p] for p in sorted(entries, key=natural_key)],
    }
    if made_here:
        content[original_code.MADE_HERE] = made_here
    original_code.write_manifest(out, content)
    return content


def clear_shipped(out: Path) -> list[dict[str, Any]]:
    """Removes what an earlier import of the shipped logs wrote to `out`, keeping the runs
    made here (``made_here_*/``, import_runs.py); returns manifest.json's list of those."""
    made_here = []
    if (out / original_code.MANIFEST).exists():
        made_here = original_code.manifest(out).get(original_code.MADE_HERE, [])
    if out.is_dir():
        for path in out.iterdir():
            if path.is_dir() and not path.name.startswith(original_code.MADE_HERE + "_"):
                shutil.rmtree(path)
            elif path.is_file():
                path.unlink()
    out.mkdir(parents=True, exist_ok=True)
    return made_here


def leave_out(entries: dict, logs: list[original_code.DistinctLog], reason: str) -> None:
    for log in logs:
        for p in log.paths:
            entries[p] |= {"status": "left out", "reason": reason}


def import_setting(
    repo: Repository,
    setting: str,
    logs: list[original_code.DistinctLog],
    plots: dict[str, list[str]],
    entries: dict[str, dict[str, Any]],
    out: Path,
) -> dict[str, Any] | None:
    configs = [
        json.loads(repo.read(log.paths[0].rsplit("/", 1)[0] + "/config.json")) for log in logs
    ]
    config = configs[0]
    game = config["env"].get("name")
    if game not in GAMES:
        what = game or config["env"].get("map_name", "unnamed")
        return leave_out(entries, logs, f"env {what} is not in pimbot")
    if "lio" not in config:
        return leave_out(
            entries, logs, f"not a LIO run (config sections: {', '.join(sorted(config))})"
        )
    attack = attack_of(setting)
    if attack is None:
        return leave_out(entries, logs, "its directory name names no attack")
    try:
        env_id, env_params = env_of(config)
        hparams = lio_hparams(config, env_id)
    except ValueError as error:
        return leave_out(entries, logs, str(error))
    horizon = int(config["alg"]["n_episodes"])
    complete, short = [], []
    for log, cfg in zip(logs, configs, strict=True):
        rows = original_code.read_log(log.data.decode())
        last = int(rows[-1]["episode"]) if rows else 0
        same = int(cfg["alg"]["n_episodes"]) == horizon
        (complete if last == horizon and same else short).append((log, last))
    for log, last in short:
        leave_out(entries, [log], f"incomplete: ends at iteration {last} of {horizon}")
    if not complete:
        return None
    seeds = original_code.one_per_seed([log for log, _ in complete])
    name, params, evidence = attack
    run = RunConfig(
        env_id=env_id,
        env_params=env_params,
        learner="lio",
        hparams=hparams,
        seeds=len(seeds),
        iterations=horizon,
        eval_period=int(config["alg"]["period"]),
        eval_episodes=int(config["alg"]["n_eval"]),
        attack=name,
        attack_params=params,
    )
    env = envs.make(env_id, **dict(env_params))
    rows, sources = [], {}
    for seed, (log, reruns) in enumerate(seeds):
        seed_rows, sources = original_code.metrics_rows(log.data.decode(), env, seed)
        rows += seed_rows
        for k, p in enumerate(log.paths):
            entries[p] |= {"status": "seed" if k == 0 else "copy", "seed": seed}
            if k:
                entries[p]["copy_of"] = log.paths[0]
        for p in (p for rerun in reruns for p in rerun.paths):
            entries[p] |= {"status": "rerun", "seed": seed, "rerun_of": log.paths[0]}
    group = f"{game}_{horizon // 1000}k"
    label = env_label(env_id, env_parameters(env))
    claims = claims_for(label, name)
    used = [log for log, _ in seeds]
    read = [log for log, _ in complete]
    used_configs = [c for c, log in zip(configs, logs, strict=True) if log in used]
    original = {
        "repository": original_code.REPOSITORY,
        "commit": repo.commit,
        "setting": setting,
        "attack_evidence": evidence,
        "attack_inferred": attack == POLICY_ATTACK,
        "files": sum(len(log.paths) for log in read),
        "distinct_files": len(read),
        "copies_merged": sum(log.copies_merged for log in read),
        "reruns_merged": len(read) - len(used),
        "seeds": [
            {
                "seed": seed,
                "sha256": log.sha256,
                "paths": list(log.paths),
                "config_seed": cfg["main"].get("seed"),
                "opening_sha256": original_code.opening_digest(log.data),
                "reruns": [rerun.paths[0] for rerun in reruns],
            }
            for seed, ((log, reruns), cfg) in enumerate(zip(seeds, used_configs, strict=True))
        ],
        "left_out": [
            {"paths": list(log.paths), "sha256": log.sha256, "ends_at": last} for log, last in short
        ],
        "shared_opening": original_code.shared_opening([log.data for log in read]),
        "read_by_plot_scripts": plots.get(setting, []),
        "claims": sorted(claims),
        "claim_roles": claims,
        "columns": sources,
        "not_in_log": [
            "eval/optimal_rate and eval/exit_success/agent_i (need per-episode outcomes)",
            "train/* and perf/* (not logged)",
        ]
        + (["eval/steps (every IPD episode lasts max_steps)"] if game != "er" else []),
        "in_log_not_carried": [
            "A<i>_received, A<i>_given (eval/received, eval/given; left out for size)",
            "the log's other columns (ER: A<i>_n_lever, A<i>_n_door, A<i>_r-lever, "
            "A<i>_r-start, A<i>_r-door; step_train, step): read the original by its path",
        ],
        "config": config,
        "config_differences": config_differences(used_configs),
    }
    for p in (p for log in read for p in log.paths):
        entries[p]["run"] = f"{group}/{setting}"
    metadata = original_code.run_metadata(run, original)
    columns = list(rows[0])
    original_code.write_run_dir(out / group / setting, metadata, columns, rows)
    condition = condition_label(name, metadata["identity"]["attack_params"], params)
    return {
        "run": f"{group}/{setting}",
        "setting": setting,
        "env": label,
        "condition": condition,
        "seeds": len(used),
        "copies_merged": original["copies_merged"],
        "reruns_merged": original["reruns_merged"],
        "left_out": len(short),
        "claims": original["claims"],
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("repo", type=Path, help="checkout or bare git directory of the repository")
    parser.add_argument("--commit", default=original_code.COMMIT)
    parser.add_argument("--out", type=Path, default=original_code.ROOT)
    args = parser.parse_args()
    content = import_logs(Repository(args.repo, args.commit), args.out)
    print(
        f"{content['log_files']} log files, {content['distinct_log_files']} distinct; "
        f"{len(content['runs'])} run directories in {args.out}"
    )
    for run in content["runs"]:
        print(
            f"  {run['run']:40s} {run['env']:8s} {run['condition']:34s} seeds {run['seeds']:2d}"
            f"  copies {run['copies_merged']:2d}  reruns {run['reruns_merged']:2d}"
            f"  left out {run['left_out']}  "
            f"{','.join(run['claims'])}"
        )
    for setting, reason in content["settings_left_out"].items():
        print(f"  left out {setting}: {reason}")


if __name__ == "__main__":
    main()
