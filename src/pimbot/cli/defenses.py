"""What the defense commands do: `pimbot defenses`, `pimbot audit verify LOG`, and the
defense options of `pimbot train` (`--defense`, `--defense-param/--dp`, `--audit-log`)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

DEPLOYMENT = {
    "authenticated_channel": "HMAC-SHA256 incentive messages with per-pair keys, sequence "
    "numbers, replay window and step order (pimbot.defenses.channel)",
    "audit_log": "HMAC-SHA256-keyed JSONL log with a signed head, key kept outside the log "
    "(--audit-key FILE, $PIMBOT_AUDIT_KEY_FILE, ~/.config/pimbot/audit.key); "
    "`pimbot train --audit-log PATH` writes one, `pimbot audit verify LOG` checks it "
    "(pimbot.defenses.audit)",
}


def run_defenses(args) -> tuple[tuple[str, Any], ...]:
    """`RunConfig.defenses` from the train options (InvalidParameter on bad input)."""
    from pimbot.envs.core import InvalidParameter
    from pimbot.training.config import parse_defenses

    if args.defense_param and not args.defense:
        raise InvalidParameter("defense_param: given without --defense NAME")
    return parse_defenses(list(args.defense), list(args.defense_param))


def chunk_logger(path: str | Path | None, run_config, key_file: str | Path | None = None):
    """A runner `on_chunk(done, states, rows)` callback writing the audit log, or None.

    The key comes from `key_file`, else the default (`audit.default_key_path`), and is
    created there on first use. InvalidParameter (one line) on any problem with either.
    """
    if path is None:
        if key_file is not None:
            from pimbot.envs.core import InvalidParameter

            raise InvalidParameter("audit_key: given without --audit-log PATH")
        return None
    import dataclasses

    from pimbot.defenses.audit import AuditError, AuditLog, writer_key
    from pimbot.envs.core import InvalidParameter

    path = Path(path)
    if path.is_dir():
        raise InvalidParameter(f"audit_log: {path} is a directory, not a file")
    try:
        key, _ = writer_key(path, key_file)
        log = AuditLog(path, key)  # continues an existing log only if it verifies
        log.append("run", config=_jsonable(dataclasses.asdict(run_config)))
    except AuditError as error:
        raise InvalidParameter(str(error)) from None

    def on_chunk(done: int, states, rows: list[dict]) -> None:
        log.append("update", **_update_record(done, states, rows))

    on_chunk.log = log  # type: ignore[attr-defined]
    return on_chunk


def _update_record(done: int, states, rows: list[dict]) -> dict:
    """An audit log's `update` record after `done` iterations: each seed's policy and
    incentive parameter digests, the incentives at the latest evaluation, the defense events."""
    import flax.serialization
    import jax

    from pimbot.defenses.audit import digest_bytes

    host = jax.device_get(states)
    seeds = sorted({int(r["seed"]) for r in rows})

    def digests(params) -> list[str]:
        return [
            digest_bytes(flax.serialization.to_bytes(jax.tree.map(lambda x, s=s: x[s], params)))
            for s in range(len(seeds))
        ]

    incentive = getattr(host, "incentive", None)
    latest = [r for r in rows if int(r["iteration"]) == done]
    transfers = {
        str(r["seed"]): {
            k.removeprefix("eval/"): r[k]
            for k in r
            if k.startswith(("eval/given/", "eval/received/"))
        }
        for r in latest
    }
    return dict(
        iteration=done,
        seeds=seeds,
        policy_sha256=digests(host.policy),
        incentive_sha256=digests(incentive) if incentive is not None else [],
        incentives_at_eval=transfers,
        defense_events={
            k: sum(float(r[k]) for r in rows)
            for k in (rows[0] if rows else {})
            if k.startswith("defense/")
        },
    )


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
    """`pimbot audit verify LOG`: exit 0 ok, 1 a bad record or head (named), 2 unusable input."""
    from pimbot.defenses.audit import AuditError, default_key_path, load_key, verify
    from pimbot.envs.core import InvalidParameter

    path = Path(args.log)
    if not path.exists():
        raise InvalidParameter(f"log: {path}: no such file")
    if not path.is_file():
        raise InvalidParameter(f"log: {path} is not a file")
    head = args.head
    if head is not None and (len(head) != 64 or any(c not in "0123456789abcdef" for c in head)):
        raise InvalidParameter("head: must be 64 lowercase hex digits (a record MAC)")
    try:
        key = load_key(args.audit_key if args.audit_key is not None else default_key_path())
        result = verify(path, key, head=head)
    except AuditError as error:
        raise InvalidParameter(str(error)) from None
    print(f"{path}: {result.message}")
    return 0 if result.ok else 1
