"""Experiment tracking: a run's metric rows and config, streamed to TensorBoard, W&B or MLflow.

`pimbot train|sweep|reproduce --log tensorboard,wandb,mlflow` sends every row that
goes to metrics.csv (after each chunk's checkpoint) and the run's config.json to
each chosen backend, through the library's own client, imported only when asked.

Series: step = iteration; seed k's column C (`eval/success`, `train/…`, `perf/…`)
is the series `seed_<k>/C`:

    tensorboard  RUN_DIR/tensorboard/seed_<k>/ holds seed k's event files (a TensorBoard
                 run per seed, tag C, so the seeds overlay in one chart); the config is
                 the text summary `config` in RUN_DIR/tensorboard/. Writer: tensorboardX.
    wandb        one W&B run per pimbot run, keys `seed_<k>/C`, config = config.json.
                 Directory $WANDB_DIR or RUN_DIR; WANDB_MODE=offline needs no account.
    mlflow       one MLflow run per pimbot run (experiment $MLFLOW_EXPERIMENT_NAME or
                 "pimbot"), keys `seed_<k>/C`; params = config.json flattened
                 (`identity.learner_config.lr_policy`), artifact config.json. Store
                 $MLFLOW_TRACKING_URI or file:RUN_DIR/mlruns (MLflow's file store, opted
                 into with MLFLOW_ALLOW_FILE_STORE=true unless that is set).

A resumed run continues the same W&B and MLflow runs (their ids are kept in
RUN_DIR/tracking.json, with the last iteration each backend received), and first
sends what the interrupted session checkpointed but had not sent. Tracking never
changes what is trained or written to metrics.csv.
"""

from __future__ import annotations

import importlib.util
import json
import os
import socket
import urllib.parse
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from pimbot.envs.core import InvalidParameter
from pimbot.training import store

CLIENTS = {"tensorboard": "tensorboardX", "wandb": "wandb", "mlflow": "mlflow"}
"""Each backend and the module of its client."""
BACKENDS = tuple(CLIENTS)
INSTALL_HINT = "pip install 'pimbot[tracking]'"
IDS = "tracking.json"
"""Run-directory file keeping the W&B and MLflow run ids (a resumed run continues them)
and, under "sent", the last iteration each backend received."""
NOT_SERIES = ("iteration", "seed")
"""Row columns that name a point (step, series) rather than being a series."""


class TrackingError(InvalidParameter):
    """A bad --log value or a backend whose client is not installed."""


def parse(values: Iterable[str] | None) -> tuple[str, ...]:
    """`["tensorboard,wandb", "mlflow"]` -> the backends, once each, in the order given."""
    chosen: list[str] = []
    for value in values or ():
        for name in value.split(","):
            name = name.strip().lower()
            if name not in CLIENTS:
                raise TrackingError(
                    f"log: unknown backend {name!r}; allowed: {', '.join(BACKENDS)}"
                )
            if name not in chosen:
                chosen.append(name)
    return tuple(chosen)


def require_clients(backends: Iterable[str]) -> None:
    """Fails, naming the missing client, unless every backend's client is importable, and
    (MLflow) unless its tracking server answers within `SERVER_TIMEOUT_S`."""
    for name in backends:
        if importlib.util.find_spec(CLIENTS[name]) is None:
            raise TrackingError(f"log: {name} needs the {CLIENTS[name]} client; {INSTALL_HINT}")
        if name == "mlflow":
            check_mlflow_server(os.environ.get("MLFLOW_TRACKING_URI", ""))


SERVER_TIMEOUT_S = 5.0
"""How long the start of a run waits for a tracking server before it refuses the run."""

MLFLOW_SCHEMES = ("file", "http", "https", "databricks", "sqlite", "postgresql", "mysql", "mssql")


def check_mlflow_server(uri: str) -> None:
    """Raises TrackingError (one line) for an MLflow tracking URI of an unknown scheme, or an
    http(s) server that does not accept a connection within `SERVER_TIMEOUT_S` ("" is the
    run directory's own file store)."""
    if not uri:
        return
    parsed = urllib.parse.urlparse(uri)
    scheme = parsed.scheme.split("+")[0]
    if scheme not in MLFLOW_SCHEMES:
        raise TrackingError(
            f"log: MLFLOW_TRACKING_URI {uri[:80]!r}: unknown scheme {parsed.scheme!r}; "
            f"allowed: {', '.join(MLFLOW_SCHEMES)} (unset it to log into the run directory)"
        )
    if scheme not in ("http", "https"):
        return
    port = parsed.port or (443 if scheme == "https" else 80)
    try:
        socket.create_connection((parsed.hostname, port), timeout=SERVER_TIMEOUT_S).close()
    except OSError as error:
        raise TrackingError(
            f"log: the MLflow server {uri[:80]} did not answer within {SERVER_TIMEOUT_S:g} s "
            f"({error.strerror or type(error).__name__}); start it, or unset "
            "MLFLOW_TRACKING_URI to log into the run directory"
        ) from None


def series_name(seed: int, column: str) -> str:
    return f"seed_{seed}/{column}"


def series(rows: list[dict[str, Any]]) -> dict[int, dict[str, float]]:
    """Rows (one per seed × evaluation) -> {iteration: {"seed_<k>/<column>": value}}."""
    out: dict[int, dict[str, float]] = {}
    for row in rows:
        point = out.setdefault(int(row["iteration"]), {})
        for column, value in row.items():
            if column not in NOT_SERIES:
                point[series_name(int(row["seed"]), column)] = float(value)
    return dict(sorted(out.items()))


def flatten(config: Any, prefix: str = "") -> dict[str, str]:
    """Nested config -> {"a.b.c": "value"} (lists stay whole, as JSON)."""
    if isinstance(config, dict) and config:
        out: dict[str, str] = {}
        for key, value in config.items():
            out.update(flatten(value, f"{prefix}{key}."))
        return out
    text = config if isinstance(config, str) else json.dumps(config, default=str)
    return {prefix.rstrip("."): text}


def _read_ids(run_dir: Path) -> dict[str, Any]:
    path = run_dir / IDS
    return store.read_json(path) if path.exists() else {}


def _save_id(run_dir: Path, key: str, value: Any) -> None:
    ids = _read_ids(run_dir)
    if ids.get(key) != value:
        store.write_json(run_dir / IDS, {**ids, key: value})


class TensorBoardTracker:
    """Event files per seed under RUN_DIR/tensorboard/ (tensorboardX)."""

    def __init__(self, run_dir: Path, config: dict[str, Any], seeds: list[int]):
        from tensorboardX import SummaryWriter

        root = run_dir / "tensorboard"
        suffix = f".{os.getpid()}"  # event file names hold whole seconds: a resume's are new
        with SummaryWriter(str(root), filename_suffix=suffix) as writer:
            text = json.dumps(config, indent=2, sort_keys=True, default=str)
            writer.add_text("config", "\n".join("    " + line for line in text.splitlines()))
        self.writers = {
            seed: SummaryWriter(str(root / f"seed_{seed}"), filename_suffix=suffix)
            for seed in seeds
        }

    def log(self, rows: list[dict[str, Any]]) -> None:
        for row in rows:
            writer, step = self.writers[int(row["seed"])], int(row["iteration"])
            for column, value in row.items():
                if column not in NOT_SERIES:
                    writer.add_scalar(column, float(value), global_step=step)
        for writer in self.writers.values():
            writer.flush()

    def close(self, status: str) -> None:
        for writer in self.writers.values():
            writer.close()


class WandbTracker:
    """One W&B run; honours WANDB_MODE, WANDB_PROJECT, WANDB_ENTITY and WANDB_DIR."""

    def __init__(self, run_dir: Path, config: dict[str, Any], seeds: list[int]):
        import wandb

        run_id = _read_ids(run_dir).get("wandb")
        self.run = wandb.init(
            project=os.environ.get("WANDB_PROJECT", "pimbot"),
            dir=os.environ.get("WANDB_DIR") or str(run_dir),
            name=run_dir.name,
            id=run_id,
            resume="allow" if run_id else None,
            config=config,
            tags=[config["run_config"]["learner"], config["run_config"]["env_id"]],
            reinit="create_new",
            settings=wandb.Settings(console="off", quiet=True),  # the terminal is the bar's
        )
        _save_id(run_dir, "wandb", self.run.id)

    def log(self, rows: list[dict[str, Any]]) -> None:
        for step, point in series(rows).items():
            self.run.log(point, step=step)

    def close(self, status: str) -> None:
        self.run.finish(exit_code=0 if status == "finished" else 1)


class MlflowTracker:
    """One MLflow run, through `MlflowClient` (no global active run)."""

    BATCH = 1000  # MLflow's limit of metrics per log_batch call
    PARAM_BATCH = 100
    STATUS = {"finished": "FINISHED", "failed": "FAILED", "killed": "KILLED"}

    def __init__(self, run_dir: Path, config: dict[str, Any], seeds: list[int]):
        from mlflow.entities import Param
        from mlflow.tracking import MlflowClient

        # a server that stops answering mid-run fails the run in seconds, not after retries
        os.environ.setdefault("MLFLOW_HTTP_REQUEST_TIMEOUT", "10")
        os.environ.setdefault("MLFLOW_HTTP_REQUEST_MAX_RETRIES", "1")
        uri = os.environ.get("MLFLOW_TRACKING_URI") or (run_dir / "mlruns").resolve().as_uri()
        if uri.startswith("file:"):  # MLflow 3 keeps its file store behind an opt-in
            os.environ.setdefault("MLFLOW_ALLOW_FILE_STORE", "true")
        self.client = client = MlflowClient(tracking_uri=uri)
        name = os.environ.get("MLFLOW_EXPERIMENT_NAME", "pimbot")
        experiment = client.get_experiment_by_name(name)
        experiment_id = experiment.experiment_id if experiment else client.create_experiment(name)
        run_id = _read_ids(run_dir).get("mlflow")
        if run_id is None:
            run = client.create_run(
                experiment_id, run_name=run_dir.name, tags={"pimbot.run_dir": str(run_dir)}
            )
            run_id = run.info.run_id
            params = [Param(k[:250], v[:6000]) for k, v in flatten(config).items()]
            for i in range(0, len(params), self.PARAM_BATCH):
                client.log_batch(run_id, params=params[i : i + self.PARAM_BATCH])
            client.log_dict(run_id, config, store.CONFIG)
            _save_id(run_dir, "mlflow", run_id)
        else:
            client.update_run(run_id, status="RUNNING")
        self.run_id = run_id

    def log(self, rows: list[dict[str, Any]]) -> None:
        import time

        from mlflow.entities import Metric

        now = int(time.time() * 1000)
        metrics = [
            Metric(key, value, now, step)
            for step, point in series(rows).items()
            for key, value in point.items()
        ]
        for i in range(0, len(metrics), self.BATCH):
            self.client.log_batch(self.run_id, metrics=metrics[i : i + self.BATCH])

    def close(self, status: str) -> None:
        self.client.set_terminated(self.run_id, status=self.STATUS[status])


def _one_line(error: BaseException) -> str:
    lines = str(error).strip().splitlines()
    return lines[0] if lines else type(error).__name__


START_HINTS = {"wandb": "WANDB_MODE=offline logs without an account"}

TRACKERS = {"tensorboard": TensorBoardTracker, "wandb": WandbTracker, "mlflow": MlflowTracker}


class Trackers:
    """The chosen backends of one run, started together; `log` and `close` go to each."""

    def __init__(self, backends: Iterable[str], run_dir: Path, seeds: list[int]):
        """Starts each backend on `run_dir`, whose config.json it logs. `backends` were
        checked before anything was written (`parse`, `require_clients`: `runner.check`)."""
        self.run_dir = run_dir = Path(run_dir)
        backends = tuple(backends)
        config = store.read_json(run_dir / store.CONFIG) if backends else {}
        self.started: dict[str, Any] = {}
        for name in backends:
            try:
                self.started[name] = TRACKERS[name](run_dir, config, seeds)
            except Exception as error:
                self.close("failed")
                hint = f" ({START_HINTS[name]})" if name in START_HINTS else ""
                raise TrackingError(
                    f"log: {name} could not start: {_one_line(error)}{hint}"
                ) from error
            except BaseException:
                self.close("killed")
                raise

    def catch_up(self, done: int) -> None:
        """Sends each backend the metrics.csv rows up to iteration `done` it has not had
        (an interrupted session's last checkpointed chunk; all of them for a backend new
        to a resumed run)."""
        if not self.started or not done:
            return
        rows = store.read_metrics(self.run_dir)
        sent = _read_ids(self.run_dir).get("sent", {})
        for name in self.started:
            missing = [r for r in rows if sent.get(name, 0) < int(r["iteration"]) <= done]
            if missing:
                self.log(missing, only=(name,))

    def log(self, rows: list[dict[str, Any]], only: Iterable[str] | None = None) -> None:
        """Sends metric rows (floats or metrics.csv strings) to every backend, or `only` some."""
        names = tuple(self.started) if only is None else tuple(only)
        if not names or not rows:
            return
        for name in names:
            self.started[name].log(rows)
        sent = _read_ids(self.run_dir).get("sent", {})
        last = max(int(r["iteration"]) for r in rows)
        _save_id(self.run_dir, "sent", {**sent, **{name: last for name in names}})

    def close(self, status: str) -> None:
        """Ends every run with status "finished", "failed" or "killed"."""
        started, self.started = self.started, {}
        for tracker in started.values():
            tracker.close(status)
