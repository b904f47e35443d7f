"""The training runner: seed independence, run directories, resume after a hard kill."""

import csv
import dataclasses
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from pimbot.attacks import strategy_union
from pimbot.training import programs, runner, store
from pimbot.training.config import RunConfig

SMALL = dict(
    env_id="escape_room-v0", learner="lio", iterations=200, eval_period=100, eval_episodes=4
)


def _rows_by_seed(run_dir: Path) -> dict[int, list[dict]]:
    rows = store.read_metrics(run_dir)
    out: dict[int, list[dict]] = {}
    for row in rows:
        out.setdefault(int(row["seed"]), []).append(row)
    return out


def _learning_columns(row: dict) -> list[str]:
    return [c for c in row if not c.startswith("perf/")]


def test_seed_gives_the_same_result_alone_or_in_a_batch_of_10(tmp_path):
    """Determinism holds bitwise for a given seed set and device count (resume, rerun: the
    SIGKILL test below). Across batch sizes it holds to rounding only: XLA's CPU kernels
    for a [S, ...] batch depend on S, so float32 sums are ordered differently and differ
    in the last bits (ER(2,1), 1000 iterations: ≤ 6e-8 absolute in the Adam moments,
    ≤ 1.8e-6 relative in the incentive columns); success and every count agree exactly.
    Long runs may drift further (chaotic), so compare seeds across batch sizes
    statistically, not bitwise."""
    alone = runner.train(RunConfig(**SMALL, seeds=1, first_seed=3), tmp_path / "a", progress=False)
    batch = runner.train(RunConfig(**SMALL, seeds=10, first_seed=0), tmp_path / "b", progress=False)
    rows_alone = _rows_by_seed(alone.run_dir)[3]
    rows_batch = _rows_by_seed(batch.run_dir)[3]
    assert len(rows_alone) == len(rows_batch) == 2
    for a, b in zip(rows_alone, rows_batch, strict=True):
        assert a.keys() == b.keys()
        for column in _learning_columns(a):
            if "success" in column or column in ("iteration", "seed"):
                assert a[column] == b[column], column
            np.testing.assert_allclose(
                float(a[column]), float(b[column]), rtol=1e-5, atol=1e-6, err_msg=column
            )
    # Different seeds do differ.
    by_seed = _rows_by_seed(batch.run_dir)
    assert by_seed[0][0]["eval/given/agent_0"] != by_seed[1][0]["eval/given/agent_0"]


def test_run_directory_layout_and_finished_rerun(tmp_path):
    run = RunConfig(**SMALL, seeds=2)
    first = runner.train(run, tmp_path / "r", progress=False)
    assert not first.already_finished
    for name in ("config.json", "metrics.csv", "summary.json", "checkpoint/state.msgpack"):
        assert (tmp_path / "r" / name).exists(), name
    config = store.read_json(tmp_path / "r" / "config.json")
    assert config["env"]["id"] == "escape_room-v0"
    assert config["jax_backend"] in ("cpu", "gpu", "tpu")
    assert config["identity"]["learner_config"]["lr_policy"] == 1e-4
    rows = store.read_metrics(tmp_path / "r")
    assert len(rows) == 2 * 2
    for column in (
        "eval/success",
        "eval/return_ratio",
        "eval/return_env/agent_1",
        "eval/given/agent_0",
        "eval/steps",
        "perf/iters_per_s",
    ):
        assert column in rows[0], column
    # A final value is its mean and per-seed values; no interval (a "95 % CI" of two
    # seeds would mean nothing: every printed interval comes from pimbot.statistics).
    final = store.read_json(tmp_path / "r" / "summary.json")["final"]["eval/success"]
    assert set(final) == {"mean", "per_seed"} and len(final["per_seed"]) == 2
    again = runner.train(run, tmp_path / "r", progress=False)
    assert again.already_finished
    assert len(store.read_metrics(tmp_path / "r")) == 4
    with pytest.raises(runner.RunDirConflict, match="seeds"):
        runner.train(RunConfig(**SMALL, seeds=3), tmp_path / "r", progress=False)


def test_a_run_from_before_a_learner_field_existed_resumes_at_its_default(tmp_path):
    """A config.json whose identity lacks a learner hyperparameter a later pimbot added
    (here voi_minibatch_rows) is the same run while the run keeps that field at its
    default (the behaviour from before it existed), and a different run once it is set."""
    from pimbot.training.config import resolve

    base = RunConfig(env_id="ipd-v0", learner="reciprocator", seeds=1, iterations=10)
    resolved = resolve(base)
    metadata = runner.run_metadata(resolved)
    del metadata["identity"]["learner_config"]["voi_minibatch_rows"]
    (tmp_path / "r").mkdir()
    store.write_json(tmp_path / "r" / "config.json", metadata)
    runner.check_run_dir(tmp_path / "r", resolved)  # the same run
    other = dataclasses.replace(base, hparams=(("voi_minibatch_rows", "distinct_weighted"),))
    with pytest.raises(runner.RunDirConflict, match="learner_config"):
        runner.check_run_dir(tmp_path / "r", resolve(other))
    changed = dataclasses.replace(base, hparams=(("lr", 1e-3),))  # a field both have
    with pytest.raises(runner.RunDirConflict, match="learner_config"):
        runner.check_run_dir(tmp_path / "r", resolve(changed))


def _cli(out: Path) -> list[str]:
    args = "train escape_room-v0 --seeds 2 --iterations 6000 --eval-period 100"
    args += " --eval-episodes 2 --chunk-iterations 500 --quiet --out"
    return [sys.executable, "-m", "pimbot.cli", *args.split(), str(out)]


def _read_csv(path: Path) -> list[dict]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def test_sigkill_then_rerun_resumes_with_identical_results(tmp_path):
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    killed = tmp_path / "killed"
    proc = subprocess.Popen(
        _cli(killed),
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )
    meta = killed / "checkpoint" / "meta.json"
    deadline = time.time() + 120
    while not meta.exists() and time.time() < deadline and proc.poll() is None:
        time.sleep(0.02)
    assert meta.exists(), "no checkpoint was written"
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    assert not (killed / "summary.json").exists(), "the run finished before it could be killed"
    done_at_kill = store.read_json(meta)["iteration"]
    assert 0 < done_at_kill < 6000

    subprocess.run(_cli(killed), env=env, check=True, capture_output=True)
    clean = tmp_path / "clean"
    subprocess.run(_cli(clean), env=env, check=True, capture_output=True)

    resumed_rows = _read_csv(killed / "metrics.csv")
    clean_rows = _read_csv(clean / "metrics.csv")
    keys = [(r["iteration"], r["seed"]) for r in resumed_rows]
    assert len(keys) == len(set(keys)) == 2 * 60, "duplicated or missing rows"
    assert keys == [(r["iteration"], r["seed"]) for r in clean_rows]
    for a, b in zip(resumed_rows, clean_rows, strict=True):
        assert {c: a[c] for c in _learning_columns(a)} == {c: b[c] for c in _learning_columns(b)}


@pytest.mark.parametrize(
    ("attack", "defense", "a", "b"),
    [
        ("fake_incentive", None, {"amount": 10.0}, {"amount": 50.0}),
        ("admo", None, {"lr": 1e-3, "budget": 10.0}, {"lr": 3e-4, "budget": 2.0}),
        ("bypass", None, {"toggle_period": 0}, {"toggle_period": 1000}),
        (None, "incentive_guard", {"outlier_z": 8.0}, {"outlier_z": 2.0}),
        (None, "health_monitor", {"patience": 50}, {"patience": 5}),
        ("admo", None, {"mode": "stealthy"}, {"mode": "disrupt"}),  # a sign: its program form
        ("admo_code", None, {"mode": "stealthy"}, {"mode": "disrupt"}),  # the same
    ],
)
def test_runs_differing_only_in_attack_or_defense_numbers_share_one_program(attack, defense, a, b):
    """Numeric attack and defense parameters are traced data, not constants: the chunk
    lowered for two configs that differ only in them is one and the same program."""
    import dataclasses

    from pimbot.training.config import resolve

    base = RunConfig(**{**SMALL, "iterations": 20, "eval_period": 10, "seeds": 2})

    def resolved(params):
        if attack:
            return resolve(
                dataclasses.replace(base, attack=attack, attack_params=tuple(params.items()))
            )
        return resolve(dataclasses.replace(base, defenses=((defense, tuple(params.items())),)))

    first, second = resolved(a), resolved(b)
    assert (first.attack, first.defenses) != (second.attack, second.defenses)
    keys = runner.seed_keys(0, 2)
    states = runner.init_states(first, keys)
    fn = runner.make_chunk_fn(first, 1)
    texts = [
        fn.lower(states, keys, r.attack.program_form(), *runner.program_args(r)[1:]).as_text()
        for r in (first, second)
    ]
    assert texts[0] == texts[1]


def test_admo_modes_share_one_program_and_give_what_the_static_mode_gives():
    """Stealthy and disrupt ADMO run on one compiled program (`ADMO.program_form`: the
    mode's sign traced, the static mode a placeholder, "disrupt"); stealthy there gives
    bitwise what ADMO with stealthy compiled in gives (a hook that branched on `mode`
    would show here), and the two modes differ."""
    import dataclasses

    import jax

    from pimbot.training.config import resolve

    base = RunConfig(**{**SMALL, "iterations": 20, "eval_period": 10, "seeds": 2})
    keys = runner.seed_keys(0, 2)
    resolved = {
        mode: resolve(dataclasses.replace(base, attack="admo", attack_params=(("mode", mode),)))
        for mode in ("stealthy", "disrupt")
    }
    shared_fn = runner.make_chunk_fn(resolved["stealthy"], 1)
    shared = {}
    for mode, r in resolved.items():
        assert type(r.attack.program_form()) is not type(r.attack)
        states = runner.init_states(r, keys)
        rest = runner.program_args(r)[1:]  # the defenses, the env, its optimum's numbers
        shared[mode] = jax.tree.leaves(shared_fn(states, keys, r.attack.program_form(), *rest))
    assert shared_fn._cache_size() == 1  # one program for both modes
    r = resolved["stealthy"]
    own = runner.make_chunk_fn(r, 1)(runner.init_states(r, keys), keys, *runner.program_args(r))
    for a, b in zip(jax.tree.leaves(own), shared["stealthy"], strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    assert any(
        not np.array_equal(a, b) for a, b in zip(shared["stealthy"], shared["disrupt"], strict=True)
    )


def test_escape_rooms_differing_only_in_m_share_one_program_and_keep_their_own_m():
    """Escape Room's M is a traced field (`traced_fields`: the env is a pytree whose leaf is
    M): ER(4, 2) and ER(4, 3) have one program key and run on one compiled chunk, where
    ER(4, 3) gives bitwise what its own chunk gives (M = 2 compiled into the shared one
    would show here) and not what ER(4, 2) gives; the optimum's numbers are computed on
    the host, and the env's validation is not rerun on the tracers."""
    import jax

    from pimbot.training.config import resolve

    def er4(m: int):
        run = RunConfig(
            **{**SMALL, "iterations": 10, "eval_period": 5, "eval_episodes": 2, "seeds": 2},
            env_params=(("n_agents", 4), ("min_at_lever", m)),
        )
        return resolve(run)

    first, second = er4(2), er4(3)
    assert programs.program_key(first, 1, 2) == programs.program_key(second, 1, 2)
    env_argument = runner.program_args(second)[2]
    assert env_argument is second.env and jax.tree.leaves(env_argument) == [3]
    assert programs.optimum_numbers(second.env) == {
        "optimal_team_return_reciprocal": np.float32(1) / np.float32(7),
        "optimal_threshold": np.float32(0.9 * 7),
    }
    keys = runner.seed_keys(0, 2)
    shared_fn = runner.make_chunk_fn(first, 2)
    shared = {
        r.env.min_at_lever: jax.tree.leaves(
            shared_fn(runner.init_states(r, keys), keys, *runner.program_args(r))
        )
        for r in (first, second)
    }
    assert shared_fn._cache_size() == 1
    own_fn = runner.make_chunk_fn(second, 2)
    own = own_fn(runner.init_states(second, keys), keys, *runner.program_args(second))
    for a, b in zip(jax.tree.leaves(own), shared[3], strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    assert any(not np.array_equal(a, b) for a, b in zip(shared[2], shared[3], strict=True))


def test_reciprocator_balances_and_nl_share_one_program_and_keep_their_own_results():
    """The Reciprocator's numbers and its balance (`grudge`, traced as its index) are
    arguments of the program, and `nl` is the same code at weight 0: the petty and the
    credit − debit balance and NL have one program key and run on one compiled chunk, where
    each gives bitwise what its own config compiled in gives (passed as None, the program
    closes over it and takes the balance's Python branch), and the three differ."""
    import jax

    from pimbot.training.config import resolve

    tiny = (("num_envs", 4), ("policy_hidden", (8,)), ("voi_hidden", (8,)), ("voi_batch", 16))
    tiny += (("voi_steps", 2), ("ppo_epochs", 2))

    def run(learner: str, grudge: str):
        hparams = (*tiny, ("grudge", grudge))
        spec = {**SMALL, "iterations": 4, "eval_period": 2, "eval_episodes": 2, "seeds": 2}
        return resolve(RunConfig(**{**spec, "learner": learner}, hparams=hparams))

    runs = {
        "petty": run("reciprocator", "petty"),
        "accumulated": run("reciprocator", "accumulated"),
        "nl": run("nl", "petty"),
    }
    assert len({programs.program_key(r, 1, 2) for r in runs.values()}) == 1
    keys = runner.seed_keys(0, 2)
    shared_fn = runner.make_chunk_fn(runs["petty"], 1)
    for name, r in runs.items():
        args = runner.program_args(r)
        assert jax.tree.leaves(args[4]) != [] and args[4].grudge in (0, 1)
        shared = jax.tree.leaves(shared_fn(runner.init_states(r, keys), keys, *args))
        own_fn = runner.make_chunk_fn(r, 1)
        own = jax.tree.leaves(own_fn(runner.init_states(r, keys), keys, *args[:4], None))
        for a, b in zip(own, shared, strict=True):
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b), err_msg=name)
        runs[name] = shared
    assert shared_fn._cache_size() == 1
    for a, b in (("petty", "accumulated"), ("petty", "nl")):
        assert any(not np.array_equal(x, y) for x, y in zip(runs[a], runs[b], strict=True))


@pytest.mark.parametrize(
    ("learner", "field", "values"),
    [("lio", "lr_incentive", (1e-3, 3e-3)), ("pg", "gamma", (0.99, 0.9))],
)
def test_runs_differing_only_in_a_traced_hyperparameter_share_one_program(learner, field, values):
    """LIO's and PG's rates, loss weights and γ are traced: two values, one program key and
    one compiled chunk, each value giving bitwise what it gives compiled in, and the two
    differing."""
    import jax

    from pimbot.training.config import resolve

    spec = {**SMALL, "iterations": 20, "eval_period": 10, "seeds": 2, "learner": learner}
    runs = [resolve(RunConfig(**spec, hparams=((field, v),))) for v in values]
    assert programs.program_key(runs[0], 1, 2) == programs.program_key(runs[1], 1, 2)
    keys = runner.seed_keys(0, 2)
    shared_fn, shared = runner.make_chunk_fn(runs[0], 1), []
    for r in runs:
        args = runner.program_args(r)
        shared.append(jax.tree.leaves(shared_fn(runner.init_states(r, keys), keys, *args)))
        own_fn = runner.make_chunk_fn(r, 1)
        own = own_fn(runner.init_states(r, keys), keys, *args[:4], None)
        for a, b in zip(jax.tree.leaves(own), shared[-1], strict=True):
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    assert shared_fn._cache_size() == 1
    assert any(not np.array_equal(a, b) for a, b in zip(*shared, strict=True))


def test_a_program_refuses_a_traced_field_that_is_not_a_number():
    import dataclasses as dc
    from typing import ClassVar

    from pimbot.envs.core import InvalidParameter, TracedFields, program_env

    @dc.dataclass(frozen=True)
    class Odd(TracedFields):
        shape: tuple = (2, 3)
        traced_fields: ClassVar[tuple[str, ...]] = ("shape",)

    with pytest.raises(
        InvalidParameter, match=r"Odd.traced_fields: shape must be a bool, int or float field"
    ):
        program_env(Odd())


def test_strategy_attacks_on_one_shared_program_give_their_own_results(tmp_path):
    """Clean, fake incentive and bypass run on one `strategy_union.Strategies` program (one
    compile, the program kept in a ProgramCache) write what each writes on its own program:
    bitwise equal metrics and checkpoints."""
    from pimbot.training.config import resolve

    runs = {
        name: RunConfig(**SMALL, seeds=2, attack=attack)
        for name, attack in (("clean", None), ("fake", "fake_incentive"), ("bypass", "bypass"))
    }
    attacks = [resolve(run).attack for run in runs.values()]
    strategies = {strategy_union.member_kind(a): a for a in attacks}
    assert len(strategies) == 3
    keys = {programs.share_key(resolve(run), 1, 2) for run in runs.values()}
    assert len(keys) == 1
    assert len({programs.program_key(resolve(run), 1, 2) for run in runs.values()}) == 3
    cache = runner.ProgramCache()
    for name, run in runs.items():
        runner.train(run, tmp_path / "own" / name, progress=False)
        runner.train(
            run, tmp_path / "shared" / name, progress=False, cache=cache, strategies=strategies
        )
    assert len(cache.compiled) == 1 and cache.reused == 2
    for name in runs:
        own, shared = tmp_path / "own" / name, tmp_path / "shared" / name
        rows = [
            [{c: r[c] for c in _learning_columns(r)} for r in store.read_metrics(d)]
            for d in (own, shared)
        ]
        assert rows[0] == rows[1], name
        state = "checkpoint/state.msgpack"
        assert (own / state).read_bytes() == (shared / state).read_bytes(), name
        assert (
            store.read_json(own / "config.json")["identity"]
            == store.read_json(shared / "config.json")["identity"]
        )
    # the attacks did change the runs
    clean, fake = (store.read_metrics(tmp_path / "own" / n) for n in ("clean", "fake"))
    assert clean[-1]["eval/given/agent_0"] != fake[-1]["eval/given/agent_0"]


def test_train_checks_a_run_once_and_takes_a_checked_one_as_it_is(tmp_path, monkeypatch):
    """`runner.check` resolves the run and checks its directory once per `train`; a caller
    that has made the checks itself (the command line, before its audit log) passes the
    ResolvedRun with checked=True, and train makes neither again. Same metrics either way."""
    from pimbot.training import config

    calls: list[str] = []

    def counted(name, fn):
        def wrapper(*args, **kwargs):
            calls.append(name)
            return fn(*args, **kwargs)

        return wrapper

    monkeypatch.setattr(runner, "resolve", counted("resolve", config.resolve))
    monkeypatch.setattr(runner, "check_run_dir", counted("check_run_dir", runner.check_run_dir))
    run, cache = RunConfig(**SMALL, seeds=2), runner.ProgramCache()
    runner.train(run, tmp_path / "a", progress=False, cache=cache)
    assert calls == ["resolve", "check_run_dir"]
    resolved, backends = runner.check(run, tmp_path / "b")
    runner.train(resolved, tmp_path / "b", progress=False, log=backends, cache=cache, checked=True)
    assert calls == ["resolve", "check_run_dir"] * 2
    assert cache.reused == 1  # one program
    rows = {
        name: [{c: r[c] for c in _learning_columns(r)} for r in store.read_metrics(tmp_path / name)]
        for name in ("a", "b")
    }
    assert rows["a"] == rows["b"] and len(rows["a"]) == 4
