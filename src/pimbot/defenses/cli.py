"""Command line of the defenses: `pimbot defenses`, `pimbot audit verify LOG`, and the
`pimbot train` options `--defense`, `--defense-param/--dp` and `--audit-log`."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

DEPLOYMENT = {
    "authenticated_channel": "HMAC-SHA256 incentive messages with per-pair keys, sequence "
    "numbers, replay window and step order (pimbot.defenses.channel)",
    "audit_log": "hash-chained JSONL log; `pimbot audit verify LOG` (pimbot.defenses.audit); "
    "`pimbot train --audit-log PATH` writes one",
}


def add_parser(commands) -> None:
    """Adds `pimbot defenses` and `pimbot audit verify LOG [--head HASH]`."""
    commands.add_parser("defenses", help="list defenses and their parameters")
    audit = commands.add_parser("audit", help="tamper-evident audit logs")
    actions = audit.add_subparsers(dest="audit_command", required=True)
    check = actions.add_parser("verify", help="verify a log (names the first bad record)")
    check.add_argument("log", help="the JSONL audit log")
    check.add_argument("--head", default=None, help="expected last-record hash")


def add_train_arguments(train: argparse.ArgumentParser) -> None:
    """The defense options of `pimbot train`."""
    train.add_argument(
        "--defense",
        action="append",
        default=[],
        metavar="NAME",
        help="training-time defense of the honest agents (repeatable; see `pimbot defenses`)",
    )
    train.add_argument(
        "--defense-param",
        "--dp",
        action="append",
        default=[],
        metavar="[NAME.]name=value",
        help="defense parameter (repeatable), e.g. --dp min_epsilon=0.3 "
        "--dp health_monitor.patience=20",
    )
    train.add_argument(
        "--audit-log",
        default=None,
        metavar="PATH",
        help="append a hash-chained audit log",
    )


def run_defenses(args: argparse.Namespace) -> tuple[tuple[str, Any], ...]:
    """`RunConfig.defenses` from the train options (InvalidParameter on bad input)."""
    from pimbot.envs.core import InvalidParameter
    from pimbot.experiment.config import parse_defenses

    if args.defense_param and not args.defense:
        raise InvalidParameter("defense_param: given without --defense NAME")
    return parse_defenses(args.defense, args.defense_param)


def chunk_logger(path: str | Path | None, run_config):
    """A runner `on_chunk(done, states, rows)` callback writing the audit log, or None."""
    if path is None:
        return None
    import dataclasses

    import flax.serialization
    import jax

    from pimbot.defenses.audit import AuditLog, digest_bytes
    from pimbot.envs.core import InvalidParameter

    try:
        log = AuditLog(path)  # continues an existing log only if it verifies
    except ValueError as error:
        raise InvalidParameter(str(error)) from None
    log.append("run", config=_jsonable(dataclasses.asdict(run_config)))

    def on_chunk(done: int, states, rows: list[dict]) -> None:
        host = jax.device_get(states)
        seeds = sorted({int(r["seed"]) for r in rows})
        policy = [
            digest_bytes(
                flax.serialization.to_bytes(jax.tree.map(lambda x, s=s: x[s], host.policy))
            )
            for s in range(len(seeds))
        ]
        incentive = getattr(host, "incentive", None)
        incentive_digests = (
            [
                digest_bytes(
                    flax.serialization.to_bytes(jax.tree.map(lambda x, s=s: x[s], incentive))
                )
                for s in range(len(seeds))
            ]
            if incentive is not None
            else []
        )
        latest = [r for r in rows if int(r["iteration"]) == done]
        transfers = {
            str(r["seed"]): {
                k.removeprefix("eval/"): r[k]
                for k in r
                if k.startswith(("eval/given/", "eval/received/"))
            }
            for r in latest
        }
        log.append(
            "update",
            iteration=done,
            seeds=seeds,
            policy_sha256=policy,
            incentive_sha256=incentive_digests,
            incentives_at_eval=transfers,
            defense_events={
                k: sum(float(r[k]) for r in rows)
                for k in (rows[0] if rows else {})
                if k.startswith("defense/")
            },
        )

    on_chunk.log = log  # type: ignore[attr-defined]
    return on_chunk


def _jsonable(value):
    import json

    return json.loads(json.dumps(value, default=str))


def cmd_defenses() -> int:
    from pimbot import defenses

    for name in defenses.registered():
        cls = defenses.defense_class(name)
        doc = ((cls.__doc__ or "").strip().splitlines() or [""])[0]
        print(f"{name} [training, honest agents]: {doc}")
        for param, default in defenses.parameters(name).items():
            print(f"    {param} = {default!r}")
    for name, text in DEPLOYMENT.items():
        print(f"{name} [deployment layer]: {text}")
    return 0


def cmd_audit(args: argparse.Namespace) -> int:
    from pimbot.defenses.audit import verify

    path = Path(args.log)
    if not path.is_file():
        from pimbot.envs.core import InvalidParameter

        raise InvalidParameter(f"log: {path} is not a file")
    result = verify(path, head=args.head)
    print(f"{path}: {result.message}")
    return 0 if result.ok else 1


def run(args: argparse.Namespace) -> int:
    """Dispatch of `pimbot defenses` and `pimbot audit ...`."""
    if args.command == "defenses":
        return cmd_defenses()
    return cmd_audit(args)
