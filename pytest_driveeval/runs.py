"""Every session keeps its own results: a run folder per session, and a history.

    driveeval-results/
      summary.json, summary.md    the last session to finish (a copy of its own)
      history.jsonl               one line per finished session, oldest first
      runs/<run id>/
        run.json                  who ran it and its state: running, then finished
        summary.json, summary.md  this session's records
        items/<item>/             this session's artefacts

A run id is unique (start time and random bits), so concurrent sessions never
write the same file, and a killed one leaves its folder marked ``running``
beside the results of the others.  Artefact paths in every summary are
relative to the output folder.  Old runs are pruned file by file from their
manifest, so nothing the plugin did not write is ever deleted.
"""
from __future__ import annotations

import datetime as dt
import json
import os
import secrets
import socket
import subprocess
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from .atomic import create_exclusive, write_json_atomic

RUNS_FOLDER = "runs"
RUN_FILE = "run.json"
HISTORY_NAME = "history.jsonl"
DEFAULT_KEEP_RUNS = 20


@dataclass(frozen=True)
class RunIdentity:
    id: str
    started: str  # ISO 8601, UTC
    commit: str | None = None
    dirty: bool | None = None
    host: str = ""
    pid: int = 0

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


def _git(root: Path, *args: str) -> str | None:
    try:
        done = subprocess.run(["git", "-C", str(root), *args], capture_output=True, text=True, timeout=5)
    except (OSError, subprocess.SubprocessError):
        return None
    return done.stdout if done.returncode == 0 else None


def new_identity(root: Path) -> RunIdentity:
    now = dt.datetime.now(dt.timezone.utc)
    commit = _git(root, "rev-parse", "HEAD")
    status = _git(root, "status", "--porcelain", "--untracked-files=no") if commit else None
    return RunIdentity(
        # Sortable by start time; the random part keeps two sessions started
        # in the same millisecond apart.
        id=f"{now:%Y%m%dT%H%M%S}.{now.microsecond // 1000:03d}Z-{secrets.token_hex(3)}",
        started=now.isoformat(timespec="seconds"),
        commit=commit.strip() if commit else None,
        dirty=bool(status.strip()) if status is not None else None,
        host=socket.gethostname(),
        pid=os.getpid(),
    )


def run_dir(output_dir: Path, run_id: str) -> Path:
    return output_dir / RUNS_FOLDER / run_id


def start_run(output_dir: Path, identity: RunIdentity) -> Path:
    """The session's run folder, marked as ours and ``running``; any process of
    the session may call this, the first one writes the mark."""
    folder = run_dir(output_dir, identity.id)
    marker = folder / RUN_FILE
    if not marker.exists():
        create_exclusive(marker, json.dumps({"run": identity.to_json(), "state": "running"}, indent=2) + "\n")
    return folder


def _files_under(folder: Path) -> list[str]:
    return sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*") if p.is_file())


def finish_run(output_dir: Path, identity: RunIdentity, summary: dict[str, Any], keep: int) -> None:
    """Write the session's summary into its run folder, make it the latest,
    add it to the history and prune runs beyond the ``keep`` newest."""
    from .report.summary import write_summary

    folder = start_run(output_dir, identity)
    write_summary(folder, summary, step_summary=False)
    finished = dt.datetime.now(dt.timezone.utc).isoformat(timespec="seconds")
    write_json_atomic(folder / RUN_FILE, {
        "run": identity.to_json(), "state": "finished", "finished": finished,
        "exit_status": summary["exit_status"], "counts": summary["counts"],
        # What this session wrote: pruning deletes these and nothing else.
        "files": _files_under(folder),
    })
    write_summary(output_dir, summary)
    line = {"run": identity.to_json(), "finished": finished, "exit_status": summary["exit_status"],
            "counts": summary["counts"], "summary": f"{RUNS_FOLDER}/{identity.id}/summary.json"}
    _append_line(output_dir / HISTORY_NAME, json.dumps(line, sort_keys=True))
    if keep > 0:
        prune_runs(output_dir, keep, current=identity.id)


def _append_line(path: Path, line: str) -> None:
    # One write of a whole line on an O_APPEND descriptor: concurrent sessions
    # add lines, they never interleave or overwrite one another's.
    fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o666)
    try:
        os.write(fd, (line + "\n").encode("utf-8"))
    finally:
        os.close(fd)


def read_run(folder: Path) -> dict[str, Any] | None:
    try:
        data = json.loads((folder / RUN_FILE).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) and isinstance(data.get("run"), dict) else None


def prune_runs(output_dir: Path, keep: int, current: str) -> list[str]:
    """Remove finished runs beyond the ``keep`` newest; running or killed runs
    and files not in a run's manifest stay.  Returns the pruned run ids."""
    root = output_dir / RUNS_FOLDER
    finished = []
    for folder in sorted(root.iterdir() if root.is_dir() else (), key=lambda p: p.name):
        data = read_run(folder)
        if folder.name != current and data is not None and data.get("state") == "finished":
            finished.append((folder, data))
    pruned = []
    for folder, data in finished[: max(0, len(finished) + 1 - keep)]:
        for name in [*data.get("files", []), RUN_FILE]:
            target = (folder / name)
            if target.resolve().is_relative_to(folder.resolve()):  # a manifest cannot point outside
                target.unlink(missing_ok=True)
        for sub in sorted((p for p in folder.rglob("*") if p.is_dir()), key=lambda p: -len(p.parts)):
            _rmdir_if_empty(sub)
        _rmdir_if_empty(folder)
        pruned.append(folder.name)
    return pruned


def _rmdir_if_empty(folder: Path) -> None:
    try:
        folder.rmdir()
    except OSError:
        pass  # not empty: something we did not write is there
