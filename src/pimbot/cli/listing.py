"""`pimbot envs | learners | attacks`: every registered entry (plugins included), each
parameter with its default and its docstring."""

from __future__ import annotations

import dataclasses

from pimbot.contracts.docs import describe
from pimbot.contracts.params import field_ranges


def _first_line(obj) -> str:
    return ((obj.__doc__ or "").strip().splitlines() or [""])[0]


def print_envs() -> int:
    from pimbot import envs, learners

    for env_id in envs.registered():
        entry = envs.spec(env_id)
        print(f"{env_id}: {entry.description}")
        print("\n".join(describe(entry.constructor, entry.parameters())))
        for learner, params in learners.declared_env_params(env_id).items():
            values = ", ".join(f"{k}={v!r}" for k, v in params.items())
            print(f"    with --learner {learner} (unless given): {values}")
    return 0


def print_learners() -> int:
    from pimbot import envs, learners

    for name in learners.registered():
        definition = learners.get(name)
        print(f"{name}: {definition.description}")
        print(f"    incentive channel: {'yes' if definition.has_incentives else 'no'}")
        print(f"    attack hooks: {', '.join(definition.attack_hooks) or 'none'}")
        print(f"    defense hooks: {', '.join(definition.defense_hooks) or 'none'}")
        base = dataclasses.replace(definition.config_cls(), **dict(definition.base_overrides))
        values = {f.name: getattr(base, f.name) for f in dataclasses.fields(base)}
        print("    hyperparameters (--hp NAME=VALUE):")
        ranges = field_ranges(base)
        print("\n".join(describe(definition.config_cls, values, "      ", ranges)))
        for env_id in envs.registered():
            declared = definition.default_config(envs.spec(env_id))
            changed = {
                f.name: getattr(declared, f.name)
                for f in dataclasses.fields(declared)
                if getattr(declared, f.name) != getattr(base, f.name)
            }
            if changed:
                values = ", ".join(f"{k}={v!r}" for k, v in changed.items())
                print(f"    on {env_id} (declared for this env): {values}")
            env_params = definition.default_env_params(envs.spec(env_id))
            if env_params:
                values = ", ".join(f"{k}={v!r}" for k, v in env_params.items())
                print(f"    on {env_id}, env parameters unless given: {values}")
    return 0


def print_attacks() -> int:
    from pimbot import attacks

    for name in attacks.registered():
        cls = attacks.attack_class(name)
        tags = [f"{cls.lever} lever"] if getattr(cls, "lever", None) else []
        if getattr(cls, "hooks", ()):
            tags.append("hooks: " + ", ".join(cls.hooks))
        doc = _first_line(cls)
        print(f"{name} [{'; '.join(tags)}]: {doc}" if tags else f"{name}: {doc}")
        print("\n".join(describe(cls, attacks.parameters(name))))
    return 0
