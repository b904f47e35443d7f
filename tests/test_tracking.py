"""Experiment tracking (--log): each backend's own reader gets back what metrics.csv holds.

TensorBoard's EventAccumulator, W&B's offline transaction log (parsed with wandb's
protobuf records) and MlflowClient against the default file store; a bad or
uninstalled backend is one line, exit 2, nothing written; and neither tracking nor
the progress display changes metrics.csv.
"""

from __future__ import annotations

import csv
import json
import sys
from pathlib import Path

import numpy as np
import pytest

from pimbot import cli
from pimbot.training import runner, store, tracking

TINY = ["train", "ipd-v0", "--learner", "pg", "--seeds", "2", "--iterations", "40"]
TINY += ["--eval-period", "20", "--quiet"]


def train(out: Path, *extra: str) -> None:
    assert cli.main([*TINY, *extra, "--out", str(out)]) == 0


def csv_series(run_dir: Path, column: str = "eval/success") -> dict[int, list[tuple[int, str]]]:
    """{seed: [(iteration, value as written)]} of one metrics.csv column."""
    out: dict[int, list[tuple[int, str]]] = {}
    for row in store.read_metrics(run_dir):
        out.setdefault(int(row["seed"]), []).append((int(row["iteration"]), row[column]))
    return out


def learning_rows(run_dir: Path) -> list[dict[str, str]]:
    """metrics.csv as written, less the wall-clock columns (perf/…)."""
    with open(run_dir / store.METRICS, newline="") as f:
        return [
            {k: v for k, v in r.items() if not k.startswith("perf/")} for r in csv.DictReader(f)
        ]


def test_tensorboard_event_files_hold_every_seeds_series_and_the_config(tmp_path):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    out = tmp_path / "run"
    train(out, "--log", "tensorboard")
    expected = csv_series(out)
    for seed in (0, 1):
        events = EventAccumulator(str(out / "tensorboard" / f"seed_{seed}"))
        events.Reload()
        assert "train/success" in events.Tags()["scalars"]
        got = [(e.step, e.value) for e in events.Scalars("eval/success")]
        assert got == [(it, float(np.float32(v))) for it, v in expected[seed]]  # float32 events
    root = EventAccumulator(str(out / "tensorboard"), size_guidance={"tensors": 0})
    root.Reload()
    text = root.Tensors("config/text_summary")[0].tensor_proto.string_val[0].decode()
    assert json.loads(text) == store.read_json(out / store.CONFIG)


def wandb_records(path: Path) -> list:
    """The records of a W&B transaction log (`run-<id>.wandb`): a 7-byte header, then
    LevelDB log blocks of 32 KiB whose pieces join into `wandb_internal_pb2.Record`s."""
    from wandb.proto import wandb_internal_pb2

    data, block, pos = path.read_bytes(), 32768, 7
    assert data[:4] == b":W&B"
    records, pending = [], b""
    while pos + 7 <= len(data):
        if block - pos % block < 7:  # a block's tail too short for a header is padding
            pos += block - pos % block
            continue
        length, kind = int.from_bytes(data[pos + 4 : pos + 6], "little"), data[pos + 6]
        pending += data[pos + 7 : pos + 7 + length]
        pos += 7 + length
        if kind in (1, 4):  # FULL or LAST
            record = wandb_internal_pb2.Record()
            record.ParseFromString(pending)
            records.append(record)
            pending = b""
    return records


def test_wandb_offline_run_holds_the_history_and_the_config(tmp_path, monkeypatch):
    monkeypatch.setenv("WANDB_MODE", "offline")
    monkeypatch.setenv("WANDB_DIR", str(tmp_path / "wb"))
    monkeypatch.setenv("WANDB_SILENT", "true")
    out = tmp_path / "run"
    train(out, "--log", "wandb")
    run_id = store.read_json(out / tracking.IDS)["wandb"]
    (log,) = (tmp_path / "wb" / "wandb").glob(f"offline-run-*-{run_id}/run-{run_id}.wandb")
    history: dict[str, list[tuple[int, float]]] = {}
    config: dict[str, object] = {}
    for record in wandb_records(log):
        kind = record.WhichOneof("record_type")
        if kind == "history":
            for item in record.history.item:
                key = item.key or "/".join(item.nested_key)
                history.setdefault(key, []).append((record.history.step.num, item.value_json))
        elif kind in ("run", "config"):
            updates = record.run.config.update if kind == "run" else record.config.update
            config.update({u.key: json.loads(u.value_json) for u in updates})
    for seed, points in csv_series(out).items():
        got = [(step, float(value)) for step, value in history[f"seed_{seed}/eval/success"]]
        assert got == [(it, float(v)) for it, v in points]
    saved = store.read_json(out / store.CONFIG)
    assert config["run_config"] == saved["run_config"]
    assert config["identity"] == saved["identity"]


def test_mlflow_file_store_holds_every_seeds_series_and_the_config(tmp_path, monkeypatch):
    from mlflow.tracking import MlflowClient

    monkeypatch.delenv("MLFLOW_TRACKING_URI", raising=False)
    out = tmp_path / "run"
    train(out, "--log", "mlflow")
    client = MlflowClient(tracking_uri=(out / "mlruns").resolve().as_uri())
    run_id = store.read_json(out / tracking.IDS)["mlflow"]
    for seed, points in csv_series(out).items():
        history = client.get_metric_history(run_id, f"seed_{seed}/eval/success")
        got = sorted((m.step, m.value) for m in history)
        assert got == [(it, float(v)) for it, v in points]
    run = client.get_run(run_id)
    assert run.info.status == "FINISHED"
    assert run.data.params["run_config.learner"] == "pg"
    assert run.data.params["identity.env_id"] == "ipd-v0"
    saved = client.download_artifacts(run_id, store.CONFIG, str(tmp_path))
    assert store.read_json(Path(saved)) == store.read_json(out / store.CONFIG)


def test_a_resumed_run_continues_the_mlflow_run_and_sends_what_the_kill_lost(tmp_path, monkeypatch):
    """Killed after the first chunk's checkpoint, before MLflow got its rows: the rerun
    sends them first, then the rest, to the same run; each point once."""
    from mlflow.tracking import MlflowClient

    monkeypatch.delenv("MLFLOW_TRACKING_URI", raising=False)
    out = tmp_path / "run"
    argv = [*TINY, "--iterations", "200", "--chunk-iterations", "100", "--log", "mlflow"]
    send = tracking.MlflowTracker.log

    def killed_once(self, rows):
        monkeypatch.setattr(tracking.MlflowTracker, "log", send)
        raise KeyboardInterrupt

    monkeypatch.setattr(tracking.MlflowTracker, "log", killed_once)
    assert cli.main([*argv, "--out", str(out)]) == 130
    run_id = store.read_json(out / tracking.IDS)["mlflow"]
    client = MlflowClient(tracking_uri=(out / "mlruns").resolve().as_uri())
    assert client.get_run(run_id).info.status == "KILLED"
    assert cli.main([*argv, "--out", str(out)]) == 0
    assert store.read_json(out / tracking.IDS)["mlflow"] == run_id
    assert client.get_run(run_id).info.status == "FINISHED"
    history = client.get_metric_history(run_id, "seed_1/eval/success")
    assert sorted((m.step, m.value) for m in history) == [
        (it, float(v)) for it, v in csv_series(out)[1]
    ]
    assert [it for it, _ in csv_series(out)[1]] == list(range(20, 201, 20))


@pytest.mark.parametrize(
    ("log", "missing", "expected"),
    [
        (["nope"], None, "log: unknown backend 'nope'; allowed: tensorboard, wandb, mlflow"),
        (["tensorboard,nope"], None, "log: unknown backend 'nope'"),
        (
            ["mlflow", "tensorboard"],
            "tensorboardX",
            "log: tensorboard needs the tensorboardX client; pip install 'pimbot[tracking]'",
        ),
        (["wandb"], "wandb", "log: wandb needs the wandb client; pip install 'pimbot[tracking]'"),
    ],
)
def test_bad_or_uninstalled_backend_is_one_line_exit_2_nothing_written(
    tmp_path, capsys, monkeypatch, log, missing, expected
):
    if missing:
        monkeypatch.setitem(sys.modules, missing, None)  # importlib finds no such module
    out = tmp_path / "run"
    argv = [*TINY, *(a for value in log for a in ("--log", value)), "--out", str(out)]
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("pimbot: error: ") and expected in err
    assert len(err.strip().splitlines()) == 1, err
    assert not out.exists()


def test_suite_log_value_is_checked_before_anything_is_written(tmp_path, capsys):
    out = tmp_path / "suite"
    grid = Path(__file__).resolve().parents[1] / "docs" / "examples" / "grid.toml"
    code = cli.main(["sweep", str(grid), "--out", str(out), "--log", "nope"])
    assert code == 2
    assert "log: unknown backend 'nope'" in capsys.readouterr().err
    assert not out.exists()


def test_parse_accepts_repeats_and_commas_once_each():
    assert tracking.parse(["tensorboard,wandb", "mlflow", "TensorBoard"]) == tracking.BACKENDS
    assert tracking.parse(None) == ()


def test_metrics_are_identical_with_and_without_tracking_and_progress(
    tmp_path, monkeypatch, capsys
):
    """With progress on, a chunk runs as several compiled calls (1000 iterations with an
    evaluation every 50: one chunk of 20 periods, two calls of 10); tracking only reads
    the rows. metrics.csv is the same file either way, less its wall-clock columns."""
    monkeypatch.setenv("WANDB_MODE", "offline")
    monkeypatch.setenv("WANDB_DIR", str(tmp_path / "wb"))
    monkeypatch.setenv("WANDB_SILENT", "true")
    monkeypatch.delenv("MLFLOW_TRACKING_URI", raising=False)
    assert runner.periods_per_call(20, 50, progress=True) == 10
    assert runner.periods_per_call(20, 50, progress=False) == 20
    longer = ["--iterations", "1000", "--eval-period", "50"]
    train(tmp_path / "plain", *longer)
    capsys.readouterr()
    argv = [*TINY[:-1], *longer, "--log", "tensorboard,wandb,mlflow", "--out"]
    assert cli.main([*argv, str(tmp_path / "both")]) == 0  # progress on, every backend
    err = capsys.readouterr().err
    assert "compiling pg ipd-v0 ×2 …" in err and "compiled pg ipd-v0 ×2 in" in err
    train(tmp_path / "chunked", *longer, "--chunk-iterations", "500")  # the same program
    reference = learning_rows(tmp_path / "plain")
    assert len(reference) == 2 * 20
    assert learning_rows(tmp_path / "both") == reference  # the same file, row for row

    def point(row):
        return int(row["iteration"]), int(row["seed"])

    chunked = sorted(learning_rows(tmp_path / "chunked"), key=point)  # rows come chunk by chunk
    assert chunked == sorted(reference, key=point)


def test_a_sweep_job_logs_its_own_run(tmp_path):
    grid = tmp_path / "grid.toml"
    grid.write_text(
        'name = "tiny"\nseeds = 2\niterations = 40\neval_period = 20\n'
        '[[envs]]\nid = "ipd-v0"\nlabel = "ipd"\n[[learners]]\nname = "pg"\n'
        '[[attacks]]\nname = "none"\n'
    )
    out = tmp_path / "suite"
    argv = ["sweep", str(grid), "--out", str(out), "--workers", "1", "--quiet"]
    assert cli.main([*argv, "--log", "tensorboard"]) == 0
    (run_dir,) = [p.parent for p in out.glob("*/*/" + store.SUMMARY)]
    assert sorted(p.name for p in (run_dir / "tensorboard").iterdir() if p.is_dir()) == [
        "seed_0",
        "seed_1",
    ]
    assert list((run_dir / "tensorboard" / "seed_1").glob("events.out.tfevents.*"))
