"""The original code's runs made here (benchmarks/original/import_runs.py), packaged beside
the shipped logs (analysis.original_code.runs_made_here)."""

from __future__ import annotations

import csv
import gzip
import hashlib
import importlib.util
import json
import shutil
import sys
from pathlib import Path

import pytest

from pimbot.analysis import original_code, runs
from pimbot.training import store

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks" / "original"
SHIPPED_POLICY_DET = original_code.ROOT / "er_25k" / "er2_1_policy_det"


def import_runs_module():
    sys.path.insert(0, str(BENCHMARKS))
    try:
        spec = importlib.util.spec_from_file_location("import_runs", BENCHMARKS / "import_runs.py")
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
    finally:
        sys.path.remove(str(BENCHMARKS))
    return module


def write_csv(path: Path, rows: list[dict]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]), lineterminator="\n")
        writer.writeheader()
        writer.writerows(rows)


def fake_lio_run(runs_dir: Path, num: int, horizon: int) -> None:
    """A run folder as run_original_lio_reverse.py leaves it, with a 2-row log."""
    config = json.loads(json.dumps(original_code.original_info(SHIPPED_POLICY_DET)["config"]))
    config["alg"]["n_episodes"] = horizon
    config["main"] |= {"exp_name": f"er{num}", "seed": 12340 + num}
    folder = runs_dir / "lio_reverse" / f"er{num}"
    log_dir = folder / "results" / f"er{num}" / config["main"]["dir_name"]
    suffixes = ["reward_total", "n_lever", "n_door", "received", "given"]
    suffixes += ["r-lever", "r-start", "r-door", "win_rate"]
    header = ["episode", "step_train", "step"]
    header += [f"A{i}_{s}" for i in (1, 2) for s in suffixes] + ["steps_per_eps"]
    rows = []
    for k, episode in enumerate(range(100, horizon + 1, 100)):
        a1 = [8.0 + num, 0, 1, 0.5, 0.5, 0, 0.5, 0, 10.0 * (k + num % 3)]
        a2 = [-1.0, 1, 0, 0.5, 0.5, 0.5, 0, 0, 0]
        values = [episode, episode, 7 * episode] + a1 + a2 + [2.0]
        rows.append(",".join(f"{v:.3e}" if isinstance(v, float) else str(v) for v in values))
    log_dir.mkdir(parents=True)
    (log_dir / "log.csv").write_text(",".join(header) + "\n" + "\n".join(rows) + "\n")
    (log_dir / "config.json").write_text(json.dumps(config))
    result = {"num": num, "wall_s": 30.0, "cpu_s": 10.0, "ms_per_iteration": 150.0}
    result |= {"cpu_ms_per_iteration": 50.0, "log": str(log_dir / "log.csv")}
    (folder / "run.json").write_text(json.dumps(result))


def fake_reciprocator_runs(runs_dir: Path) -> None:
    for seed in (0, 1):
        folder = runs_dir / "rec_ipd" / f"seed{seed}"
        rows = []
        for update in range(1, 101):
            both = min(1.0, update / 100 + 0.1 * seed)
            rows.append(
                {
                    "update": update,
                    "mutual_cooperation": both,
                    "p_cooperate_0": both,
                    "p_cooperate_1": both,
                    "reward_0": -1.0 * both - 2.0 * (1 - both),
                    "reward_1": -1.0 * both - 2.0 * (1 - both),
                    "wall_s": 1.0,
                    "cpu_s": 1.0,
                }
            )
        write_csv(folder / "updates.csv", rows)
        (folder / "out_100.json").write_text("[]")
        result = {"seed": seed, "updates": 100}
        result["final_mutual_cooperation"] = rows[-1]["mutual_cooperation"]
        result |= {"wall_s": 200.0, "cpu_s": 130.0, "batch_size": 2048, "max_steps": 32}
        result |= {"torch": "2.13.0+cpu", "torch_threads": 1, "python": "3.11.7"}
        (folder / "run.json").write_text(json.dumps(result))

        folder = runs_dir / "rec_er" / f"seed{seed}"
        rows = [
            {
                "episode": episode,
                "success": 0.5 * seed,
                "success_argmax": 0.0,
                "steps": 3.0,
                "return_env_0": 9.0 * seed,
                "return_env_1": -1.0,
                "steps_argmax": 5,
                "return_env_argmax_0": -1,
                "return_env_argmax_1": -1,
                "train_success": 0.9,
                "wall_s": episode / 10,
                "cpu_s": episode / 20,
            }
            for episode in range(100, 5001, 100)
        ]
        write_csv(folder / "eval.csv", rows)
        result = {"seed": seed, "episodes": 5000, "training_episodes_escaped": 4000}
        result |= {"final_success": 0.5 * seed, "eval_period": 100, "eval_episodes": 10}
        result |= {"stubbed_modules": ["tensorflow"], "wall_s": 900.0, "cpu_s": 800.0}
        result |= {"ms_per_episode": 180.0, "torch": "2.13.0+cpu", "torch_threads": 1}
        result |= {"python": "3.11.7", "adam_moments_nan_from_episode": 1 + seed}
        result |= {"final_policy_off_uniform": 0.0}
        (folder / "run.json").write_text(json.dumps(result))


@pytest.fixture
def imported(tmp_path, monkeypatch):
    runs_dir, out = tmp_path / "runs", tmp_path / "original_code"
    out.mkdir()
    shutil.copy(original_code.ROOT / original_code.MANIFEST, out / original_code.MANIFEST)
    fake_lio_run(runs_dir, 6, 300)
    fake_lio_run(runs_dir, 7, 300)
    fake_lio_run(runs_dir, 8, 400)  # stopped short of its horizon below
    log = next((runs_dir / "lio_reverse" / "er8").glob("results/*/*/log.csv"))
    log.write_text("\n".join(log.read_text().splitlines()[:3]) + "\n")
    fake_reciprocator_runs(runs_dir)
    module = import_runs_module()
    argv = ["import_runs.py", "--runs", str(runs_dir), "--out", str(out)]
    monkeypatch.setattr(sys, "argv", argv + ["--greedy-rec-tree", str(tmp_path / "none")])
    module.main()
    return out


def test_made_here_runs_are_original_code_kept_apart_from_the_shipped_logs(imported):
    made = original_code.runs_made_here(root=imported)
    names = [p.relative_to(imported).as_posix() for p in made]
    assert names == [
        "made_here_er_25k/er2_1_a2d",
        "made_here_reciprocator/er2_1_run_er",
        "made_here_reciprocator/ipd2",
    ]
    assert original_code.shipped_runs(imported) == []  # only the manifest was copied
    assert original_code.runs_made_here("C4", imported) == made[:1]
    assert original_code.runs_made_here("C7", imported) == made[1:]
    assert made[0] in original_code.runs_for_claim("C4", imported)
    table = runs.load_table(imported)
    assert sorted(r.path for r in table.original) == made
    for run_dir in made:
        info = original_code.original_info(run_dir)
        assert original_code.made_here(run_dir) and info["made_by"].startswith(
            "pimbot benchmarks/original, "
        )
        assert info["command"].startswith("taskset -c 1 ")
        assert info["fixes_and_shims"] and info["run_time"]["per_seed_wall_s"]
        seeds = {int(r["seed"]) for r in store.read_metrics(run_dir)}
        assert seeds == set(range(len(info["seeds"])))
        for seed in info["seeds"]:
            kept = gzip.decompress((run_dir / seed["paths"][0]).read_bytes())
            assert hashlib.sha256(kept).hexdigest() == seed["sha256"]
    manifest = original_code.manifest(imported)
    assert [e["run"] for e in manifest[original_code.MADE_HERE]] == names
    assert manifest["log_files"] == 498  # the shipped part is untouched


def test_lio_reverse_run_matches_the_shipped_policy_det_settings(imported):
    run_dir = imported / "made_here_er_25k" / "er2_1_a2d"
    info = original_code.original_info(run_dir)
    assert [s["config_seed"] for s in info["seeds"]] == [12346, 12347]
    assert info["left_out"] == [{"run": "lio_reverse/er8", "ends_at": 200, "of": 400}]
    assert info["claim_roles"] == {"C4": "attacked"} and not info["attack_inferred"]
    ours = next(r for r in runs.load_table(imported).original if r.path == run_dir)
    shipped = runs.load_table(original_code.ROOT).original
    policy_det = next(r for r in shipped if r.path == SHIPPED_POLICY_DET)
    assert runs.same_settings(ours, policy_det)  # pooled with it by RunTable.original_for
    rows = store.read_metrics(run_dir)
    assert [float(r["eval/success"]) for r in rows if r["seed"] == "0"] == [0.0, 0.1, 0.2]


def test_reciprocator_runs_in_pimbot_columns(imported):
    ipd = imported / "made_here_reciprocator" / "ipd2"
    rows = store.read_metrics(ipd)
    assert [int(r["iteration"]) for r in rows if r["seed"] == "0"] == list(range(5, 101, 5))
    row = rows[0]  # update 5 of seed 0: 5 % mutual cooperation
    assert float(row["eval/success"]) == pytest.approx(0.05)
    assert float(row["eval/return_env/agent_0"]) == pytest.approx(32 * (-0.05 - 1.9))
    summary = store.read_json(ipd / store.SUMMARY)
    # the mean of the last 10 evaluations (updates 55 … 100), as pimbot's summary
    assert summary["final"]["eval/success"]["per_seed"][0] == pytest.approx(0.775)
    config = store.read_json(ipd / store.CONFIG)
    assert config["identity"]["learner_config"]["policy_head"] == "sigmoid"
    assert config["original"]["repository"] == "johnlyzhou/reciprocator"
    er = imported / "made_here_reciprocator" / "er2_1_run_er"
    summary = store.read_json(er / store.SUMMARY)
    assert summary["final"]["eval/success"]["per_seed"] == [0.0, 0.5]
    assert summary["iterations"] == 5000
    assert "train/success" in store.read_metrics(er)[0]
    finding = store.read_json(er / store.CONFIG)["original"]["finding"]
    assert finding.startswith("its agents stop learning at episode 1–2")
    assert "uniformly at random (largest |π(a|s₀) − 1/|A|| 0)" in finding


PACKAGED = original_code.runs_made_here()


@pytest.mark.skipif(not PACKAGED, reason="no runs made here are packaged")
def test_packaged_runs_made_here():
    for run_dir in PACKAGED:
        info = original_code.original_info(run_dir)
        config = store.read_json(run_dir / store.CONFIG)
        assert config["source"] == original_code.SOURCE and info["made_here"]
        rows = store.read_metrics(run_dir)
        assert {int(r["seed"]) for r in rows} == set(range(len(info["seeds"])))
        assert max(int(r["iteration"]) for r in rows) == config["identity"]["iterations"]
        for seed in info["seeds"]:
            kept = gzip.decompress((run_dir / seed["paths"][0]).read_bytes())
            assert hashlib.sha256(kept).hexdigest() == seed["sha256"]
        assert len(info["run_time"]["per_seed_wall_s"]) == len(info["seeds"])
    lio = original_code.ROOT / "made_here_er_25k" / "er2_1_a2d"
    if lio in PACKAGED:
        assert len(original_code.original_info(lio)["seeds"]) >= 10
        assert store.read_json(lio / store.CONFIG)["identity"]["iterations"] == 25000
