"""`pimbot reproduce` engine and `pimbot report`: a tiny suite run for real.

One uninterrupted local sweep is the reference. Against it: the same suite
killed with SIGKILL mid-run and rerun (complete, no duplicated or missing
rows, identical metrics), the same suite on a real local Ray instance
(identical metrics), and the report rendered in headless Chromium (every
figure loads).
"""

from __future__ import annotations

import csv
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import psutil
import pytest

from pimbot.suites import sweep
from pimbot.training import store

# The tiny suite, as code a subprocess can run too: three training jobs (two
# programs share a shape), a one-second paired profile and a physics evaluation
# that waits for the run it reads.
SUITE_CODE = """
from pimbot.training.config import RunConfig
from pimbot.suites.presets import Job, RobotEval
from pimbot.profiling.decision_loop import ProfileConfig

TINY = dict(learner="lio", iterations=1000, eval_period=100, eval_episodes=2, seeds=2)
JOBS = [
    Job("attacks/er21_clean", "train", RunConfig(env_id="escape_room-v0", **TINY), ("C1",)),
    Job(
        "attacks/er21_bypass",
        "train",
        RunConfig(env_id="escape_room-v0", attack="bypass", **TINY),
        ("C3",),
    ),
    Job("attacks/ipd_clean", "train", RunConfig(env_id="ipd-v0", **TINY), ("C1",)),
    Job(
        "profile/er21_paired",
        "profile",
        ProfileConfig(duration_s=1.0, hidden=(32,), cadences=(10,), rounds=2),
        ("C8",),
    ),
    Job(
        "robot/er21_clean",
        "robot_eval",
        RobotEval("attacks/er21_clean", episodes=1),
        after=("attacks/er21_clean",),
    ),
]
"""
OPTIONS = dict(workers=2, devices_per_job=1, chunk_iterations=200, progress=False)
RUN_CODE = SUITE_CODE + (
    "import sys\nfrom pimbot.suites import sweep\n"
    f"sweep.run(JOBS, sys.argv[1], 'tiny', sweep.SweepOptions(**{OPTIONS!r}))\n"
)
# The same suite with training jobs long enough (100 000 iterations) that none can finish
# between its first checkpoint and an interrupt, however fast the machine.
LONG_RUN_CODE = RUN_CODE.replace("iterations=1000,", "iterations=100_000,")
assert LONG_RUN_CODE != RUN_CODE
namespace: dict = {}
exec(SUITE_CODE, namespace)
JOBS = namespace["JOBS"]
TRAIN_JOBS = [j for j in JOBS if j.kind == "train"]


def learning_rows(run_dir: Path) -> list[dict]:
    with open(run_dir / "metrics.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    return [{k: v for k, v in r.items() if not k.startswith("perf/")} for r in rows]


@pytest.fixture(scope="module")
def reference(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("reference")
    result = sweep.run(JOBS, out, "tiny", sweep.SweepOptions(**OPTIONS))
    assert not result.failed, result.index
    return out


def test_reference_sweep_writes_every_run_and_the_index(reference):
    index = sweep.read_index(reference)
    assert [j["status"] for j in index["jobs"]] == ["finished"] * len(JOBS)
    for job in TRAIN_JOBS:
        rows = learning_rows(reference / job.name)
        keys = {(r["seed"], r["iteration"]) for r in rows}
        assert len(rows) == len(keys) == 2 * 10
    assert (reference / "profile/er21_paired/summary.json").exists()
    robot = store.read_json(reference / "robot/er21_clean/summary.json")
    assert robot["spec"]["run"] == "attacks/er21_clean" and len(robot["seeds"]) == 2
    # er21 clean and bypass differ only in the strategy attack: one task, one program
    programs = index["programs"]
    assert programs["tasks"] == 4 and programs["training_programs"] == 2, programs
    assert programs["chunk_programs"] == 2 and programs["xla_compiles"] > 2, programs
    again = sweep.run(JOBS, reference, "tiny", sweep.SweepOptions(**OPTIONS))
    assert again.wall_s < 5, "finished jobs must be skipped"


def test_groups_put_jobs_on_one_program_together_and_keep_dependencies_apart():
    import dataclasses

    from pimbot.suites.jobs import Job, JobOptions
    from pimbot.training.config import RunConfig

    er21 = dict(env_id="escape_room-v0", iterations=1000, eval_period=100, seeds=2)
    jobs = [
        Job("a/clean", "train", RunConfig(**er21)),
        Job("a/ipd", "train", RunConfig(env_id="ipd-v0", iterations=1000, seeds=2)),
        Job("a/fake", "train", RunConfig(**er21, attack="fake_incentive")),
        Job(
            "a/fake_10",
            "train",
            RunConfig(**er21, attack="fake_incentive", attack_params=(("amount", 10.0),)),
        ),
        Job("a/admo", "train", RunConfig(**er21, attack="admo")),
        Job("a/more_seeds", "train", RunConfig(**{**er21, "seeds": 3})),
        Job("a/after_clean", "train", RunConfig(**er21, attack="bypass"), after=("a/clean",)),
    ]
    jobs.append(dataclasses.replace(jobs[0], name="robot/x", kind="robot_eval", spec=None))
    tasks = sweep.groups(jobs, JobOptions(chunk_iterations=200), devices=1)
    names = [[j.name for j in task] for task in tasks]
    assert names == [
        ["a/clean", "a/fake", "a/fake_10"],
        ["a/after_clean"],
        ["a/ipd"],
        ["a/admo"],
        ["a/more_seeds"],
        ["robot/x"],
    ]
    # a property of the job kind: the robot_eval task compiles no training program
    assert sweep.planned_programs(tasks)["training_programs"] == 5


def test_sigkill_mid_sweep_then_rerun_completes_with_identical_results(reference, tmp_path):
    out = tmp_path / "killed"
    command = [sys.executable, "-c", RUN_CODE, str(out)]
    proc = subprocess.Popen(
        command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True
    )
    deadline = time.time() + 180
    checkpoints = []
    while time.time() < deadline and proc.poll() is None:
        checkpoints = list(out.glob("attacks/*/checkpoint/meta.json"))
        if checkpoints:
            break
        time.sleep(0.05)
    assert checkpoints, "no job wrote a checkpoint"
    workers = psutil.Process(proc.pid).children(recursive=True)
    os.kill(proc.pid, signal.SIGKILL)  # the driver only: its workers must notice and exit
    proc.wait()
    unfinished = [j for j in TRAIN_JOBS if not (out / j.name / "summary.json").exists()]
    assert unfinished, "the sweep finished before it could be killed"
    # a worker notices its driver is gone at its next poll; a busy machine delays it
    _, alive = psutil.wait_procs(workers, timeout=30)
    assert not alive, "workers outlived the killed sweep"

    subprocess.run(command, check=True, capture_output=True, timeout=300)
    index = sweep.read_index(out)
    assert [j["status"] for j in index["jobs"]] == ["finished"] * len(JOBS)
    for job in TRAIN_JOBS:
        assert learning_rows(out / job.name) == learning_rows(reference / job.name), job.name


def _sigint_as_in_a_foreground_shell() -> None:
    """A driver started from a foreground shell has SIGINT's default disposition (Python
    raises KeyboardInterrupt); one started in the background of a non-interactive shell
    (`cmd &`, `nohup`, a CI runner's background job) inherits it *ignored*, and honours
    that. The test must not depend on how pytest itself was launched: a backgrounded
    pytest made the driver ignore the SIGINT and this test time out."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def test_interrupting_the_driver_alone_ends_its_running_jobs_and_workers(tmp_path):
    """SIGINT to the driver only (as a job manager sends it; a terminal's Ctrl-C reaches
    the whole process group): the sweep must stop its running jobs, not wait for them to
    finish, and leave no worker behind (one left training holds its job's lock)."""
    out = tmp_path / "interrupted"
    command = [sys.executable, "-c", LONG_RUN_CODE, str(out)]
    proc = subprocess.Popen(
        command,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
        preexec_fn=_sigint_as_in_a_foreground_shell,
    )
    deadline = time.time() + 180
    checkpoints = []
    while time.time() < deadline and proc.poll() is None:
        checkpoints = list(out.glob("attacks/*/checkpoint/meta.json"))
        if checkpoints:
            break
        time.sleep(0.05)
    assert checkpoints, "no job wrote a checkpoint"
    workers = psutil.Process(proc.pid).children(recursive=True)
    os.kill(proc.pid, signal.SIGINT)
    proc.wait(timeout=60)
    unfinished = [j for j in TRAIN_JOBS if not (out / j.name / "summary.json").exists()]
    assert unfinished, "the interrupted sweep let its running jobs finish"
    _, alive = psutil.wait_procs(workers, timeout=10)
    assert not alive, "workers outlived the interrupted sweep"


def test_progress_counts_a_running_groups_finished_jobs_and_lists_only_running_ones(tmp_path):
    """A group reports its jobs when its last one ends: the headline counts a job whose
    summary is written as done meanwhile, and the running list holds only the job a
    worker holds the lock of: not a finished one, nor a queued one that an earlier
    sitting started (its directory is there)."""
    import fcntl

    finished, training, queued = TRAIN_JOBS
    (tmp_path / finished.name).mkdir(parents=True)
    (tmp_path / finished.name / store.SUMMARY).write_text("{}")
    for job in (training, queued):
        (tmp_path / job.name).mkdir(parents=True)
    store.lock_path(tmp_path / queued.name).touch()  # left by the earlier sitting's worker
    display = sweep.SweepDisplay(TRAIN_JOBS, tmp_path, {}, enabled=False)
    display.start([job.name for job in TRAIN_JOBS])
    assert display.headline().startswith(f"jobs 1/{len(TRAIN_JOBS)} done")
    with open(store.lock_path(tmp_path / training.name), "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # what the worker running it holds
        assert [name for name, _ in display.running()] == [training.name]
    assert display.running() == []


def test_ray_backend_gives_the_same_metrics_as_local(reference, tmp_path):
    ray = pytest.importorskip("ray", reason="the ray extra is part of the test install")
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        options = sweep.SweepOptions(**{**OPTIONS, "backend": "ray"})
        result = sweep.run(TRAIN_JOBS, tmp_path / "ray", "tiny", options)
    finally:
        ray.shutdown()
    assert not result.failed, result.index
    for job in TRAIN_JOBS:
        assert learning_rows(tmp_path / "ray" / job.name) == learning_rows(reference / job.name)


def test_conflicting_directory_is_refused_before_anything_runs(reference, tmp_path):
    out = tmp_path / "conflict"
    shutil.copytree(reference / "attacks/er21_clean", out / "attacks/er21_clean")
    bigger = [j for j in JOBS if j.name == "attacks/er21_clean"]
    import dataclasses

    bigger = [dataclasses.replace(bigger[0], spec=dataclasses.replace(bigger[0].spec, seeds=3))]
    with pytest.raises(sweep.SweepError, match="attacks/er21_clean.*seeds"):
        sweep.run(bigger, out, "tiny", sweep.SweepOptions(**OPTIONS))
    assert not (out / sweep.INDEX).exists()


def _chromium() -> str | None:
    return shutil.which("chromium") or shutil.which("chromium-browser")


def test_report_html_renders_every_figure_in_headless_chromium(reference, tmp_path):
    from pimbot.analysis import report

    out = report.write_report(reference, tmp_path / "report")
    markdown = (out / report.MARKDOWN).read_text()
    figures = sorted((out / report.FIGURES).glob("*.png"))
    assert len(figures) >= 6  # fig1, fig1b, fig2, fig3, fig8, fig9 from this suite
    for figure in figures:
        assert f"{report.FIGURES}/{figure.name}" in markdown
    assert "| C8 |" in markdown and "| C1a |" in markdown and "| C1b |" in markdown

    executable = _chromium()
    if executable is None:
        if os.environ.get("PIMBOT_REQUIRE_CHROMIUM"):
            pytest.fail("chromium is required here (PIMBOT_REQUIRE_CHROMIUM) but not installed")
        pytest.skip("chromium is not installed (.ci/run installs it)")
    playwright = pytest.importorskip("playwright.sync_api")
    with playwright.sync_playwright() as p:
        browser = p.chromium.launch(
            executable_path=executable,
            args=["--no-sandbox", "--disable-gpu", "--disable-background-networking"],
        )
        page = browser.new_page(viewport={"width": 1200, "height": 900})
        page.goto((out / report.HTML).resolve().as_uri())
        page.wait_for_load_state("load")
        loaded = page.evaluate(
            "Array.from(document.images).map(i => i.complete && i.naturalWidth > 100)"
        )
        page.screenshot(path=str(out / "screenshot.png"), full_page=True)
        browser.close()
    assert loaded == [True] * len(figures)


@pytest.mark.parametrize(
    "argv, expected",
    [
        (["reproduce", "--backend", "slurm", "--out", "x"], "backend: unknown value 'slurm'"),
        (["reproduce", "--only", "nothing/*", "--out", "x"], "only: no job matches nothing/*"),
        (["reproduce", "--ray-address", "auto", "--out", "x"], "ray_address: given without"),
        (["reproduce", "--workers", "-1", "--out", "x"], "workers: must be an integer ≥ 0"),
        (["report", "missing"], "suite_dir: missing is not a directory"),
    ],
)
def test_reproduce_and_report_bad_input_is_one_line_exit_2(
    tmp_path, monkeypatch, capsys, argv, expected
):
    from pimbot import cli

    monkeypatch.chdir(tmp_path)
    assert cli.main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and expected in err, err
    assert not any(tmp_path.iterdir()), "nothing may be written"


def _settings(jobs: dict, group: str) -> set:
    """(env, its parameters, learner) of each training job of `group` (kind otherwise)."""
    return {
        (j.spec.env_id, j.spec.env_params, j.spec.learner) if j.kind == "train" else j.kind
        for n, j in jobs.items()
        if n.startswith(group)
    }


def _claims(jobs: dict, group: str) -> set:
    return {c for n, j in jobs.items() if n.startswith(group) for c in j.claims}


def test_quick_suite_keeps_every_setting_of_the_full_suite():
    from pimbot.suites import presets

    full = {j.name: j for j in presets.suite(quick=False)}
    quick = {j.name: j for j in presets.suite(quick=True)}
    assert set(quick) <= set(full)
    for group in ("attacks", "stag_hunt", "reciprocators", "profile"):  # every setting
        # Every environment setting and claim of the group runs on the quick budget; a
        # condition of a setting may be full-only (admo_code's second mode, the code's
        # slow one-episode Reciprocator under ADMO, 2048-game IPD).
        assert _settings(quick, group) == _settings(full, group), group
        assert _claims(quick, group) == _claims(full, group), group
        in_quick, in_full = (sum(n.startswith(group) for n in jobs) for jobs in (quick, full))
        assert in_quick >= 0.7 * in_full, group
    for group in ("defenses", "robot"):  # a representative slice, never nothing
        assert 0 < sum(n.startswith(group) for n in quick) < sum(n.startswith(group) for n in full)
    for name, q in quick.items():
        f = full[name]
        if f.kind != "train":
            continue
        noisy = f.group == "attacks" and name.split("/", 1)[1] in presets.NOISE_LIMITED
        assert q.spec.seeds < f.spec.seeds == (presets.NOISE_LIMITED_SEEDS if noisy else 10)
        assert q.spec.iterations < f.spec.iterations
        assert q.spec.iterations // (q.spec.eval_period or 1000) >= 10
        same = ("env_id", "env_params", "learner", "hparams", "attack", "attack_params", "defenses")
        assert all(getattr(f.spec, k) == getattr(q.spec, k) for k in same)


def test_nl_shares_the_reciprocators_programs_but_not_its_strategies_program():
    """`nl` is the Reciprocator's code at weight 0 (its config's numbers traced): its clean
    Escape Room runs share the Reciprocator's program; its clean IPD run stays out of the
    Reciprocator's clean + self-centered `Strategies` program, where the act hook would
    play its games through the rollout instead of the tabular sampler (its results
    would change), and runs on its own."""
    from pimbot.suites import presets
    from pimbot.suites.jobs import JobOptions
    from pimbot.suites.sweep import groups

    jobs = [j for j in presets.suite(quick=True) if j.kind == "train"]
    task_of = {
        j.name: tuple(sorted(x.name for x in task))
        for task in groups(jobs, JobOptions(), 1)
        for j in task
    }
    room = task_of["reciprocators/rec_er21_clean"]
    assert "reciprocators/nl_er21_clean" in room
    assert "reciprocators/rec_er21_petty_clean" in room  # the code's credit-only balance too
    assert task_of["reciprocators/nl_ipd2_clean"] == ("reciprocators/nl_ipd2_clean",)
    assert task_of["reciprocators/rec_ipd2_clean"] == (
        "reciprocators/rec_ipd2_clean",
        "reciprocators/rec_ipd2_self_centered",
    )
