"""`authenticated_channel`: integrity-protected incentive messages between robots.

Every incentive message carries giver, recipient, episode, step, a per-pair
sequence number and the value, and an HMAC-SHA256 tag under a key shared by that
(giver, recipient) pair only (≥ 16 bytes; `KeyRing.generate` makes 32). A receiver
accepts a message only if

* it is well formed: integer fields ≥ 0, a finite value, a 64-hex-digit tag —
  anything else (None, bytes, wrong length, non-hex, wrong types) is rejected
  ("malformed ..."), never an exception;
* it is addressed to it, from a known giver other than itself;
* the tag verifies (constant-time compare) — forged or altered messages fail;
* its sequence number is new: above the highest seen minus the replay window and
  not seen before inside the window — replays fail;
* its (episode, step) is strictly after the last message accepted from that
  giver — reordered or delayed messages fail.

Restarts, and the boundary. A `Receiver` without `state_path` keeps its replay
state in memory only: after a restart it accepts any old message again. With
`state_path=FILE` it loads its state at start and saves it (atomically, fsynced,
each peer's entry MACed under that pair's key) before accepting each message, so
replays stay rejected across restarts, and a state file that is edited, forged or
unreadable makes it refuse to start rather than forget. Not covered: someone who can
write the receiver's disk can delete the state file or put back an older copy;
messages sent after that copy are then accepted again — keep the file where only
the receiver writes. A restarted `Sender` must continue its sequence numbers
(`next_sequence`), or its new messages are rejected as replays.

Keys come from `secrets`, tags from `hmac`/`hashlib` (standard library only).
"""

from __future__ import annotations

import dataclasses
import hashlib
import hmac
import json
import math
import re
import secrets
from pathlib import Path
from typing import Any

from pimbot.atomic_files import write_atomic

KEY_BYTES = 32
MIN_KEY_BYTES = 16
INT_FIELDS = ("giver", "recipient", "episode", "step", "sequence")
_HEX64 = re.compile(r"[0-9a-f]{64}\Z")
_STATE_DOMAIN = b"pimbot-channel-state\0"


def check_key(key: Any, name: str = "key") -> bytes:
    """`key` if it is bytes of at least MIN_KEY_BYTES; ValueError (one line) otherwise."""
    if not isinstance(key, bytes | bytearray):
        raise ValueError(f"{name}: must be bytes, got {type(key).__name__}")
    if len(key) < MIN_KEY_BYTES:
        raise ValueError(
            f"{name}: {len(key)} bytes; at least {MIN_KEY_BYTES} needed "
            f"(KeyRing.generate makes {KEY_BYTES})"
        )
    return bytes(key)


@dataclasses.dataclass(frozen=True)
class IncentiveMessage:
    """One incentive transfer as sent over the network."""

    giver: int
    recipient: int
    episode: int
    step: int
    sequence: int
    value: float
    tag: str = ""
    """Hex HMAC-SHA256 of the other fields under the pair's key."""

    def payload(self) -> bytes:
        """Canonical bytes of every field but the tag (the fields must be well formed)."""
        fields = {name: int(getattr(self, name)) for name in INT_FIELDS}
        fields["value"] = float(self.value).hex()  # exact, no float formatting ambiguity
        return json.dumps(fields, sort_keys=True, separators=(",", ":")).encode()


def malformed(message: Any) -> str:
    """Why `message` is not a well-formed incentive message ("" when it is)."""
    if not isinstance(message, IncentiveMessage):
        return "malformed message: not an IncentiveMessage"
    for name in INT_FIELDS:
        value = getattr(message, name)
        if type(value) is not int or value < 0:
            return f"malformed message: {name} must be an integer ≥ 0"
    value = message.value
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        return "malformed message: value must be a finite number"
    if not isinstance(message.tag, str) or not _HEX64.match(message.tag):
        return "malformed tag: not 64 lowercase hex digits"
    return ""


@dataclasses.dataclass(frozen=True)
class KeyRing:
    """Per-pair secret keys: keys[(giver, recipient)], one per ordered pair."""

    keys: dict[tuple[int, int], bytes]

    def __post_init__(self):
        for pair, key in self.keys.items():
            check_key(key, f"keys[{pair!r}]")

    @classmethod
    def generate(cls, num_agents: int) -> KeyRing:
        pairs = [(i, j) for i in range(num_agents) for j in range(num_agents) if i != j]
        return cls({pair: secrets.token_bytes(KEY_BYTES) for pair in pairs})

    def key(self, giver: int, recipient: int) -> bytes | None:
        return self.keys.get((giver, recipient))


def sign(message: IncentiveMessage, key: bytes) -> IncentiveMessage:
    """The message with its tag set (ValueError on an empty or short key)."""
    tag = hmac.new(check_key(key), message.payload(), hashlib.sha256).hexdigest()
    return dataclasses.replace(message, tag=tag)


class Sender:
    """One giver's end: numbers and signs its messages, one sequence per recipient.

    `next_sequence` continues the numbering of a restarted sender.
    """

    def __init__(self, giver: int, keyring: KeyRing, next_sequence: dict[int, int] | None = None):
        self.giver = giver
        self.keyring = keyring
        self.next_sequence: dict[int, int] = dict(next_sequence or {})

    def send(self, recipient: int, episode: int, step: int, value: float) -> IncentiveMessage:
        key = self.keyring.key(self.giver, recipient)
        if key is None:
            raise ValueError(f"recipient: no key for pair ({self.giver}, {recipient})")
        if not math.isfinite(value):
            raise ValueError(f"value: must be finite, got {value}")
        sequence = self.next_sequence.get(recipient, 0)
        self.next_sequence[recipient] = sequence + 1
        message = IncentiveMessage(self.giver, recipient, episode, step, sequence, float(value))
        return sign(message, key)


@dataclasses.dataclass(frozen=True)
class Verdict:
    accepted: bool
    reason: str
    """"ok", or why the message was rejected."""


@dataclasses.dataclass
class _PeerState:
    highest: int = -1
    seen: set[int] = dataclasses.field(default_factory=set)
    last_time: tuple[int, int] = (-1, -1)

    def body(self, recipient: int, giver: int) -> dict[str, Any]:
        return {
            "recipient": recipient,
            "giver": giver,
            "highest": self.highest,
            "seen": sorted(self.seen),
            "last_time": list(self.last_time),
        }


def _state_mac(key: bytes, body: dict[str, Any]) -> str:
    canonical = json.dumps(body, sort_keys=True, separators=(",", ":")).encode()
    return hmac.new(key, _STATE_DOMAIN + canonical, hashlib.sha256).hexdigest()


class Receiver:
    """One recipient's end: verifies tags, rejects replays and out-of-order messages.

    With `state_path` the replay state survives restarts (see the module docstring).
    """

    def __init__(
        self,
        recipient: int,
        keyring: KeyRing,
        window: int = 64,
        state_path: str | Path | None = None,
    ):
        if type(window) is not int or window < 1:
            raise ValueError(f"window: must be an integer ≥ 1, got {window}")
        self.recipient = recipient
        self.keyring = keyring
        self.window = window
        self.state_path = Path(state_path) if state_path is not None else None
        self.peers: dict[int, _PeerState] = {}
        if self.state_path is not None and self.state_path.exists():
            self.peers = self._load(self.state_path)

    def receive(self, message: IncentiveMessage) -> Verdict:
        """Checks `message`; on acceptance records it (so a second copy is a replay).

        Never raises: anything wrong with the message is a rejection.
        """
        problem = malformed(message)
        if problem:
            return Verdict(False, problem)
        if message.recipient != self.recipient:
            return Verdict(False, "wrong recipient")
        key = self.keyring.key(message.giver, self.recipient)
        if key is None:
            return Verdict(False, "unknown giver")
        expected = sign(message, key).tag
        if not hmac.compare_digest(expected, message.tag):
            return Verdict(False, "bad tag")
        old = self.peers.get(message.giver, _PeerState())
        if message.sequence <= old.highest - self.window:
            return Verdict(False, "replay: sequence older than the window")
        if message.sequence in old.seen:
            return Verdict(False, "replay: sequence already received")
        if (message.episode, message.step) <= old.last_time:
            return Verdict(False, "out of order: not after the last accepted step")
        highest = max(old.highest, message.sequence)
        seen = {s for s in old.seen | {message.sequence} if s > highest - self.window}
        self.peers[message.giver] = _PeerState(highest, seen, (message.episode, message.step))
        if self.state_path is not None:
            try:
                self._save(self.state_path)
            except OSError as error:
                self.peers[message.giver] = old
                return Verdict(False, f"state not saved ({error.strerror}): not accepted")
        return Verdict(True, "ok")

    def _save(self, path: Path) -> None:
        peers = {}
        for giver, peer in sorted(self.peers.items()):
            body = peer.body(self.recipient, giver)
            peers[str(giver)] = {
                **body,
                "mac": _state_mac(self.keyring.key(giver, self.recipient), body),
            }
        write_atomic(path, json.dumps({"v": 1, "peers": peers}, sort_keys=True).encode())

    def _load(self, path: Path) -> dict[int, _PeerState]:
        def refuse(why: str) -> ValueError:
            return ValueError(
                f"state_path: {path} {why}; refusing to start (replays could be accepted)"
            )

        try:
            saved = json.loads(path.read_bytes().decode("utf-8"))
        except OSError as error:
            raise refuse(f"cannot be read ({error.strerror})") from None
        except (UnicodeDecodeError, ValueError, RecursionError):
            raise refuse("is not JSON") from None
        if (
            not isinstance(saved, dict)
            or saved.get("v") != 1
            or not isinstance(saved.get("peers"), dict)
        ):
            raise refuse("is not a receiver state")
        peers: dict[int, _PeerState] = {}
        for name, entry in saved["peers"].items():
            try:
                giver = int(name)
                body = {k: entry[k] for k in ("recipient", "giver", "highest", "seen", "last_time")}
                key = self.keyring.key(giver, self.recipient)
                valid = (
                    key is not None
                    and set(entry) == {*body, "mac"}
                    and isinstance(entry["mac"], str)
                    and _HEX64.match(entry["mac"]) is not None
                    and hmac.compare_digest(_state_mac(key, body), entry["mac"])
                    and body["recipient"] == self.recipient
                    and body["giver"] == giver
                )
                if valid:
                    e, s = body["last_time"]
                    peer = _PeerState(
                        int(body["highest"]), {int(x) for x in body["seen"]}, (int(e), int(s))
                    )
            except (TypeError, ValueError, KeyError):
                valid = False
            if not valid:
                raise refuse(f"has a bad entry for giver {name!r} (edited or forged)")
            peers[giver] = peer
        return peers
