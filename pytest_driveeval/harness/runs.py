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
manifest, so nothing the plugin did not write is ever deleted, and nothing is
written or deleted through a symbolic link: a link may lead out of the folder.
"""
from __future__ import annotations

import datetime as dt
import fcntl
import json
import os
import secrets
import socket
import stat
import subprocess
from dataclasses import asdict, dataclass
from pathlib import Path, PurePosixPath
from typing import Any, Callable

from ..core.atomic import MAX_BASELINE_BYTES, create_exclusive, finite_json, read_json, write_json_atomic
from ..report.trends import history_entries

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
    # Regular files only: a link someone put here is not ours to delete later.
    return sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*") if p.is_file() and not p.is_symlink())


def _kind(path: Path) -> str | None:
    """What is at ``path`` without following a link: None when nothing."""
    try:
        mode = path.lstat().st_mode
    except (FileNotFoundError, NotADirectoryError):
        return None
    if stat.S_ISLNK(mode):
        return "link"
    return "folder" if stat.S_ISDIR(mode) else "file" if stat.S_ISREG(mode) else "special"


def damaged_entry(output_dir: Path, folders: tuple[str, ...] = ()) -> str | None:
    """Why the output folder's own files cannot take this session's results,
    or None: each is absent or of its kind, and none is a symbolic link."""
    from ..report.summary import MARKDOWN_NAME, SUMMARY_NAME

    wanted = {RUNS_FOLDER: "folder", HISTORY_NAME: "file", SUMMARY_NAME: "file", MARKDOWN_NAME: "file",
              **{name: "folder" for name in folders}}
    for name, kind in wanted.items():
        found = _kind(output_dir / name)
        if name == HISTORY_NAME and found == "file" and (output_dir / name).stat().st_nlink > 1:
            # Appended in place: a second name may be a file outside the output folder.
            return (f"{output_dir / name} has {(output_dir / name).stat().st_nlink - 1} other hard link(s); "
                    "the plugin appends to it only when it is the file's one name: copy it")
        if found is None or found == kind:
            continue
        if found == "link":
            return (f"{output_dir / name} is a symbolic link (to {os.readlink(output_dir / name)}); "
                    "the plugin writes nothing through a link: remove it")
        what = {"folder": "the folder of its runs", "file": "its own file"}[kind]
        found = {"folder": "a folder", "file": "a file"}.get(found, "not a regular file")
        return f"{output_dir / name} is {found}, where the plugin keeps {what}: move it away"
    return None


Warn = Callable[[str], None]


def finish_run(output_dir: Path, identity: RunIdentity, summary: dict[str, Any], keep: int) -> list[str]:
    """Write the session's summary into its run folder, make it the latest,
    add it to the history and prune runs beyond the ``keep`` newest.  Returns
    warnings: each step that fails (the folder damaged while the session ran)
    is one, and the other steps still write what they can."""
    from ..report.summary import write_summary

    warnings: list[str] = []

    def step(what: str, action: Callable[[], Any]) -> None:
        try:
            action()
        except OSError as exc:
            warnings.append(f"{what}: {exc.strerror or exc} ({exc.filename2 or exc.filename or output_dir})")

    folder = run_dir(output_dir, identity.id)
    finished = dt.datetime.now(dt.timezone.utc).isoformat(timespec="seconds")
    # Strict JSON has no NaN or infinity: one such value (a hand-edited reference's figure shown
    # beside an item's) must not cost the session its summary.
    replaced: list[str] = []
    summary = finite_json(summary, found=replaced)
    if replaced:
        shown = ", ".join(replaced[:5]) + (f" and {len(replaced) - 5} more" if len(replaced) > 5 else "")
        warnings.append(f"summary.json: {len(replaced)} value(s) that JSON cannot hold as numbers (NaN or infinite) "
                        f"written as the strings \"NaN\", \"Infinity\" or \"-Infinity\": {shown}")

    def write_run() -> None:
        start_run(output_dir, identity)
        write_summary(folder, summary, step_summary=False)
        write_json_atomic(folder / RUN_FILE, {
            "run": identity.to_json(), "state": "finished", "finished": finished,
            "exit_status": summary["exit_status"], "counts": summary["counts"],
            # What this session wrote: pruning deletes these and nothing else.
            "files": _files_under(folder),
        })

    step("cannot write this session's run folder", write_run)
    step("cannot write the latest summary", lambda: write_summary(output_dir, summary))
    line = {"run": identity.to_json(), "finished": finished, "exit_status": summary["exit_status"],
            "counts": summary["counts"], "summary": f"{RUNS_FOLDER}/{identity.id}/summary.json"}
    step(f"cannot add this session to {HISTORY_NAME}",
         lambda: _append_line(output_dir / HISTORY_NAME, json.dumps(line, sort_keys=True)))
    if keep > 0:
        step("cannot prune old runs", lambda: prune_runs(output_dir, keep, current=identity.id, warn=warnings.append))
    return warnings


def _append_line(path: Path, line: str) -> None:
    # One write of a whole line on an O_APPEND descriptor: concurrent sessions
    # add lines, they never interleave or overwrite one another's.  Never
    # through a link, never into a folder or a pipe.
    fd = os.open(path, os.O_RDWR | os.O_APPEND | os.O_CREAT | os.O_NOFOLLOW | os.O_NONBLOCK, 0o666)
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            raise OSError(0, "not a regular file", str(path))
        if os.fstat(fd).st_nlink > 1:
            raise OSError(0, "a file with other hard links", str(path))
        # Locked so that the look at the last byte and the write are one step
        # for the sessions appending at the same time.
        fcntl.flock(fd, fcntl.LOCK_EX)
        size = os.fstat(fd).st_size
        # A last line without its newline (a crash, a hand edit) would swallow ours.
        lead = b"\n" if size and os.pread(fd, 1, size - 1) != b"\n" else b""
        os.write(fd, lead + (line + "\n").encode("utf-8"))
    finally:
        os.close(fd)


def history_runs(output_dir: Path) -> list[tuple[dict[str, Any], Path]]:
    """(run identity, its summary.json) of each line of the output folder's history, newest first
    (report.trends.history_entries: a torn line, or a summary path leading out of the folder, skipped)."""
    return list(history_entries(output_dir / HISTORY_NAME))


def read_run(folder: Path) -> dict[str, Any] | None:
    if _kind(folder / RUN_FILE) != "file":  # a link's run.json is another folder's
        return None
    try:
        data = read_json(folder / RUN_FILE, MAX_BASELINE_BYTES)
    except ValueError:  # a JSONFileError: the run is not ours to prune
        return None
    return data if isinstance(data, dict) and isinstance(data.get("run"), dict) else None


def _manifest(data: dict[str, Any]) -> list[PurePosixPath] | None:
    """The run's files as paths inside its folder, or None when the manifest
    is not a list of such paths (an old or hand-edited run.json)."""
    files = data.get("files", [])
    if not isinstance(files, list) or not all(isinstance(name, str) and name for name in files):
        return None
    paths = [PurePosixPath(name) for name in files]
    if any(p.is_absolute() or any(part in ("", ".", "..") for part in p.parts) for p in paths):
        return None
    return paths


def _unlink_own(folder: Path, name: PurePosixPath) -> None:
    """Delete ``folder/name`` if it is a regular file reached through real folders only."""
    target = folder
    for part in name.parts[:-1]:
        target = target / part
        if _kind(target) != "folder":
            return
    target = target / name.parts[-1]
    if _kind(target) == "file":
        target.unlink(missing_ok=True)


def prune_runs(output_dir: Path, keep: int, current: str, warn: Warn = lambda message: None) -> list[str]:
    """Remove finished runs beyond the ``keep`` newest; running or killed runs,
    files not in a run's manifest and anything reached through a symbolic link
    stay.  A run whose manifest is not a list of its files is kept, with a
    warning.  Returns the pruned run ids."""
    root = output_dir / RUNS_FOLDER
    if _kind(root) != "folder":
        return []
    finished = []
    for folder in sorted(root.iterdir(), key=lambda p: p.name):
        if _kind(folder) != "folder":  # a link to a run elsewhere is not ours to prune
            continue
        data = read_run(folder)
        if folder.name != current and data is not None and data.get("state") == "finished":
            finished.append((folder, data))
    pruned = []
    for folder, data in finished[: max(0, len(finished) + 1 - keep)]:
        files = _manifest(data)
        if files is None:
            warn(f"{folder / RUN_FILE}: 'files' is not a list of paths inside the run's folder; "
                 "that run is kept, delete it by hand")
            continue
        for name in [*files, PurePosixPath(RUN_FILE)]:
            _unlink_own(folder, name)
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
