"""ms per LIO iteration (10 seeds vmapped) with each defense set, clean, interleaved.

    python benchmarks/defense_iteration_time.py SUITE_DIR

Writes SUITE_DIR/defenses/iteration_time.json ({env label: {defense set: ms}}), which
`pimbot report` shows beside the defense matrix. The defense sets are the paper
suite's (`presets.DEFENSE_SETS`) plus "none"; the settings are those of
`presets.DEFENSE_SETTINGS`. Each timed call is `iterations` updates under `lax.scan`,
compiled beforehand; the median over `--repeats` interleaved calls is reported.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from pimbot import jax_setup

jax_setup.enable_compilation_cache()

import jax  # noqa: E402
import numpy as np  # noqa: E402

from pimbot import envs  # noqa: E402
from pimbot.analysis.runs import env_label  # noqa: E402
from pimbot.suites import presets  # noqa: E402
from pimbot.training.config import (  # noqa: E402
    RunConfig,
    env_parameters,  # noqa: E402
    resolve,
)
from pimbot.training.runner import init_states  # noqa: E402


def timed_update(run: RunConfig, iterations: int):
    """(compiled fn(states) -> states, initial states) of `iterations` LIO updates."""
    r = resolve(run)

    def many(states, attack, defenses):
        def one(s):
            step = lambda s, _: r.learner.update(s, r.env, r.learner_config, attack, defenses)  # noqa: E731
            return jax.lax.scan(step, s, None, length=iterations)[0]

        return jax.vmap(one)(states)

    states = init_states(r, jax.random.split(jax.random.PRNGKey(0), run.seeds))
    fn = jax.jit(many).lower(states, r.attack, r.defenses).compile()
    return (lambda s: fn(s, r.attack, r.defenses)), states


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("suite_dir", type=Path)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--iterations", type=int, default=200)
    args = parser.parse_args()
    sets = {"none": ()} | dict(presets.DEFENSE_SETS)
    result: dict[str, dict[str, float]] = {}
    for setting in presets.DEFENSE_SETTINGS:
        fns = {}
        for label, names in sets.items():
            run = RunConfig(
                setting.env_id,
                setting.env_params,
                hparams=setting.hparams,
                seeds=10,
                defenses=tuple((n, ()) for n in names),
            )
            fn, states = timed_update(run, args.iterations)
            jax.block_until_ready(fn(states))  # warm-up
            fns[label] = (fn, states)
        times: dict[str, list[float]] = {label: [] for label in sets}
        for _ in range(args.repeats):
            for label, (fn, states) in fns.items():
                t = time.perf_counter()
                jax.block_until_ready(fn(states))
                times[label].append((time.perf_counter() - t) / args.iterations * 1000)
        env = envs.make(setting.env_id, **dict(setting.env_params))
        label = env_label(setting.env_id, env_parameters(env))
        result[label] = {k: float(np.median(v)) for k, v in times.items()}
        print(label, {k: round(v, 3) for k, v in result[label].items()}, flush=True)
    out = args.suite_dir / "defenses" / "iteration_time.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=2) + "\n")
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
