"""What the defense commands do: `pimbot defenses`, `pimbot audit verify LOG`, and the
defense options of `pimbot train` (`--defense`, `--defense-param/--dp`, `--audit-log`)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

DEPLOYMENT = {
    "authenticated_channel": "HMAC-SHA256 incentive messages with per-pair keys, sequence "
    "numbers, replay window and step order (pimbot.defenses.channel)",
    "audit_log": "hash-chained JSONL log; `pimbot audit verify LOG` (pimbot.defenses.audit); "
    "`pimbot train --audit-log PATH` writes one",
}


def run_defenses(args) -> tuple[tuple[str, Any], ...]:
    """`RunConfig.defenses` from the train options (InvalidParameter on bad input)."""
    from pimbot.envs.core import InvalidParameter
    from pimbot.experiment.config import parse_defenses

    if args.defense_param and not args.defense:
        raise InvalidParameter("defense_param: given without --defense NAME")
    return parse_defenses(list(args.defense), list(args.defense_param))


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
    from pimbot.contracts.docs import describe

    for name in defenses.registered():
        cls = defenses.defense_class(name)
        doc = ((cls.__doc__ or "").strip().splitlines() or [""])[0]
        print(f"{name} [training, honest agents]: {doc}")
        print("\n".join(describe(cls, defenses.parameters(name))))
    for name, text in DEPLOYMENT.items():
        print(f"{name} [deployment layer]: {text}")
    return 0


def cmd_audit(args) -> int:
    from pimbot.defenses.audit import verify

    path = Path(args.log)
    if not path.is_file():
        from pimbot.envs.core import InvalidParameter

        raise InvalidParameter(f"log: {path} is not a file")
    result = verify(path, head=args.head)
    print(f"{path}: {result.message}")
    return 0 if result.ok else 1
