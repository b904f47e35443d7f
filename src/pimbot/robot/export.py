"""Trained policies as ONNX models with a JSON sidecar, for robots that run onnxruntime.

`export_run(run_dir, out, seed)` writes, for one seed of a finished (or checkpointed) run:

* `agent_<i>_policy.onnx` per agent: input `observation` float32 [B, obs_dim], outputs
  `logits` and `probabilities` float32 [B, num_actions]; the agent acts by sampling an
  action from `probabilities` (its trained policy at ε = 0, as pimbot's evaluation and
  robot case study act), or takes their argmax for a greedy policy;
* `agent_<i>_incentive.onnx` per agent where the learner has an incentive channel (LIO):
  inputs `observation` float32 [B, obs_dim] (the giver's own) and `actions` int32 [B, N]
  (the joint action just played), output `incentives` float32 [B, N] (what agent i gives
  each agent; 0 to itself);
* `policy.json`: the observation layout and bounds, the action names, the env, learner and
  run configuration, pimbot's version, the seed, the ONNX inputs and outputs, and the
  largest difference between onnxruntime's outputs and pimbot's on the observations the
  export checked itself on.

The graphs are converted with jax2onnx (https://github.com/enpasos/jax2onnx) from pimbot's
own network modules (`pimbot.nets`, `pimbot.learners.reciprocator_nets`) with the trained
parameters as constants (`pimbot.robot.exportable`: which learners can be exported, and
how; others are refused by name), checked with `onnx.checker`, and run in onnxruntime
against pimbot's agents before anything is written (`pimbot.robot.export_check`).
docs/robot.md, "Exported policies (ONNX)", says how to run the models in a ROS 2 node.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import os
import re
from collections.abc import Iterator
from importlib import metadata
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp

import pimbot
from pimbot import envs
from pimbot.atomic_files import staged_directory
from pimbot.envs.core import observation_parts
from pimbot.errors import InvalidParameter
from pimbot.robot.export_check import check_parity
from pimbot.robot.exportable import (
    ACTIONS,
    INCENTIVES,
    LOGITS,
    OBSERVATION,
    PROBABILITIES,
    Agent,
    exported_agents,
    incentive_file,
    policy_file,
)
from pimbot.training import provenance, runs, store
from pimbot.training.runner import run_description

SIDECAR = "policy.json"
FORMAT = "pimbot-onnx-export/1"
"""`policy.json`'s `format`: what a later pimbot recognises as an export it may replace."""
OPSET = 17
"""ONNX opset of the models (ONNX 1.12's)."""
IR_VERSION = 8
"""ONNX IR version of the models: ONNX 1.12's, with opset 17, so onnxruntime ≥ 1.13 (2022)
runs them (jax2onnx writes the IR of the installed onnx; the models use nothing newer)."""
EXPORT_FILE = re.compile(r"agent_\d+_(policy|incentive)\.onnx")


def seed_index_of(loaded: runs.LoadedRun, seed: int | None) -> int:
    """The index of `seed` among the run's seeds (None: the first seed)."""
    if seed is None:
        return 0
    if seed not in loaded.seeds:
        raise InvalidParameter(
            f"seed: {seed} is not a seed of {loaded.run_dir} (its seeds: "
            f"{loaded.seeds[0]}–{loaded.seeds[-1]})"
        )
    return loaded.seeds.index(seed)


def require_converter() -> None:
    """InvalidParameter (one line) where jax2onnx, onnx or onnxruntime is not installed."""
    import importlib.util

    missing = [
        m for m in ("jax2onnx", "onnx", "onnxruntime") if importlib.util.find_spec(m) is None
    ]
    if missing:
        raise InvalidParameter(
            f"export: needs {', '.join(missing)} (not installed); pip install 'pimbot[onnx]'"
        )


@contextlib.contextmanager
def _quiet_converter() -> Iterator[None]:
    """onnx_ir (under jax2onnx) logs a warning for every intermediate value it leaves
    untyped; the models are complete (`onnx.checker` passes), so they are noise here."""
    logger = logging.getLogger("onnx_ir")
    level = logger.level
    logger.setLevel(logging.ERROR)
    try:
        yield
    finally:
        logger.setLevel(level)


def to_onnx(fn, inputs: list[tuple[str, int, Any]], outputs: list[str], name: str, props):
    """`fn` as an ONNX model (checked): `inputs` (name, size, dtype) of shape [B, size] with
    a free batch dimension B, named `outputs`, metadata `props`."""
    import jax2onnx
    import onnx

    (batch,) = jax.export.symbolic_shape("B")
    specs = [jax.ShapeDtypeStruct((batch, size), dtype) for _, size, dtype in inputs]
    with _quiet_converter():
        model = jax2onnx.to_onnx(
            fn,
            specs,
            model_name=name,
            opset=OPSET,
            input_names=[n for n, _, _ in inputs],
            output_names=outputs,
        )
    model.ir_version = IR_VERSION
    onnx.helper.set_model_props(model, props)
    onnx.checker.check_model(model, full_check=True)
    return model


class NotConvertible(InvalidParameter):
    """A learner's policy or incentives hold an operation ONNX (or jax2onnx) lacks."""


def convert(loaded: runs.LoadedRun, seed_index: int, agents: list[Agent]) -> dict[str, Any]:
    """File name -> ONNX model of every agent's policy and, where it has one, incentives.

    Raises:
        NotConvertible: one line naming the learner, the model and what failed.
    """
    r = loaded.resolved
    obs_input = (OBSERVATION, r.env.obs_dim, jnp.float32)
    graphs = []
    for agent in agents:
        graphs.append(
            (policy_file(agent.index), agent.policy, [obs_input], [LOGITS, PROBABILITIES])
        )
        if agent.give is not None:
            inputs = [obs_input, (ACTIONS, r.env.num_agents, jnp.int32)]
            graphs.append((incentive_file(agent.index), agent.give, inputs, [INCENTIVES]))
    models = {}
    for file, fn, inputs, outputs in graphs:
        props = {
            "pimbot_version": pimbot.__version__,
            "env_id": r.run.env_id,
            "learner": r.run.learner,
            "seed": str(loaded.seeds[seed_index]),
            "iteration": str(loaded.iteration),
        }
        try:
            models[file] = to_onnx(fn, inputs, outputs, file.removesuffix(".onnx"), props)
        except Exception as error:  # jax2onnx's or onnx.checker's: an operation ONNX lacks
            reason = (str(error).strip().splitlines() or [type(error).__name__])[-1]
            raise NotConvertible(
                f"learner: {r.run.learner}'s {file.removesuffix('.onnx')} does not convert to "
                f"ONNX ({type(error).__name__}: {reason[:200]}); nothing written"
            ) from error
    return models


def model_io(model) -> dict[str, list[dict[str, Any]]]:
    """The inputs and outputs of an ONNX model as it declares them: name, shape (a symbolic
    dimension by its name), dtype."""
    import onnx

    def entry(value) -> dict[str, Any]:
        tensor = value.type.tensor_type
        shape = [d.dim_param or d.dim_value for d in tensor.shape.dim]
        dtype = onnx.helper.tensor_dtype_to_np_dtype(tensor.elem_type).name
        return {"name": value.name, "shape": shape, "dtype": dtype}

    return {
        "inputs": [entry(v) for v in model.graph.input],
        "outputs": [entry(v) for v in model.graph.output],
    }


def observation_layout(env, learner_config: Any = None) -> dict[str, Any]:
    """Shape, dtype, bounds and every part of one agent's observation, each with its slice
    (`start`, `stop`), meaning, units and bounds (`envs.core.observation_parts`). An
    incentive part's upper bound, which the env cannot know, is the learner's per-step
    bound (`incentive_max`) times the episode's steps where the learner has one."""
    per_step = getattr(learner_config, "incentive_max", None)
    parts, start = [], 0
    for part in observation_parts(env):
        high = part.high
        if high is None and part.name == "incentives_given" and per_step is not None:
            high = float(per_step) * env.max_steps
        parts.append(
            {
                "name": part.name,
                "start": start,
                "stop": start + part.size,
                "meaning": part.meaning,
                "units": part.units,
                "low": part.low,
                "high": high,  # JSON null: unbounded
            }
        )
        start += part.size
    highs = [p["high"] for p in parts]
    return {
        "shape": [env.obs_dim],
        "dtype": "float32",
        "low": min(p["low"] for p in parts),
        "high": None if None in highs else max(highs),
        "parts": parts,
        "layout": "docs/environments.md; one row per agent, the parts in this order",
    }


def describe(loaded: runs.LoadedRun, seed_index: int, models, parity) -> dict[str, Any]:
    """The sidecar policy.json: what the models are, what they take and return, where from."""
    import onnx

    r = loaded.resolved
    env, spec = r.env, envs.spec(r.run.env_id)
    description = run_description(r)
    names = list(spec.action_names) or [f"a{k}" for k in range(env.num_actions)]
    agents = []
    for i in range(env.num_agents):
        entry: dict[str, Any] = {"index": i, "policy": {"file": policy_file(i)}, "incentive": None}
        entry["policy"] |= model_io(models[policy_file(i)])
        if incentive_file(i) in models:
            entry["incentive"] = {"file": incentive_file(i)} | model_io(models[incentive_file(i)])
        agents.append(entry)
    adversary = getattr(r.attack, "adversary", None) if r.run.attack else None
    return {
        "format": FORMAT,
        "pimbot_version": pimbot.__version__,
        "git_commit": store.git_commit(),
        "converter": {
            "jax2onnx": metadata.version("jax2onnx"),
            "onnx": onnx.__version__,
            "opset": OPSET,
            "ir_version": IR_VERSION,
        },
        "run_dir": str(loaded.run_dir.resolve()),
        "iteration": loaded.iteration,
        "seed": loaded.seeds[seed_index],
        "env": description["env"] | {"description": spec.description, "max_steps": env.max_steps},
        "learner": {"name": r.run.learner, "config": dataclasses.asdict(r.learner_config)},
        "run_config": description["run_config"],
        "adversary": adversary,
        "observation": observation_layout(env, r.learner_config),
        "actions": {"count": env.num_actions, "names": names, "dtype": "int32"},
        "acting": "sample the action index from `probabilities` (the trained policy at "
        "epsilon = 0, as pimbot evaluates it); argmax for a greedy policy. The models hold "
        "the agents' trained networks only: an attack's hooks (an idling adversary, a "
        "forged incentive) are not in them.",
        "agents": agents,
        "parity": parity,
    }


def is_export(directory: Path) -> bool:
    """Whether `directory` holds a previous export only (policy.json of `FORMAT` and ONNX
    models named as an export names them), which a new export may replace."""
    entries = list(directory.iterdir())
    for path in entries:
        plain = path.is_file() and not path.is_symlink()
        if not plain or not (path.name == SIDECAR or EXPORT_FILE.fullmatch(path.name)):
            return False
    try:
        return store.read_json(directory / SIDECAR).get("format") == FORMAT
    except (OSError, InvalidParameter):
        return False


def check_out(out: Path) -> None:
    """InvalidParameter (one line) where `out` cannot take an export: a link, a file, a
    directory holding anything but a previous export, or under a file."""
    if out.is_symlink():
        raise InvalidParameter(f"out: {out} is a symbolic link; give a directory of its own")
    absolute, here = Path(os.path.abspath(out)), Path.cwd()
    if absolute == here or absolute in here.parents:
        raise InvalidParameter(
            f"out: {out} is the current directory or holds it, which an export (a directory "
            "renamed into place) cannot replace; give a directory to create, e.g. --out export"
        )
    if out.exists() and not out.is_dir():
        raise InvalidParameter(f"out: {out} exists and is not a directory")
    if out.is_dir() and any(out.iterdir()) and not is_export(out):
        raise InvalidParameter(
            f"out: {out} is not empty and holds no pimbot export; give a new or empty directory"
        )
    for parent in out.absolute().parents:
        if parent.exists():
            if not parent.is_dir():
                raise InvalidParameter(f"out: {parent} is a file, not a directory")
            break


def write_export(out: Path, files: dict[str, bytes], sidecar: dict[str, Any]) -> None:
    """Writes the export into a new directory beside `out`, then renames it to `out` (a
    previous export there is replaced): readers see the old export or the new one (or,
    for a moment, none), never a partial one."""
    out.parent.mkdir(parents=True, exist_ok=True)
    umask = os.umask(0o022)
    os.umask(umask)
    with staged_directory(out) as new:
        new.mkdir()
        for name, data in files.items():
            (new / name).write_bytes(data)
        store.write_json(new / SIDECAR, sidecar)
        (new / SIDECAR).chmod(0o666 & ~umask)  # as a file made with open (mkstemp's is private)


def export_run(
    run_dir: str | Path,
    out: str | Path,
    seed: int | None = None,
    accept_changed_code: bool = False,
) -> dict[str, Any]:
    """Exports one seed (None: the run's first) of `run_dir` as ONNX models and policy.json
    into `out`; returns the sidecar. Every input is checked before anything is written: a
    run made by other code (another pimbot, a changed plugin: `provenance.check`) only
    with `accept_changed_code`, which policy.json then records ("provenance_changes").

    Raises:
        InvalidParameter: not a run directory, no checkpoint, a seed the run lacks, a
            learner without a `PolicyExport`, an `out` that is not an empty directory or a
            previous export, or the converter missing (one line each).
    """
    require_converter()
    out = Path(out)
    check_out(out)  # before any work: the run is loaded and converted only for a usable out
    changed = provenance.check(Path(run_dir), accept_changed_code, "export")
    loaded = runs.load_run(run_dir)
    seed_index = seed_index_of(loaded, seed)
    agents = exported_agents(loaded, seed_index)
    models = convert(loaded, seed_index, agents)
    parity = check_parity(loaded, seed_index, agents, models)
    sidecar = describe(loaded, seed_index, models, parity)
    if changed:  # accepted: the run's own directory is left as it is (readers never write)
        sidecar[provenance.CHANGES] = changed
    write_export(out, {name: m.SerializeToString() for name, m in models.items()}, sidecar)
    return sidecar
