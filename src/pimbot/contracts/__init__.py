"""The contracts plugins implement: attacks, defenses and learners, and their registries.

This package sits just above `pimbot.envs` and imports no plugin: the built-in
attacks (`pimbot.attacks`), defenses (`pimbot.defenses`) and learners
(`pimbot.learners`) register here through the same `register` a user's plugin
calls, and the rollout, learners and experiment layers only ever see these
base classes and registries.
"""
