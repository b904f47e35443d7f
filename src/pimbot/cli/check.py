"""`pimbot check FILE.py`: load a plugin file, run its canary, print the table.

Exit status 0 when every hook of every part ran and changed what the learner does (and
every learner and env trained; an "ok" line per part says what was checked), 1 with one
line per problem otherwise, 2 for bad input (no such file, a file that registers
nothing: `pimbot.training.canary`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from pimbot import plugins
from pimbot.cli.options import CHECK_ENV

if TYPE_CHECKING:  # the command class runs this module: it is imported for its type only
    from pimbot.cli.commands import Check


def cmd_check(args: Check) -> int:
    """Runs the canary of `args.file` (its size bounded: `canary.Size`, each run announced
    on stderr); its exit status."""
    from pimbot.training import canary

    size = canary.Size(seeds=args.seeds, iterations=args.iterations, progress=True)  # bounds
    plugins.load_plugins([args.file], from_env=False)
    path = getattr(plugins.load(args.file), "__file__", None) or plugins.canonical(args.file)
    from pimbot.contracts import preflight

    preflight.check_plugins()  # a broken env is one line before any run
    options = canary.Options(
        default_env=CHECK_ENV,
        env=args.env,
        learner=args.learner,
        defense_attack=args.defense_attack,
        size=size,
    )
    parts = canary.describe(canary.parts_of(path))
    print(f"pimbot check {args.file} ({parts}): seeds: {size.seeds}, iterations: {size.iterations}")
    result = canary.check_file(path, options)
    print(canary.table(result))
    for checked in result.checked:  # the parts without a problem, also beside one with
        print(f"ok: {checked}")
    for problem in result.problems:
        print(f"problem: {problem}")
    return 1 if result.problems else 0
