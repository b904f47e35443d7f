"""`audit_log`: an append-only JSONL log, keyed with HMAC-SHA256, and its verification.

Record k is one JSON line {"v": 2, "index": k, "prev": t_{k−1}, "kind": ..., "data": {...},
"key": key id, "mac": t_k} with t_k = HMAC-SHA256(key, canonical JSON of the other fields).
t_{−1} is a random log id, so no two logs share a chain. Beside the log, `LOG.head` holds
the signed head {"records": n, "last": t_{n−1}, "key", "mac"}, rewritten atomically after
every record.

What it protects, and the boundary. The key is kept **outside** the log: a key file
(32 random bytes, hex, mode 0600, created on first use) named by `--audit-key FILE`, else
`$PIMBOT_AUDIT_KEY_FILE`, else `$XDG_CONFIG_HOME/pimbot/audit.key` (default
`~/.config/pimbot/audit.key`); a key file in the log's own directory is refused. Whoever
can edit the log and its head but cannot read the key cannot edit, insert, delete,
reorder, re-sign or re-chain any record (plain SHA-256 included), cut records from the end,
or forge the head, without `verify` naming the first bad record (or the head). Not
covered: someone who kept an *older copy* of the log and its head can put both back (a
rollback to a state that once existed) — `pimbot train --audit-log` prints the head, and
`verify(head=...)` (`pimbot audit verify --head TAG`) catches that; deleting the log and
its head together leaves nothing to verify; anyone holding the key can rewrite everything.

Logs of the old unkeyed format (a plain SHA-256 `hash` per record) are refused as not
tamper-evident: anyone can recompute such a chain. Records beyond the signed head (the
writer stopped between a record and its head) verify, with a note: they carry valid MACs.
A writer continuing a log drops a partial last line (a writer killed mid-write) when
everything before it verifies, and says so in a MACed "recovered" record.
"""

from __future__ import annotations

import dataclasses
import hashlib
import hmac
import json
import os
import re
import secrets
import stat
from pathlib import Path
from typing import Any

from pimbot.atomic_files import write_atomic

VERSION = 2
KEY_BYTES = 32
MIN_KEY_BYTES = 16
KEY_ENV = "PIMBOT_AUDIT_KEY_FILE"
RECORD_FIELDS = frozenset({"v", "index", "prev", "kind", "data", "key", "mac"})
HEAD_FIELDS = frozenset({"v", "records", "last", "key", "mac"})
UNKEYED_FIELDS = frozenset({"index", "prev", "kind", "data", "hash"})
_HEX64 = re.compile(r"[0-9a-f]{64}\Z")
_RECORD_DOMAIN = b"pimbot-audit-record\0"
_HEAD_DOMAIN = b"pimbot-audit-head\0"


class AuditError(ValueError):
    """A one-line problem with an audit log or its key (the CLI prints it, exit 2)."""


# --- keys --------------------------------------------------------------------------------


def default_key_path() -> Path:
    """`$PIMBOT_AUDIT_KEY_FILE`, else `$XDG_CONFIG_HOME/pimbot/audit.key` (~/.config)."""
    named = os.environ.get(KEY_ENV)
    if named:
        return Path(named).expanduser()
    config = os.environ.get("XDG_CONFIG_HOME") or Path.home() / ".config"
    return Path(config) / "pimbot" / "audit.key"


def load_key(path: str | Path) -> bytes:
    """Reads a key file (hex, ≥ 16 bytes, not readable or writable by other users)."""
    path = Path(path)
    try:
        info = path.stat()
    except FileNotFoundError:
        raise AuditError(
            f"audit key {path}: no such file (the key the log was written with is needed; "
            f"--audit-key FILE or ${KEY_ENV})"
        ) from None
    except OSError as error:
        raise AuditError(f"audit key {path}: {error.strerror}") from None
    if not stat.S_ISREG(info.st_mode):
        raise AuditError(f"audit key {path}: not a regular file")
    if os.name == "posix" and info.st_mode & 0o077:
        raise AuditError(
            f"audit key {path}: readable or writable by other users "
            f"(mode {stat.S_IMODE(info.st_mode):04o}); run chmod 600 {path}"
        )
    try:
        key = bytes.fromhex(path.read_bytes().decode("ascii").strip())
    except OSError as error:
        raise AuditError(f"audit key {path}: {error.strerror}") from None
    except (UnicodeDecodeError, ValueError):
        raise AuditError(f"audit key {path}: not a hex key") from None
    if len(key) < MIN_KEY_BYTES:
        raise AuditError(f"audit key {path}: {len(key)} bytes, at least {MIN_KEY_BYTES} needed")
    return key


def create_key(path: str | Path) -> bytes:
    """Writes a new random key file with mode 0600 (its directory 0700); never overwrites."""
    path = Path(path)
    key = secrets.token_bytes(KEY_BYTES)
    try:
        path.parent.mkdir(parents=True, exist_ok=True, mode=0o700)
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    except FileExistsError:
        return load_key(path)  # created meanwhile by another writer
    except OSError as error:
        raise AuditError(f"audit key {path}: cannot create it: {error.strerror}") from None
    with os.fdopen(fd, "w") as f:
        f.write(key.hex() + "\n")
    return key


def writer_key(log: str | Path, path: str | Path | None = None) -> tuple[bytes, Path]:
    """The key for writing `log` (created on first use) and its file."""
    path = Path(path) if path is not None else default_key_path()
    if path.absolute().parent.resolve() == Path(log).absolute().parent.resolve():
        raise AuditError(
            f"audit key {path}: in the log's own directory; whoever can edit the log could "
            "read it — keep the key elsewhere (--audit-key FILE)"
        )
    if not path.exists():
        return create_key(path), path
    return load_key(path), path


def key_id(key: bytes) -> str:
    """A short public fingerprint of the key (tells a wrong key from an edited record)."""
    return hmac.new(key, b"pimbot-audit-key-id", hashlib.sha256).hexdigest()[:16]


def _canonical(body: dict[str, Any]) -> bytes:
    return json.dumps(body, sort_keys=True, separators=(",", ":"), allow_nan=True).encode()


def record_mac(key: bytes, body: dict[str, Any]) -> str:
    """t_k: HMAC-SHA256 of a record's fields other than `mac`."""
    return hmac.new(key, _RECORD_DOMAIN + _canonical(body), hashlib.sha256).hexdigest()


def head_mac(key: bytes, body: dict[str, Any]) -> str:
    return hmac.new(key, _HEAD_DOMAIN + _canonical(body), hashlib.sha256).hexdigest()


def head_path(path: str | Path) -> Path:
    path = Path(path)
    return path.with_name(path.name + ".head")


def digest_bytes(data: bytes) -> str:
    """SHA-256 hex digest (policy parameter digests, checkpoints)."""
    return hashlib.sha256(data).hexdigest()


# --- writing -----------------------------------------------------------------------------


class AuditLog:
    """Appends keyed records to a log (continuing an existing one only if it verifies).

    Holds an exclusive lock on the log while open: a second writer is refused.
    """

    def __init__(self, path: str | Path, key: bytes):
        if len(key) < MIN_KEY_BYTES:
            raise AuditError(f"audit key: {len(key)} bytes, at least {MIN_KEY_BYTES} needed")
        self.path, self.key, self.key_id = Path(path), key, key_id(key)
        self._lock = self._acquire_lock()
        fresh = not head_path(self.path).exists() and (
            not self.path.exists() or self.path.stat().st_size == 0
        )
        if fresh:
            self.count, self.last_hash = 0, secrets.token_hex(32)  # the log id
        else:
            result, dropped = self._verify_for_writing()
            if not result.ok:
                self.close()
                raise AuditError(f"audit log {self.path} fails verification: {result.message}")
            self.count, self.last_hash = result.records, result.head
            if dropped:
                self.append("recovered", dropped_bytes=dropped, reason="a partial last line")

    def _verify_for_writing(self) -> tuple[VerifyResult, int]:
        """The log's verification, after dropping a partial last line (what a writer killed
        mid-write leaves) if everything before it verifies; and the bytes dropped."""
        result = verify(self.path, self.key)
        if result.ok:
            return result, 0
        data = self.path.read_bytes()
        cut = data.rfind(b"\n") + 1
        if data.endswith(b"\n") or result.first_bad != data.count(b"\n") + 1:
            return result, 0
        shorter = verify(self.path, self.key, data=data[:cut])
        if not shorter.ok:
            return result, 0
        try:
            os.truncate(self.path, cut)
        except OSError as error:
            raise AuditError(f"audit log {self.path}: {error.strerror}") from None
        return shorter, len(data) - cut

    def _acquire_lock(self):
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            lock = self.path.open("a")  # creates an empty log: still a fresh one
        except OSError as error:
            raise AuditError(f"audit log {self.path}: {error.strerror}") from None
        try:
            import fcntl
        except ImportError:  # not POSIX: no lock
            return lock
        try:
            fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            lock.close()
            raise AuditError(f"audit log {self.path}: in use by another pimbot process") from None
        return lock

    def close(self) -> None:
        if self._lock is not None:
            self._lock.close()
            self._lock = None

    def append(self, kind: str, **data: Any) -> dict[str, Any]:
        """Writes one record, then the new signed head; returns the record."""
        body = {
            "v": VERSION,
            "index": self.count,
            "prev": self.last_hash,
            "kind": kind,
            "data": data,
            "key": self.key_id,
        }
        record = {**body, "mac": record_mac(self.key, body)}
        try:
            with self.path.open("a") as f:
                f.write(json.dumps(record, sort_keys=True) + "\n")
            self.count, self.last_hash = self.count + 1, record["mac"]
            head = {"v": VERSION, "records": self.count, "last": self.last_hash}
            head["key"] = self.key_id
            head["mac"] = head_mac(self.key, head)
            write_atomic(head_path(self.path), (json.dumps(head, sort_keys=True) + "\n").encode())
        except OSError as error:
            raise AuditError(f"audit log {self.path}: {error.strerror}") from None
        return record


# --- verifying ---------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class VerifyResult:
    ok: bool
    records: int
    """Records read that form a valid chain from the start."""
    head: str
    """MAC of the last valid record (the log id when none)."""
    first_bad: int | None = None
    """1-based line number of the first bad record (None when ok or when the head is bad)."""
    reason: str = ""
    note: str = ""

    @property
    def message(self) -> str:
        if self.ok:
            note = f"; {self.note}" if self.note else ""
            return f"ok: {self.records} records, keyed (HMAC-SHA256), head {self.head}{note}"
        if self.first_bad is None:
            return self.reason
        return f"record at line {self.first_bad} is bad: {self.reason}"


def _check_record(record: Any, kid: str) -> str:
    """Why a parsed line is not a well-formed keyed record ("" when it is)."""
    if isinstance(record, dict) and set(record) == UNKEYED_FIELDS:
        return (
            "unkeyed record (a plain SHA-256 `hash`, the old format): anyone who can edit "
            "the file can recompute it, so it is refused as not tamper-evident"
        )
    if not isinstance(record, dict) or set(record) != RECORD_FIELDS:
        return "not an audit record (fields v, index, prev, kind, data, key, mac)"
    if record["v"] != VERSION or isinstance(record["v"], bool):
        return f"format version {record['v']!r}, expected {VERSION}"
    if type(record["index"]) is not int:
        return "index is not an integer"
    if not isinstance(record["kind"], str) or not isinstance(record["key"], str):
        return "kind or key is not a string"
    for field in ("prev", "mac"):
        if not isinstance(record[field], str) or not _HEX64.match(record[field]):
            return f"{field} is not 64 hex digits"
    if record["key"] != kid:
        return (
            f"signed with another key (key id {record['key'][:16]!r}, this key's is {kid}): "
            "the wrong key file, a record re-signed by someone else, or its key id edited"
        )
    return ""


def verify(
    path: str | Path, key: bytes, head: str | None = None, *, data: bytes | None = None
) -> VerifyResult:
    """Checks every record's MAC, index and chain, then the signed head; names the first bad.

    Args:
        key: the log's key (`load_key`).
        head: a record MAC recorded elsewhere (printed by `pimbot train --audit-log`); the
            log must contain it. Without it the signed `LOG.head` must be there.
        data: the log's bytes, if not to be read from `path` (whose head is used).

    Raises:
        AuditError: the log cannot be read (missing, a directory, no permission).
    """
    path = Path(path)
    kid = key_id(key)
    chain = _check_chain(_log_lines(path, data), key, kid)
    if isinstance(chain, VerifyResult):
        return chain
    return _check_end(path, key, kid, chain, head)


def _log_lines(path: Path, data: bytes | None) -> list[bytes]:
    """The log's lines (`data`'s, or the file's), without the final newline's empty one."""
    try:
        data = path.read_bytes() if data is None else data
    except OSError as error:
        raise AuditError(f"audit log {path}: {error.strerror}") from None
    lines = data.split(b"\n")
    if lines[-1] == b"":
        lines.pop()
    return lines


def _check_chain(lines: list[bytes], key: bytes, kid: str) -> list[str] | VerifyResult:
    """The records' MACs in order, each record checked (well-formed, its MAC, written as
    the writer writes it, its index and its link to the previous one); or the first bad
    record's result."""
    prev, macs = "", []
    for number, raw in enumerate(lines, start=1):
        record, problem = _parse_line(raw, last=number == len(lines))
        problem = (
            problem
            or _check_record(record, kid)
            or _check_mac(record, raw, key)
            or _check_link(record, len(macs), prev)
        )
        if problem:
            return VerifyResult(False, len(macs), prev, number, problem)
        prev = record["mac"]
        macs.append(prev)
    if not macs:
        return VerifyResult(False, 0, prev, 1, "the log is empty (no records)")
    return macs


def _parse_line(raw: bytes, last: bool) -> tuple[Any, str]:
    """(the line's JSON value, "") or (None, why it is not JSON)."""
    try:
        return json.loads(raw.decode("utf-8")), ""
    except UnicodeDecodeError:
        return None, "not UTF-8 text (a binary file?)"
    except (ValueError, RecursionError):
        return None, "not valid JSON" + (" (a partial last line)" if last else "")


def _check_mac(record: dict, raw: bytes, key: bytes) -> str:
    """Why a well-formed record's MAC or bytes are not the writer's ("" when they are)."""
    body = {k: v for k, v in record.items() if k != "mac"}
    try:
        expected = record_mac(key, body)
    except (ValueError, RecursionError):
        return "data cannot be encoded canonically"
    if not hmac.compare_digest(expected, record["mac"]):
        return "MAC does not match the record (edited, or forged without the key)"
    if raw != json.dumps(record, sort_keys=True).encode():
        return "not written as the writer writes it (bytes edited: spacing, escapes)"
    return ""


def _check_link(record: dict, count: int, prev: str) -> str:
    """Why a record is not the chain's next after `count` records ending in MAC `prev`."""
    if record["index"] != count:
        return f"index {record['index']}, expected {count} (deleted, inserted or moved)"
    if count and record["prev"] != prev:
        return "prev does not match the previous record's MAC (chain broken)"
    return ""


def _check_end(path: Path, key: bytes, kid: str, macs: list[str], head: str | None):
    """The result of a log whose records all verify (MACs `macs`): whether it ends where
    it should (it contains `head`, if given; its signed head file agrees)."""
    count, prev = len(macs), macs[-1]
    notes = []
    if head is not None:
        if head not in macs:
            return VerifyResult(
                False,
                count,
                prev,
                count + 1,
                f"the log does not contain the head given ({head[:12]}…): records removed or "
                "replaced at the end, or another log",
            )
        notes.append(f"contains the head given at record {macs.index(head)}")
    checked = _check_head(path, key, kid, macs)
    if isinstance(checked, VerifyResult):
        return checked
    if checked is None:
        if head is None:
            return VerifyResult(
                False,
                count,
                prev,
                None,
                f"head file {head_path(path)} is missing: records removed from the end cannot "
                "be ruled out (give --head TAG, printed when the log was written)",
            )
        notes.append("no head file")
    elif checked < count:
        notes.append(
            f"{count - checked} records after the signed head (the writer stopped between a "
            "record and its head; their MACs verify)"
        )
    return VerifyResult(True, count, prev, note="; ".join(notes))


def _check_head(path: Path, key: bytes, kid: str, macs: list[str]) -> int | VerifyResult | None:
    """The signed head's record count, why the head is bad, or None when there is none."""
    count, prev = len(macs), macs[-1]
    where = head_path(path)

    def bad(reason: str, first_bad: int | None = None) -> VerifyResult:
        return VerifyResult(False, count, prev, first_bad, reason)

    if not where.exists():
        return None
    try:
        saved = json.loads(where.read_bytes().decode("utf-8"))
    except OSError as error:
        return bad(f"head file {where}: {error.strerror}")
    except (UnicodeDecodeError, ValueError, RecursionError):
        return bad(f"head file {where} is not JSON")
    if (
        not isinstance(saved, dict)
        or set(saved) != HEAD_FIELDS
        or type(saved["records"]) is not int
        or saved["records"] < 1
        or not all(isinstance(saved[f], str) and _HEX64.match(saved[f]) for f in ("last", "mac"))
    ):
        return bad(f"head file {where} is not a signed head (fields v, records, last, key, mac)")
    if saved["key"] != kid:
        return bad(f"head file {where} is signed with another key")
    body = {k: v for k, v in saved.items() if k != "mac"}
    if not hmac.compare_digest(head_mac(key, body), saved["mac"]):
        return bad(f"head file {where}: MAC does not match (edited, or forged without the key)")
    records = saved["records"]
    if records > count:
        return bad(
            f"the log ends after {count} records, but its signed head expects {records} "
            "(records removed at the end)",
            count + 1,
        )
    if macs[records - 1] != saved["last"]:
        return bad(f"record {records - 1} does not match the signed head (replaced)", records)
    return records
