"""Deployment-layer defenses: the authenticated incentive channel and the keyed audit log."""

import dataclasses
import hashlib
import hmac
import json
import math
import os

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from pimbot import cli
from pimbot.defenses import audit, channel

# --- authenticated channel ---------------------------------------------------------------


def _pair(window=64, state_path=None):
    keys = channel.KeyRing.generate(3)
    return channel.Sender(0, keys), channel.Receiver(1, keys, window, state_path), keys


def test_honest_messages_are_accepted_in_order():
    sender, receiver, _ = _pair()
    for episode in range(3):
        for step in range(5):
            verdict = receiver.receive(sender.send(1, episode, step, 0.25 * step))
            assert verdict == channel.Verdict(True, "ok")


def test_forged_message_without_the_key_is_rejected():
    _, receiver, _ = _pair()
    forged = channel.sign(channel.IncentiveMessage(0, 1, 0, 0, 0, 50.0), b"\0" * 32)
    assert receiver.receive(forged) == channel.Verdict(False, "bad tag")
    untagged = channel.IncentiveMessage(0, 1, 0, 0, 0, 50.0)
    assert not receiver.receive(untagged).accepted


def test_a_key_of_another_pair_does_not_verify():
    _, receiver, keys = _pair()
    other = channel.sign(channel.IncentiveMessage(0, 1, 0, 0, 0, 1.0), keys.key(2, 1))
    assert receiver.receive(other).reason == "bad tag"


@pytest.mark.parametrize(
    "key, expected",
    [(b"", "0 bytes; at least 16"), (b"k" * 15, "15 bytes"), ("k" * 32, "must be bytes")],
)
def test_empty_short_or_text_keys_are_refused_in_one_line(key, expected):
    with pytest.raises(ValueError, match=expected) as error:
        channel.KeyRing({(0, 1): key})
    assert "\n" not in str(error.value)
    with pytest.raises(ValueError, match=expected):
        channel.sign(channel.IncentiveMessage(0, 1, 0, 0, 0, 1.0), key)


@settings(max_examples=40, deadline=None)
@given(
    field=st.sampled_from(["giver", "recipient", "episode", "step", "sequence", "value"]),
    delta=st.integers(1, 1000),
)
def test_every_altered_field_is_rejected(field, delta):
    sender, receiver, _ = _pair()
    message = sender.send(1, 2, 3, 1.5)
    altered = dataclasses.replace(message, **{field: getattr(message, field) + delta})
    verdict = receiver.receive(altered)
    assert not verdict.accepted
    assert receiver.receive(message).accepted  # the original still verifies afterwards


MALFORMED_TAGS = {
    "empty": "",
    "short": "ab" * 31,
    "long": "ab" * 33,
    "non-hex": "g" * 64,
    "upper-case hex": "AB" * 32,
    "non-ASCII": "é" * 64,
    "trailing newline": "ab" * 32 + "\n",
    "None": None,
    "raw bytes": b"\x01" * 32,
    "hex bytes": b"ab" * 32,
    "int": 12345,
}


@pytest.mark.parametrize("tag", MALFORMED_TAGS.values(), ids=MALFORMED_TAGS.keys())
def test_malformed_tags_are_rejected_not_raised(tag):
    sender, receiver, _ = _pair()
    message = sender.send(1, 0, 0, 1.0)
    verdict = receiver.receive(dataclasses.replace(message, tag=tag))
    assert verdict == channel.Verdict(False, "malformed tag: not 64 lowercase hex digits")
    assert receiver.receive(message).accepted


MALFORMED_FIELDS = [
    ("giver", "0"),
    ("giver", None),
    ("giver", [0]),  # unhashable
    ("recipient", 1.0),
    ("step", True),
    ("sequence", -1),
    ("episode", 2**70 * 1.0),
    ("value", "1.0"),
    ("value", math.nan),
    ("value", math.inf),
    ("value", None),
]


@pytest.mark.parametrize("field, value", MALFORMED_FIELDS)
def test_malformed_fields_are_rejected_not_raised(field, value):
    sender, receiver, _ = _pair()
    message = sender.send(1, 0, 0, 1.0)
    verdict = receiver.receive(dataclasses.replace(message, **{field: value}))
    assert not verdict.accepted and verdict.reason.startswith("malformed message: " + field)
    assert receiver.receive(message).accepted
    assert not receiver.receive("not a message").accepted


ANYTHING = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(-(2**70), 2**70),
    st.floats(),
    st.text(max_size=70),
    st.binary(max_size=70),
    st.lists(st.integers(), max_size=2),
)


@settings(max_examples=150, deadline=None)
@given(
    fields=st.fixed_dictionaries(
        {}, optional=dict.fromkeys([*channel.INT_FIELDS, "value", "tag"], ANYTHING)
    )
)
def test_receive_never_raises_on_arbitrary_fields(fields):
    sender, receiver, _ = _pair()
    original = sender.send(1, 0, 0, 1.0)
    message = dataclasses.replace(original, **fields)
    verdict = receiver.receive(message)
    assert isinstance(verdict, channel.Verdict) and isinstance(verdict.reason, str)
    if verdict.accepted:  # only if nothing that the tag covers was changed
        assert message.payload() == original.payload() and message.tag == original.tag


def test_replayed_message_is_rejected():
    sender, receiver, _ = _pair()
    first = sender.send(1, 0, 0, 1.0)
    assert receiver.receive(first).accepted
    assert receiver.receive(first) == channel.Verdict(False, "replay: sequence already received")


def test_replay_older_than_the_window_is_rejected():
    sender, receiver, _ = _pair(window=4)
    old = sender.send(1, 0, 0, 1.0)
    assert receiver.receive(old).accepted
    for step in range(1, 10):
        assert receiver.receive(sender.send(1, 0, step, 1.0)).accepted
    assert receiver.receive(old).reason == "replay: sequence older than the window"


def test_reordered_messages_are_rejected():
    sender, receiver, _ = _pair()
    early = sender.send(1, 0, 1, 1.0)
    late = sender.send(1, 0, 2, 1.0)
    assert receiver.receive(late).accepted
    verdict = receiver.receive(early)  # new sequence number, but an earlier step
    assert verdict == channel.Verdict(False, "out of order: not after the last accepted step")


def test_message_for_someone_else_is_rejected():
    sender, receiver, _ = _pair()
    assert receiver.receive(sender.send(2, 0, 0, 1.0)).reason == "wrong recipient"


def test_replay_after_a_restart_what_is_and_is_not_protected(tmp_path):
    """The boundary of the module docstring, case by case."""
    state = tmp_path / "receiver-1.json"
    sender, receiver, keys = _pair(window=4, state_path=state)
    sent = [sender.send(1, 0, step, 1.0) for step in range(8)]
    assert all(receiver.receive(m).accepted for m in sent[:3])
    snapshot = state.read_bytes()
    assert all(receiver.receive(m).accepted for m in sent[3:6])

    # In memory only: a restarted receiver has forgotten everything.
    assert channel.Receiver(1, keys, window=4).receive(sent[4]).accepted
    # With its state file: replays inside and beyond the window and reordering stay rejected.
    restarted = channel.Receiver(1, keys, window=4, state_path=state)
    assert restarted.receive(sent[4]).reason == "replay: sequence already received"
    assert restarted.receive(sent[0]).reason == "replay: sequence older than the window"
    assert restarted.receive(sent[6]).accepted  # and new messages go through
    # A restarted sender continues its numbering.
    resumed = channel.Sender(0, keys, next_sequence=sender.next_sequence)
    assert restarted.receive(resumed.send(1, 1, 0, 1.0)).accepted
    assert channel.Receiver(1, keys, 4, state).receive(resumed.send(1, 1, 1, 1.0)).accepted

    # Not protected: an older copy of the state file put back reopens later messages.
    state.write_bytes(snapshot)
    rolled_back = channel.Receiver(1, keys, window=4, state_path=state)
    assert rolled_back.receive(sent[4]).accepted
    assert rolled_back.receive(sent[2]).reason == "replay: sequence already received"


@pytest.mark.parametrize(
    "corrupt, expected",
    [
        (lambda s: s.replace('"highest": 2', '"highest": -1'), "bad entry for giver '0'"),
        (lambda s: s.replace('"seen": [0, 1, 2]', '"seen": []'), "bad entry for giver '0'"),
        (lambda s: s[: len(s) // 2], "is not JSON"),
        (lambda s: "\udcff" + s, "is not JSON"),
        (lambda s: "[]", "is not a receiver state"),
        (lambda s: s.replace('"0"', '"7"'), "bad entry for giver '7'"),
    ],
    ids=["highest", "seen", "truncated", "binary", "not a state", "unknown giver"],
)
def test_an_edited_or_broken_state_file_refuses_to_start(tmp_path, corrupt, expected):
    state = tmp_path / "receiver-1.json"
    sender, receiver, keys = _pair(state_path=state)
    for step in range(3):
        assert receiver.receive(sender.send(1, 0, step, 1.0)).accepted
    text = json.dumps(json.loads(state.read_text()), sort_keys=True)
    state.write_bytes(corrupt(text).encode("utf-8", "surrogateescape"))
    with pytest.raises(ValueError, match=expected) as error:
        channel.Receiver(1, keys, state_path=state)
    assert "refusing to start" in str(error.value) and "\n" not in str(error.value)


# --- audit log ---------------------------------------------------------------------------

KEY = bytes(range(32))
OTHER_KEY = bytes(range(1, 33))


def _write_log(path, n, key=KEY):
    log = audit.AuditLog(path, key)
    for k in range(n):
        log.append("update", iteration=100 * k, policy_sha256=[f"{k:064x}"], incentive=[0.5 * k])
    log.close()
    return log


def _lines(path):
    return path.read_text().splitlines(keepends=True)


def _signed(key, index, prev, data, kind="update"):
    body = {"v": 2, "index": index, "prev": prev, "kind": kind, "data": data}
    body["key"] = audit.key_id(key)
    return json.dumps({**body, "mac": audit.record_mac(key, body)}, sort_keys=True) + "\n"


def _rechain(lines, key):
    """Every record re-signed under `key` (an attacker's), and a head to match."""
    out, prev = [], "f" * 64
    for index, line in enumerate(lines):
        out.append(_signed(key, index, prev, json.loads(line)["data"]))
        prev = json.loads(out[-1])["mac"]
    return out, prev


def _rechain_sha256(lines):
    """The old unkeyed format: a plain SHA-256 chain anyone can recompute."""
    out, prev = [], "0" * 64
    for index, line in enumerate(lines):
        body = {"index": index, "prev": prev, "kind": "update", "data": json.loads(line)["data"]}
        canonical = json.dumps(body, sort_keys=True, separators=(",", ":"))
        body["hash"] = hashlib.sha256(canonical.encode()).hexdigest()
        out.append(json.dumps(body, sort_keys=True) + "\n")
        prev = body["hash"]
    return out


def test_honest_log_verifies_and_continues(tmp_path):
    path = tmp_path / "audit.jsonl"
    log = _write_log(path, 4)
    result = audit.verify(path, KEY)
    assert result.ok and result.records == 4 and result.head == log.last_hash
    more = audit.AuditLog(path, KEY)  # reopening continues the chain
    more.append("end", done=True)
    more.close()
    assert audit.verify(path, KEY).records == 5
    assert audit.verify(path, KEY, head=more.last_hash).ok
    assert audit.verify(path, KEY, head=log.last_hash).ok  # an earlier head: still contained


def _tamper(path, lines, tamper, k):
    """Applies one tamper to a log of len(lines) records; returns the expected first bad line
    (None: the head file is named) and a word of the reason."""
    n = len(lines)
    if tamper == "edit data":
        record = json.loads(lines[k])
        record["data"]["iteration"] += 1
        lines[k] = json.dumps(record, sort_keys=True) + "\n"
        expected = (k + 1, "MAC does not match")
    elif tamper == "edit mac":
        record = json.loads(lines[k])
        record["mac"] = hashlib.sha256(b"forged").hexdigest()
        lines[k] = json.dumps(record, sort_keys=True) + "\n"
        expected = (k + 1, "MAC does not match")
    elif tamper == "edit spacing":
        lines[k] = lines[k].replace(": ", ":", 1)
        expected = (k + 1, "bytes edited")
    elif tamper == "delete":
        del lines[k]
        end = "records removed at the end" if k else "empty"
        expected = (k + 1, "index" if k < n - 1 else end)
    elif tamper == "insert forged":  # signed with a key the writer does not hold
        lines.insert(k, _signed(OTHER_KEY, k, json.loads(lines[k])["prev"], {"iteration": 7}))
        expected = (k + 1, "another key")
    elif tamper == "insert copy":  # a genuine record, duplicated
        lines.insert(k, lines[k])
        expected = (k + 2, "index")
    elif tamper == "reorder":
        j = k + 1 if k + 1 < n else k - 1
        if j < 0:
            return None
        lo = min(k, j)
        lines[k], lines[j] = lines[j], lines[k]
        expected = (lo + 1, "index")
    elif tamper == "truncate end":
        del lines[k:]
        expected = (k + 1, "records removed at the end") if k else (1, "empty")
    elif tamper == "partial last line":
        lines[k] = lines[k][: len(lines[k]) // 2]
        del lines[k + 1 :]
        expected = (k + 1, "not valid JSON")
    elif tamper == "re-chain sha256":
        lines[:] = _rechain_sha256(lines)
        expected = (1, "unkeyed")
    elif tamper == "re-chain hmac":  # re-signed with the attacker's own key, head too
        lines[:], last = _rechain(lines, OTHER_KEY)
        head = {"v": 2, "records": n, "last": last, "key": audit.key_id(OTHER_KEY)}
        head["mac"] = audit.head_mac(OTHER_KEY, head)
        audit.head_path(path).write_text(json.dumps(head) + "\n")
        expected = (1, "another key")
    elif tamper == "forge head":  # claims fewer records (so a cut tail would pass), or more
        head = json.loads(audit.head_path(path).read_text())
        if k + 1 < n:
            head["records"], head["last"] = k + 1, json.loads(lines[k])["mac"]
            del lines[k + 1 :]
        else:
            head["records"] += 1
        audit.head_path(path).write_text(json.dumps(head) + "\n")
        expected = (None, "MAC does not match")
    elif tamper == "delete head":
        audit.head_path(path).unlink()
        expected = (None, "missing")
    elif tamper == "head of another log":
        other = path.with_name("other.jsonl")
        _write_log(other, n)
        audit.head_path(path).write_bytes(audit.head_path(other).read_bytes())
        expected = (n, "does not match the signed head")
    else:
        raise AssertionError(tamper)
    path.write_text("".join(lines))
    return expected


TAMPERS = [
    "edit data",
    "edit mac",
    "edit spacing",
    "delete",
    "insert forged",
    "insert copy",
    "reorder",
    "truncate end",
    "partial last line",
    "re-chain sha256",
    "re-chain hmac",
    "forge head",
    "delete head",
    "head of another log",
]


@pytest.mark.parametrize("tamper", TAMPERS)
@pytest.mark.parametrize("n, where", [(1, 0), (4, 0), (4, 2), (4, 3)])
def test_every_tamper_is_detected_and_the_first_bad_record_named(tmp_path, tamper, n, where):
    path = tmp_path / "audit.jsonl"
    _write_log(path, n)
    expected = _tamper(path, _lines(path), tamper, where)
    if expected is None:
        return  # reordering needs two records
    first_bad, word = expected
    result = audit.verify(path, KEY)
    assert not result.ok
    assert (result.first_bad, word in result.message) == (first_bad, True), result.message
    if first_bad is None:
        assert str(audit.head_path(path)) in result.message
    else:
        assert result.message.startswith(f"record at line {first_bad} is bad: ")
    with pytest.raises(audit.AuditError, match="fails verification"):
        audit.AuditLog(path, KEY)  # a writer never continues a tampered log


@settings(
    max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(data=st.data())
def test_any_single_byte_change_is_caught_at_its_line(tmp_path, data):
    path = tmp_path / "audit.jsonl"
    if not path.exists():
        _write_log(path, 3)
    original = path.read_bytes()
    position = data.draw(st.integers(0, len(original) - 1))
    byte = data.draw(st.integers(0, 255).filter(lambda b: b != original[position]))
    changed = original[:position] + bytes([byte]) + original[position + 1 :]
    tampered = tmp_path / "tampered.jsonl"
    tampered.write_bytes(changed)
    audit.head_path(tampered).write_bytes(audit.head_path(path).read_bytes())
    result = audit.verify(tampered, KEY)
    line = original[:position].count(b"\n") + 1
    assert not result.ok and result.first_bad == min(line, 3), result.message


def test_wrong_key_names_the_first_record(tmp_path):
    path = tmp_path / "audit.jsonl"
    _write_log(path, 3)
    result = audit.verify(path, OTHER_KEY)
    assert result.first_bad == 1 and "signed with another key" in result.reason


def test_rollback_to_an_older_copy_is_caught_only_against_a_head_kept_elsewhere(tmp_path):
    path = tmp_path / "audit.jsonl"
    _write_log(path, 2)
    old_log, old_head = path.read_bytes(), audit.head_path(path).read_bytes()
    log = audit.AuditLog(path, KEY)
    log.append("update", iteration=200)
    log.close()
    path.write_bytes(old_log)
    audit.head_path(path).write_bytes(old_head)
    assert audit.verify(path, KEY).ok  # the boundary: a state that once existed
    result = audit.verify(path, KEY, head=log.last_hash)
    assert not result.ok and result.first_bad == 3 and "head given" in result.reason


def test_records_after_the_signed_head_verify_with_a_note(tmp_path):
    path = tmp_path / "audit.jsonl"
    _write_log(path, 2)
    head = audit.head_path(path).read_bytes()
    log = audit.AuditLog(path, KEY)
    log.append("update", iteration=200)
    log.close()
    audit.head_path(path).write_bytes(head)  # as if the writer died before its head
    result = audit.verify(path, KEY)
    assert result.ok and result.records == 3 and "1 records after the signed head" in result.note


def test_a_writer_killed_mid_record_is_recovered_on_reopening(tmp_path):
    path = tmp_path / "audit.jsonl"
    _write_log(path, 2)
    whole, head = path.read_bytes(), audit.head_path(path).read_bytes()
    log = audit.AuditLog(path, KEY)
    log.append("update", iteration=200)
    log.close()
    partial = path.read_bytes()[: len(whole) + 40]  # killed 40 bytes into record 2
    path.write_bytes(partial)
    audit.head_path(path).write_bytes(head)  # the head is written after a whole record
    assert audit.verify(path, KEY).first_bad == 3  # a reader sees it
    reopened = audit.AuditLog(path, KEY)
    reopened.close()
    result = audit.verify(path, KEY)
    assert result.ok and result.records == 3
    assert json.loads(_lines(path)[2])["data"] == {
        "dropped_bytes": 40,
        "reason": "a partial last line",
    }
    path.write_bytes(partial.replace(b"update", b"UPDATE", 1))  # not only a partial line
    with pytest.raises(audit.AuditError, match="line 1 is bad"):
        audit.AuditLog(path, KEY)


def test_a_second_writer_is_refused(tmp_path):
    path = tmp_path / "audit.jsonl"
    first = audit.AuditLog(path, KEY)
    first.append("run")
    with pytest.raises(audit.AuditError, match="in use by another pimbot process"):
        audit.AuditLog(path, KEY)
    first.close()
    audit.AuditLog(path, KEY).close()


def test_writer_key_is_created_0600_outside_the_log_directory(tmp_path, monkeypatch):
    log = tmp_path / "runs" / "audit.jsonl"
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "config"))
    monkeypatch.delenv(audit.KEY_ENV, raising=False)
    key, where = audit.writer_key(log)
    assert where == tmp_path / "config" / "pimbot" / "audit.key"
    assert os.stat(where).st_mode & 0o777 == 0o600 and len(key) == audit.KEY_BYTES
    assert audit.writer_key(log) == (key, where)  # reused, never overwritten
    monkeypatch.setenv(audit.KEY_ENV, str(tmp_path / "elsewhere.key"))
    assert audit.default_key_path() == tmp_path / "elsewhere.key"
    with pytest.raises(audit.AuditError, match="in the log's own directory"):
        audit.writer_key(log, tmp_path / "runs" / "audit.key")


# --- `pimbot audit verify`: every outcome is one line ----------------------------------


@pytest.fixture
def keyed(tmp_path, monkeypatch):
    """A 3-record log and its key file in a separate directory, named by the environment."""
    key_file = tmp_path / "keys" / "audit.key"
    monkeypatch.setenv(audit.KEY_ENV, str(key_file))
    path = tmp_path / "logs" / "audit.jsonl"
    key, _ = audit.writer_key(path)
    _write_log(path, 3, key)
    return path, key_file, key


def _cli(argv, capsys):
    code = cli.main(argv)
    captured = capsys.readouterr()
    out = (captured.out + captured.err).strip()
    assert "Traceback" not in out and out.count("\n") == 0, out
    return code, out


def test_audit_verify_cli_names_the_first_bad_record(keyed, capsys):
    path, key_file, key = keyed
    assert _cli(["audit", "verify", str(path)], capsys)[0] == 0
    assert _cli(["audit", "verify", str(path), "--audit-key", str(key_file)], capsys)[0] == 0
    lines = _lines(path)
    record = json.loads(lines[1])
    record["data"]["incentive"] = [50.0]
    lines[1] = json.dumps(record, sort_keys=True) + "\n"
    path.write_text("".join(lines))
    code, out = _cli(["audit", "verify", str(path)], capsys)
    assert code == 1 and "record at line 2 is bad" in out and "edited" in out


def _binary(path, key_file):
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(range(256)) * 4)


def _empty(path, key_file):
    path.write_bytes(b"")


def _directory(path, key_file):
    path.unlink()
    path.mkdir()


def _missing(path, key_file):
    path.unlink()


def _unkeyed(path, key_file):
    path.write_text("".join(_rechain_sha256(_lines(path))))


def _no_key(path, key_file):
    key_file.unlink()


def _open_key(path, key_file):
    key_file.chmod(0o644)


def _text_key(path, key_file):
    key_file.write_text("not a key\n")


def _short_key(path, key_file):
    key_file.write_text("abcd\n")


def _deep_json(path, key_file):
    path.write_text("[" * 100_000 + "\n")


def _huge_int(path, key_file):
    path.write_text('{"index": ' + "9" * 10_000 + "}\n")


CLI_CASES = [
    (_binary, 1, "line 1 is bad: not UTF-8"),
    (_empty, 1, "the log is empty"),
    (_deep_json, 1, "line 1 is bad: not valid JSON"),
    (_huge_int, 1, "line 1 is bad: not valid JSON"),
    (_unkeyed, 1, "line 1 is bad: unkeyed record"),
    (_directory, 2, "is not a file"),
    (_missing, 2, "no such file"),
    (_no_key, 2, "audit key"),
    (_open_key, 2, "chmod 600"),
    (_text_key, 2, "not a hex key"),
    (_short_key, 2, "2 bytes, at least 16"),
]


@pytest.mark.parametrize(
    "damage, code, expected", CLI_CASES, ids=[c[0].__name__ for c in CLI_CASES]
)
def test_audit_verify_cli_bad_input_is_one_line(keyed, capsys, damage, code, expected):
    path, key_file, _ = keyed
    damage(path, key_file)
    got, out = _cli(["audit", "verify", str(path)], capsys)
    assert (got, expected in out) == (code, True), out


def test_audit_verify_cli_head_option(keyed, capsys):
    path, _, key = keyed
    head = audit.verify(path, key).head
    assert _cli(["audit", "verify", str(path), "--head", head], capsys)[0] == 0
    code, out = _cli(["audit", "verify", str(path), "--head", "xyz"], capsys)
    assert code == 2 and "64 lowercase hex" in out
    code, out = _cli(["audit", "verify", str(path), "--head", "a" * 64], capsys)
    assert code == 1 and "head given" in out


def test_hmac_is_the_standard_construction():
    """Anyone holding the key can check a record with any HMAC-SHA256 implementation."""
    body = {"v": 2, "index": 0, "prev": "0" * 64, "kind": "run", "data": {}, "key": "k"}
    canonical = json.dumps(body, sort_keys=True, separators=(",", ":")).encode()
    expected = hmac.new(KEY, b"pimbot-audit-record\0" + canonical, hashlib.sha256).hexdigest()
    assert audit.record_mac(KEY, body) == expected
