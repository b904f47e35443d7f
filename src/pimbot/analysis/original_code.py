"""The original PIMbot code's training logs as pimbot run directories ("original code").

The PIMbot repository (UCR-Intelligent-Robotics-Lab/greedy_agent, commit a750298)
keeps the `log.csv` of its LIO runs under ``lio/results/<exp>/<setting>/``, where
``<exp>`` numbers the runs of one setting (``er1`` … ``er20``, ``ipd1`` …). Many of
those "seeds" are byte-identical copies of one file, so they are counted once. The
conversion (`benchmarks/original/import_logs.py`) writes one run directory per setting,
packaged under `ROOT` as ``<group>/<setting>/`` with ``<group>`` = the game and horizon
(``er_25k``) and ``<setting>`` = the original directory name (``er2_1_pure_det``):

- ``config.json``: ``"source": "original code"``; ``identity``, ``run_config`` and
  ``env`` in pimbot's own vocabulary (env id and parameters, attack name and
  parameters, learner and its hyperparameters), as `pimbot train` writes them; and
  ``original``: the repository, commit, every path and SHA-256 of each seed's log, how
  many copies were merged, what the opening rows the seeds share are, which claims the
  run speaks to (``claims``), which of the repository's plot scripts read the setting,
  how each pimbot column was derived from the log's columns, and what the log lacks.
- ``metrics.csv``: one row per evaluation point and seed, pimbot's column names
  (``iteration``, ``seed``, ``eval/success``, ``eval/return_ratio``, ``eval/return_env/
  agent_i`` …), so pimbot's own metric code (`pimbot.training.summary.summarize`,
  `pimbot.analysis.runs.load_table`, `pimbot.analysis.curves.read_curves`) reads it
  unchanged. Every evaluation point of every distinct log is kept (nothing is
  downsampled); a log that stops before its configured horizon is left out and listed.
- ``summary.json``: pimbot's `summarize` of the directory.

``manifest.json`` at `ROOT` accounts for every ``log.csv`` of the repository: the run
directory and seed it became, the seed it is a copy of, or why it was left out.

Interface (for the report): `run_dirs()` lists the converted run directories;
`claims_of(run_dir)` the claims a run speaks to (``original.claim_roles`` says whether as
the attacked run or as the clean baseline); `runs_for_claim("C1")` the reverse, best
series first (`preferred_order`: the series the repository's plot scripts read, i.e. the
paper's figures, `plotted_by`; then independent seeds, `independent_seeds`; then more
seeds); `summary_at(run_dir, iterations)` pimbot's summary of a run cut at a horizon,
and `truncated` the cut directory itself, so the original code and pimbot are compared
at equal horizons (convergence depends on the horizon). `pimbot.analysis.runs.load_table
(ROOT)` reads them all into a run table (as `RunTable.original`).

Runs made here. Besides the shipped logs, `ROOT` holds runs of the original code made on
this project's machine (benchmarks/original/run_original_*.py, imported by
benchmarks/original/import_runs.py), under ``made_here_<...>/<setting>/``: the PIMbot
code's LIO with its reverse attack on ER(2,1) at 25 000 iterations
(``made_here_er_25k/er2_1_a2d``, claim C4, attacked), johnlyzhou/reciprocator's IPD
trainer (``made_here_reciprocator/ipd2``, C7, clean baseline) and the PIMbot code's
Reciprocator ER script (``made_here_reciprocator/er2_1_run_er``, C7, clean baseline).
Their ``original`` block has ``made_here: true``, ``made_by``, the ``command``, the
``fixes_and_shims``, the ``run_time`` per seed, and the same keys as the shipped runs
(``seeds``, ``claims``, ``claim_roles``, ``columns`` …). `made_here` tells them apart,
`runs_made_here("C7")` lists them, `shipped_runs` the others; manifest.json lists them
under ``made_here``.

The writing side (`distinct_logs`, `metrics_rows`, `run_metadata`, `write_run_dir`) is
what the import scripts call; it reads only bytes and pimbot's own env objects.
"""

from __future__ import annotations

import csv
import dataclasses
import hashlib
import itertools
import tempfile
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

from pimbot.analysis.runs import natural_key
from pimbot.training import config as run_configs
from pimbot.training import store
from pimbot.training.summary import summarize

SOURCE = "original code"
"""config.json "source" of every converted run."""
REPOSITORY = "UCR-Intelligent-Robotics-Lab/greedy_agent"
COMMIT = "a750298569e39c1872868f0e523a50213ee0dd35"
ROOT = Path(__file__).resolve().parents[1] / "data" / "original_code"
"""The packaged run directories (`ROOT/<group>/<setting>/`) and manifest.json."""
MANIFEST = "manifest.json"
MADE_HERE = "made_here"
"""The key of the runs made here: manifest.json's list of them, and ``original.made_here``
(true) in each one's config.json; their group directories start with ``made_here_``."""
ADVERSARY = 0
"""The original code's manipulated agent: agent_0 (the log's A1) is its greedy LIO."""
VALUE_FORMAT = ".6g"
"""The logs print 4 significant digits; 6 keep every digit of sums of them."""


# --- reading the packaged runs ----------------------------------------------------------


def run_dirs(root: Path = ROOT) -> list[Path]:
    """Every converted run directory under `root` (`<group>/<setting>/`), in natural order."""
    root = Path(root)
    found = [p.parent for p in root.glob(f"*/*/{store.CONFIG}")]
    return sorted(
        (p for p in found if is_original(p)),
        key=lambda p: natural_key(p.relative_to(root).as_posix()),
    )


def is_original(run_dir: Path) -> bool:
    """Whether `run_dir`'s config.json marks it as converted from the original code."""
    path = Path(run_dir) / store.CONFIG
    if not path.exists():
        return False
    config = store.read_json(path)
    return isinstance(config, dict) and config.get("source") == SOURCE


def original_info(run_dir: Path) -> dict[str, Any]:
    """The "original" block of a converted run's config.json (repository, files, claims)."""
    return store.read_json(Path(run_dir) / store.CONFIG)["original"]


def claims_of(run_dir: Path) -> tuple[str, ...]:
    """The claims (``C1`` …) the run's logs speak to, as the import recorded them."""
    return tuple(original_info(run_dir).get("claims", ()))


def made_here(run_dir: Path) -> bool:
    """Whether the run was made here, by running the original code
    (benchmarks/original/run_original_*.py, imported by import_runs.py), rather than
    converted from the logs the PIMbot repository ships."""
    return bool(original_info(run_dir).get(MADE_HERE, False))


def shipped_runs(root: Path = ROOT) -> list[Path]:
    """The run directories converted from the repository's shipped logs."""
    return [p for p in run_dirs(root) if not made_here(p)]


def runs_made_here(claim: str | None = None, root: Path = ROOT) -> list[Path]:
    """The runs made here by running the original code (of `claim`, if given), in natural
    order. Their ``original`` block names the repository, commit, command, fixes and shims
    (``fixes_and_shims``), who made them and when (``made_by``) and each seed's wall and
    CPU time (``run_time``)."""
    return [p for p in run_dirs(root) if made_here(p) and (claim is None or claim in claims_of(p))]


def plotted_by(run_dir: Path) -> tuple[str, ...]:
    """The original repository's plot scripts that read this setting's logs (outside
    comments): the series behind the paper's figures. Empty for the other series."""
    return tuple(original_info(run_dir).get("read_by_plot_scripts", ()))


def independent_seeds(run_dir: Path) -> bool:
    """Whether the run's logs differ from their first evaluation (independent seeds) rather
    than sharing opening rows (reruns of one random seed that drift apart later)."""
    opening = original_info(run_dir)["shared_opening"]
    return opening["rows_equal_in_all_seeds"] == 0


def preferred_order(dirs: Iterable[Path]) -> list[Path]:
    """`dirs` best first for a claim's "original code" column: the series the repository's
    plot scripts read (the paper's figures), then independent seeds before reruns of one
    seed, then more seeds; ties in natural order."""

    def key(path: Path) -> tuple:
        seeds = len(original_info(path)["seeds"])
        return (not plotted_by(path), not independent_seeds(path), -seeds, natural_key(str(path)))

    return sorted(dirs, key=key)


def runs_for_claim(claim: str, root: Path = ROOT) -> list[Path]:
    """The converted run directories that speak to `claim` (``"C3"``), `preferred_order`;
    the runs made here among them (`made_here`) too."""
    return preferred_order(p for p in run_dirs(root) if claim in claims_of(p))


def manifest(root: Path = ROOT) -> dict[str, Any]:
    """manifest.json: the repository, commit, and what became of every log.csv in it."""
    return store.read_json(Path(root) / MANIFEST)


def truncated(run_dir: Path, iterations: int, out_dir: Path) -> Path:
    """A copy of `run_dir` in `out_dir` holding only the evaluation points ≤ `iterations`.

    Its identity's ``iterations`` is the horizon and its summary.json is pimbot's
    `summarize` of the cut rows, so final values and convergence are those at the
    horizon. Raises ValueError if the run is shorter than `iterations`.
    """
    run_dir, out_dir = Path(run_dir), Path(out_dir)
    config = store.read_json(run_dir / store.CONFIG)
    length = int(config["identity"]["iterations"])
    if iterations > length:
        raise ValueError(f"{run_dir}: runs {length} iterations, fewer than {iterations}")
    rows = [r for r in store.read_metrics(run_dir) if int(r["iteration"]) <= iterations]
    config["identity"] = {**config["identity"], "iterations": iterations}
    config["run_config"] = {**config["run_config"], "iterations": iterations}
    config["original"] = {**config["original"], "truncated_from": length}
    columns = list(rows[0]) if rows else ["iteration", "seed"]
    write_run_dir(out_dir, config, columns, rows)
    return out_dir


def summary_at(run_dir: Path, iterations: int | None = None) -> dict[str, Any]:
    """pimbot's `summarize` of `run_dir` cut at `iterations` (None: the whole run)."""
    if iterations is None:
        return summarize(run_dir)
    with tempfile.TemporaryDirectory() as tmp:
        return summarize(truncated(run_dir, iterations, Path(tmp) / "run"))


# --- deduplication ------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class DistinctLog:
    """One distinct log file: its bytes and every path in the repository that holds them."""

    data: bytes
    paths: tuple[str, ...]
    """In natural order (``er2`` before ``er10``); the first names the log."""

    @property
    def sha256(self) -> str:
        return hashlib.sha256(self.data).hexdigest()

    @property
    def copies_merged(self) -> int:
        return len(self.paths) - 1


def distinct_logs(files: Iterable[tuple[str, bytes]]) -> list[DistinctLog]:
    """The byte-distinct files of `files` ((path, bytes) pairs), each once, with all its
    paths; ordered by their first path in natural order."""
    by_hash: dict[str, tuple[bytes, list[str]]] = {}
    for path, data in files:
        digest = hashlib.sha256(data).hexdigest()
        by_hash.setdefault(digest, (data, []))[1].append(path)
    logs = [
        DistinctLog(data, tuple(sorted(paths, key=natural_key))) for data, paths in by_hash.values()
    ]
    return sorted(logs, key=lambda log: natural_key(log.paths[0]))


OPENING_ROWS = 3
"""A log's opening: its first evaluation rows. Logs whose openings are identical in every
column are reruns of one random seed (the original code's TF runs drift apart later):
they count as one seed. In the repository's logs, every setting either shares its
opening in all its logs (3 to 48 rows) or differs in the first row of every pair."""


def opening_digest(data: bytes) -> str:
    """SHA-256 of a log's `OPENING_ROWS` first evaluation rows (its header left out)."""
    rows = data.decode().splitlines()[1 : 1 + OPENING_ROWS]
    return hashlib.sha256("\n".join(rows).encode()).hexdigest()


def one_per_seed(logs: list[DistinctLog]) -> list[tuple[DistinctLog, list[DistinctLog]]]:
    """(the first log of each random seed, the later reruns of that seed) in the order of
    `logs`: logs with the same `opening_digest` are reruns of one seed."""
    seeds: dict[str, tuple[DistinctLog, list[DistinctLog]]] = {}
    for log in logs:
        seeds.setdefault(opening_digest(log.data), (log, []))[1].append(log)
    return [(first, reruns[1:]) for first, reruns in seeds.values()]


def shared_opening(logs: list[bytes]) -> dict[str, Any]:
    """How far the seeds' logs agree row for row from the start.

    Reruns of one random seed print identical rows until they drift apart; independent
    seeds differ from their first evaluation. Returns the evaluation points all logs
    share and the first differing iteration over pairs (min, max; None for one log).
    """
    tables = [log.decode().splitlines()[1:] for log in logs]
    common = 0
    while all(common < len(t) for t in tables) and len({t[common] for t in tables}) == 1:
        common += 1
    pairs = []
    for a, b in itertools.combinations(tables, 2):
        k = next((i for i, (x, y) in enumerate(zip(a, b, strict=False)) if x != y), None)
        if k is not None:
            pairs.append(int(float(a[k].split(",")[0])))
    return {
        "rows_equal_in_all_seeds": common if len(tables) > 1 else None,
        "pairwise_first_difference": {"min": min(pairs), "max": max(pairs)} if pairs else None,
    }


# --- converting one log ------------------------------------------------------------------


def read_log(text: str) -> list[dict[str, float]]:
    """The rows of an original log.csv as floats."""
    return [{k: float(v) for k, v in row.items()} for row in csv.DictReader(text.splitlines())]


def agents_in(columns: Iterable[str]) -> int:
    """Number of agents of a log (its ``A<i>_reward_total`` columns)."""
    return sum(1 for c in columns if c.startswith("A") and c.endswith("_reward_total"))


def joint_outcomes(env: Any) -> tuple[np.ndarray, np.ndarray]:
    """(rewards [J, N], success [J]) of every joint action of a stateless matrix game,
    one step from its reset state, read from pimbot's own env."""
    import jax
    import jax.numpy as jnp

    key = jax.random.PRNGKey(0)
    _, state = env.reset(key)
    joint = list(itertools.product(range(env.num_actions), repeat=env.num_agents))
    rewards, success = [], []
    for actions in joint:
        _, _, r, _, info = env.step(key, state, jnp.array(actions))
        rewards.append(np.asarray(r, dtype=float))
        success.append(bool(info["success"]))
    return np.array(rewards), np.array(success)


def success_bounds(
    mean_rewards: np.ndarray, outcomes: tuple[np.ndarray, np.ndarray], tol: float = 2e-3
) -> tuple[float, float]:
    """Least and largest success rate (fraction of steps with a success joint action)
    of any joint-action distribution whose mean per-step rewards are `mean_rewards` [N].

    The feasible distributions form a polytope; its extremes lie at vertices, where all
    but N + 1 joint actions have probability 0, so each vertex is one small linear
    solve. `tol` absorbs the log's 4-digit rounding. (nan, nan) if none is feasible.
    """
    rewards, success = outcomes
    n_joint = rewards.shape[0]
    a = np.vstack([rewards.T, np.ones((1, n_joint))])  # [N + 1, J]
    b = np.append(np.asarray(mean_rewards, dtype=float), 1.0)
    values = []
    for support in itertools.combinations(range(n_joint), a.shape[0]):
        sub = a[:, support]
        if abs(np.linalg.det(sub)) < 1e-12:
            continue
        p = np.linalg.solve(sub, b)
        if (p >= -tol).all() and np.abs(sub @ np.clip(p, 0, None) - b).max() <= 5 * tol:
            values.append(float(np.clip(p, 0, None) @ success[list(support)]))
    if not values:
        return float("nan"), float("nan")
    return min(values), max(values)


def metrics_rows(
    text: str, env: Any, seed: int, adversary: int = ADVERSARY
) -> tuple[list[dict[str, Any]], dict[str, str]]:
    """One seed's evaluation rows in pimbot's columns, and how each column was derived.

    Escape Room logs (``A<i>_win_rate``) give success, steps and per-agent returns; the
    matrix-game logs (``A<i>_reward_env``, per-step means) give per-agent returns, and
    success only as the bounds of `success_bounds` (``eval/success`` is their midpoint).

    Args:
        text: the log.csv.
        env: pimbot's env object of the run (its optimum and, for matrix games, its rules).
        seed: the seed number written in every row.
    """
    rows = read_log(text)
    n = agents_in(rows[0])
    if n != env.num_agents:
        raise ValueError(f"log has {n} agents, env {env.num_agents}")
    room = "A1_win_rate" in rows[0]
    per_step = 1 if room else env.max_steps  # the matrix-game logs divide by max_steps
    outcomes = None if room else joint_outcomes(env)
    optimum = getattr(env, "optimal_team_return", None)
    out = []
    for row in rows:
        values: dict[str, float] = {}
        for i in range(n):
            a = f"A{i + 1}_"
            got, given = row[a + "received"] * per_step, row[a + "given"] * per_step
            total = row[a + "reward_total"] * per_step
            env_return = row[a + "reward_env"] * per_step if not room else total - got + given
            values[f"eval/return_total/agent_{i}"] = total
            values[f"eval/return_env/agent_{i}"] = env_return
        for kind in ("env", "total"):
            mine = values[f"eval/return_{kind}/agent_{adversary}"]
            others = [values[f"eval/return_{kind}/agent_{i}"] for i in range(n) if i != adversary]
            values[f"eval/adversary_margin_{kind}"] = mine - float(np.mean(others))
        values["eval/team_return"] = sum(values[f"eval/return_env/agent_{i}"] for i in range(n))
        if optimum:
            values["eval/return_ratio"] = values["eval/team_return"] / optimum
        if room:
            values["eval/success"] = row["A1_win_rate"] / 100.0
            values["eval/steps"] = row["steps_per_eps"]
        else:
            means = [row[f"A{i + 1}_reward_env"] for i in range(n)]
            lo, hi = success_bounds(np.array(means), outcomes)
            values["eval/success_lower_bound"] = lo
            values["eval/success_upper_bound"] = hi
            values["eval/success"] = (lo + hi) / 2
        line: dict[str, Any] = {"iteration": int(row["episode"]), "seed": seed}
        line.update({k: format(v, VALUE_FORMAT) for k, v in sorted(values.items())})
        out.append(line)
    return out, column_sources(room, adversary, per_step)


def column_sources(room: bool, adversary: int, per_step: int) -> dict[str, str]:
    """What each pimbot column of a converted run is, in the log's own columns."""
    scale = "" if per_step == 1 else f" × {per_step} (the log holds per-step means)"
    a = f"A{adversary + 1}"
    sources = {
        "iteration": "episode",
        "eval/return_total/agent_i": f"A<i+1>_reward_total{scale}",
        "eval/return_env/agent_i": (
            "A<i+1>_reward_total − A<i+1>_received + A<i+1>_given"
            if room
            else f"A<i+1>_reward_env{scale}"
        ),
        "eval/adversary_margin_env": f"return_env of agent {adversary} ({a}) − mean of the others",
        "eval/adversary_margin_total": f"return_total of agent {adversary} − mean of the others",
        "eval/team_return": "Σ_i return_env",
    }
    if room:
        sources |= {
            "eval/return_ratio": "team_return / the env's optimal team return",
            "eval/success": "A1_win_rate / 100 (the code counts team wins in A1's column)",
            "eval/steps": "steps_per_eps",
        }
    else:
        sources |= {
            "eval/success_lower_bound": (
                "least all-cooperate step rate of any joint-action distribution with the "
                "logged mean rewards (the log has no action counts)"
            ),
            "eval/success_upper_bound": "largest such rate",
            "eval/success": "midpoint of the two bounds (inferred, not logged)",
        }
    return sources


# --- writing a run directory ---------------------------------------------------------------


def run_metadata(run: run_configs.RunConfig, original: dict[str, Any]) -> dict[str, Any]:
    """config.json of a converted run: pimbot's identity, run config and env of `run`
    (validated by `pimbot.training.config.resolve`), the source, and `original`."""
    resolved = run_configs.resolve(run)
    return {
        "source": SOURCE,
        "identity": resolved.identity(),
        "run_config": dataclasses.asdict(run),
        "env": {
            "id": run.env_id,
            "version": run.env_id.rsplit("-v", 1)[-1],
            "params": run_configs.env_parameters(resolved.env),
            "num_agents": resolved.env.num_agents,
            "optimal_team_return": getattr(resolved.env, "optimal_team_return", None),
        },
        "original": original,
    }


def write_run_dir(
    run_dir: Path, config: dict[str, Any], columns: list[str], rows: list[dict[str, Any]]
) -> None:
    """Writes config.json, metrics.csv (`columns`, `rows`) and summary.json (pimbot's
    `summarize` of them) to `run_dir`, replacing what a previous import wrote there."""
    run_dir = Path(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    (run_dir / store.METRICS).unlink(missing_ok=True)
    store.write_json(run_dir / store.CONFIG, config)
    with open(run_dir / store.METRICS, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=columns, lineterminator="\n")
        writer.writeheader()
        writer.writerows(rows)
    store.write_json(run_dir / store.SUMMARY, summarize(run_dir))


def write_manifest(root: Path, content: dict[str, Any]) -> None:
    store.write_json(Path(root) / MANIFEST, content)


__all__ = [
    "ROOT",
    "SOURCE",
    "DistinctLog",
    "MADE_HERE",
    "claims_of",
    "distinct_logs",
    "independent_seeds",
    "made_here",
    "manifest",
    "metrics_rows",
    "one_per_seed",
    "opening_digest",
    "plotted_by",
    "preferred_order",
    "run_dirs",
    "run_metadata",
    "runs_for_claim",
    "runs_made_here",
    "shipped_runs",
    "summary_at",
    "truncated",
    "write_run_dir",
]
