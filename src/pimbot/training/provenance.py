"""The code a run was made with, checked wherever a run is read again to go on with it.

A run's config.json records the code that made it: `pimbot_version` and each plugin's file
and sha256 (`plugins.provenance`). `changes` lists how the code of this process differs:
another pimbot version, a plugin file whose bytes changed since, a recorded plugin not
loaded now. `check` is the one check every command that goes on with a run makes before
anything runs: a resume (`pimbot train`, the same command or `--from`, and a sweep's jobs:
`runner.check`, `sweep.plan`), a rerun of a saved run into a new directory (`train --from`)
and an export (`robot.export.export_run`). Any change is refused in one line naming it and
the flag, `--accept-changed-code`; with the flag, the run's writer (holding its lock)
records the change in config.json (`record`: "provenance_changes", then the code now), so
the run says which of its iterations each code made. An export records it in its own
policy.json instead: readers never change a run directory, which may be training.

The report reads runs made by other code as they are, never refusing: its provenance table
names each pimbot version and plugin digest with the runs that recorded it, and
`differences` gives, per run, how the report's code differs from the run's (docs/usage.md,
"Provenance: the code a run was made with").
"""

from __future__ import annotations

import datetime
from pathlib import Path
from typing import Any

from pimbot import plugins
from pimbot.errors import InvalidParameter
from pimbot.training import store

FLAG = "--accept-changed-code"
"""The option that lets a command go on with a run made by other code (recorded)."""
CHANGES = "provenance_changes"
"""config.json's list of accepted changes: {"at", "changes", "before", "after"} each."""


class CodeChanged(InvalidParameter):
    """A run made by other code than this process's (another pimbot, a changed plugin)."""


def version() -> str:
    import pimbot

    return pimbot.__version__


def current() -> dict[str, Any]:
    """What config.json records of this process's code."""
    return {"pimbot_version": version(), "plugins": plugins.provenance()}


def changes(config: dict[str, Any]) -> list[str]:
    """How this process's code differs from what `config` (a run's config.json) recorded,
    one phrase each; empty where it does not (or where nothing was recorded: a run made
    before pimbot recorded it)."""
    found = []
    made_by = config.get("pimbot_version")
    if isinstance(made_by, str) and made_by != version():
        found.append(f"pimbot {made_by} (this is pimbot {version()})")
    recorded = config.get("plugins")
    now = plugins.provenance()
    by_file = {r["file"]: r["sha256"] for r in now if r.get("file")}
    digests = {r["sha256"] for r in now if r.get("sha256")}
    for record in recorded if isinstance(recorded, list) else []:
        if not isinstance(record, dict):
            continue
        file, digest = record.get("file"), record.get("sha256")
        if digest and digest in digests:
            continue  # the same code, maybe from another path
        name = str(file or record.get("plugin") or "?")
        if file and file in by_file:
            now_digest = by_file[file] or "unreadable"
            then = (digest or "not recorded")[:12]
            found.append(f"plugin {name} at sha256 {then}… (it is {now_digest[:12]}… now)")
        elif digest or file:
            found.append(f"plugin {name} ({plugins._file_state(file, digest)}; not loaded now)")
    return found


def unloaded_plugins(config: dict[str, Any]) -> list[str]:
    """The files of the plugins `config` recorded that this process has not loaded (by
    path or by the same code elsewhere), as they were recorded."""
    now = plugins.provenance()
    files = {r.get("file") for r in now}
    digests = {r.get("sha256") for r in now if r.get("sha256")}
    recorded = config.get("plugins")
    return [
        str(r["file"])
        for r in (recorded if isinstance(recorded, list) else [])
        if isinstance(r, dict)
        and r.get("file")
        and r["file"] not in files
        and r.get("sha256") not in digests
    ]


def check(run_dir: Path, accept: bool, doing: str = "resume") -> list[str]:
    """Refuses (CodeChanged, one line) to `doing` a run whose config.json records other
    code than this process's, unless `accept`; returns the changes (empty: the same code).
    Reads only; the writer records accepted changes (`record`)."""
    path = Path(run_dir) / store.CONFIG
    if not path.is_file():
        return []
    config = store.read_json(path)
    found = changes(config)
    missing = unloaded_plugins(config)
    if missing and not accept:  # a plugin the run was made with and this process lacks
        hint = " ".join(f"--plugin {file}" for file in missing)
        raise CodeChanged(
            f"{path}: the run was made with plugin(s) not loaded now; add {hint} to "
            f"{doing} it (or {FLAG} to go on without them)"
        )
    if found and not accept:
        raise CodeChanged(
            f"{path}: the run was made with {'; '.join(found)}; {doing} it with the code it "
            f"was made with, or add {FLAG} to go on with this code (recorded in config.json)"
        )
    return found


def record(run_dir: Path, found: list[str]) -> None:
    """Writes accepted `found` changes into the run's config.json: appended to
    "provenance_changes" (when, what, the code before and after), then the code now as the
    run's `pimbot_version` and `plugins`. Only the run's writer calls this, holding its
    lock (`store.locked`)."""
    if not found:
        return
    path = Path(run_dir) / store.CONFIG
    config = store.read_json(path)
    now = current()
    entry = {
        "at": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "changes": found,
        "before": {key: config.get(key) for key in now},
        "after": now,
    }
    history = config.get(CHANGES)
    config[CHANGES] = [*(history if isinstance(history, list) else []), entry]
    config.update(now)
    store.write_json(path, config)


def differences(config: dict[str, Any]) -> list[str]:
    """`changes` for a reader that goes on regardless (the report): how this code differs
    from the run's, and the changes the run accepted while it was made."""
    found = changes(config)
    history = config.get(CHANGES)
    for entry in history if isinstance(history, list) else []:
        if isinstance(entry, dict) and isinstance(entry.get("changes"), list):
            found += [f"accepted at {entry.get('at')}: {c}" for c in entry["changes"]]
    return found
