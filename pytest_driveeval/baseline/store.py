"""Where references live: a folder of baseline files committed with the scenarios, or the summary
of an earlier run in the output folder.

A baseline file is JSON, indented, keys sorted, one per item at ``<DIR>/<scenario file>.d/<item>.json``
(the scenario file's path from the rootdir), so that a changed figure is a changed line in a diff.
Reading one parses JSON and checks its shape; it never runs anything in it.  Writing replaces the
file atomically (two sessions updating at once leave one whole file), never through a symbolic link.
"""
from __future__ import annotations

import hashlib
import json
import math
import re
from pathlib import Path, PurePosixPath
from typing import Any

from ..core.atomic import (MAX_BASELINE_BYTES, MAX_SUMMARY_BYTES, JSONFileError, loads_bounded, read_json, read_regular,
                      write_text_atomic)
from ..core.errors import DriveEvalError, display_path
from ..harness.runs import HISTORY_NAME, RUNS_FOLDER, history_runs

BASELINE_FORMAT = 1
SUFFIX = ".json"
FOLDER_SUFFIX = ".d"
_UNSAFE = re.compile(r"[^A-Za-z0-9._=,+@\[\]-]+")
MAX_NAME = 150


class BaselineError(DriveEvalError):
    """A baseline or reference that cannot be read: corrupt, truncated, hand-edited, or not ours."""


def _safe(part: str) -> str:
    name = _UNSAFE.sub("_", part).strip("_") or "_"
    if name in (".", ".."):
        name = name.replace(".", "_")
    # A replaced character or a cut tail would let two items ("a b", "a/b", "a_b") share one file:
    # the digest of the whole original keeps them apart.
    if name != part or len(name) > MAX_NAME:
        name = f"{name[:MAX_NAME - 13]}-{hashlib.sha256(part.encode()).hexdigest()[:12]}"
    return name


def relative_path(nodeid: str) -> PurePosixPath:
    """``a/b.scenario.yaml::closed_loop[x]`` -> ``a/b.scenario.yaml.d/closed_loop[x].json``."""
    file, _, item = nodeid.partition("::")
    parts = [_safe(p) for p in PurePosixPath(file).parts if p not in ("", ".", "/")]
    if parts:
        # A folder named like the scenario file would be found by every "**/*.yaml" glob.
        parts[-1] += FOLDER_SUFFIX
    return PurePosixPath(*parts, _safe(item.replace("::", "__") or "item") + SUFFIX)


def _no_link_on_the_way(root: Path, path: Path) -> None:
    current = root
    for part in path.relative_to(root).parts:
        current = current / part
        if current.is_symlink():
            raise BaselineError(f"{display_path(current)} is a symbolic link; baselines are written and read "
                                "only through real folders: remove it")


class BaselineStore:
    def __init__(self, root: Path):
        self.root = root

    def path_for(self, nodeid: str) -> Path:
        return self.root / relative_path(nodeid)

    def read(self, nodeid: str) -> dict[str, Any] | None:
        """The item's baseline, or None when there is none; a BaselineError names the file and key."""
        path = self.path_for(nodeid)
        if not path.exists() and not path.is_symlink():
            return None
        _no_link_on_the_way(self.root, path)
        return check_baseline(read_text(path), path, nodeid)

    def write(self, nodeid: str, payload: dict[str, Any], run: dict[str, Any]) -> Path:
        path = self.path_for(nodeid)
        self.root.mkdir(parents=True, exist_ok=True)
        _no_link_on_the_way(self.root, path.parent if path.parent != self.root else self.root)
        path.parent.mkdir(parents=True, exist_ok=True)
        _no_link_on_the_way(self.root, path)
        write_text_atomic(path, json.dumps(_record(payload, run), indent=1, sort_keys=True, ensure_ascii=False) + "\n")
        return path

    def unchanged(self, nodeid: str, payload: dict[str, Any]) -> bool:
        """Whether the item's baseline file already says all that ``payload`` would write but the
        run that wrote it (its id, time, commit): rewritten, it would be a changed file in git for
        nothing but the run."""
        path = self.path_for(nodeid)
        if path.is_symlink() or not path.is_file():
            return False
        try:
            old = self.read(nodeid)  # one that does not read (a hand-edited run, say) is rewritten
        except BaselineError:
            return False
        new = json.loads(json.dumps(_record(payload, {}), ensure_ascii=False))
        return isinstance(old, dict) and {**old, "run": None} == {**new, "run": None}

    def files(self) -> dict[Path, str | None]:
        """Every baseline file under the root and the node id it says it is for (None: unreadable)."""
        out: dict[Path, str | None] = {}
        if not self.root.is_dir():
            return out
        for path in sorted(self.root.rglob(f"*{SUFFIX}")):
            if path.is_symlink() or not path.is_file():
                continue
            try:
                data = read_json(path, MAX_BASELINE_BYTES)
                key = data["key"]["nodeid"] if isinstance(data, dict) and isinstance(data.get("key"), dict) else None
            except (ValueError, KeyError, TypeError):  # JSONFileError is a ValueError
                key = None
            out[path] = key if isinstance(key, str) else None
        return out


def _record(payload: dict[str, Any], run: dict[str, Any]) -> dict[str, Any]:
    """A baseline file's content: the payload without what only the current session needs."""
    return {"driveeval_baseline": BASELINE_FORMAT, "run": {k: run.get(k) for k in ("id", "started", "commit", "dirty")},
            **{k: v for k, v in payload.items() if k not in ("version", "rules")}}


# key -> the type it must have; every other key is free (the file may gain keys)
_SHAPE = {"driveeval_baseline": int, "key": dict, "run": dict, "verdict": str, "figures": dict}


def read_text(path: Path) -> str:
    """A baseline file's text, refused (BaselineError naming it) when it is no regular file or
    larger than a baseline ever is."""
    where = display_path(path)
    try:
        raw = read_regular(path, MAX_BASELINE_BYTES + 1)
        if raw is None:
            raise BaselineError(f"baseline {where} is not a regular file: remove it")
        if len(raw) > MAX_BASELINE_BYTES:
            raise BaselineError(f"baseline {where} is larger than {MAX_BASELINE_BYTES // 2 ** 20} MiB, which no "
                                "baseline is: remove it or rewrite it with --driveeval-baseline-update")
        return raw.decode("utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise BaselineError(f"baseline {where} cannot be read: {exc}") from None


def check_baseline(text: str, path: Path, nodeid: str) -> dict[str, Any]:
    where = display_path(path)
    try:
        data = loads_bounded(text, f"baseline {where} of {nodeid}")
    except JSONFileError as exc:
        raise BaselineError(f"{exc}; remove it or rewrite it with --driveeval-baseline-update") from None
    except ValueError as exc:
        # A string without its closing quote runs to the end of the text: cut there too.
        cut = exc.msg.startswith("Unterminated string") or ("Expecting" in exc.msg  # type: ignore[attr-defined]
                                                            and exc.pos >= len(text.rstrip()))  # type: ignore[attr-defined]
        truncated = " (truncated?)" if cut else ""
        raise BaselineError(f"baseline {where} of {nodeid} is not valid JSON{truncated}: {exc}; "
                            "fix it or rewrite it with --driveeval-baseline-update") from None
    if not isinstance(data, dict):
        raise BaselineError(f"baseline {where} of {nodeid}: not a mapping at the top level")
    # A newer format may have reshaped any other key: say so before judging them (rewriting the
    # file with this version would lose what the newer one wrote).
    version = data.get("driveeval_baseline")
    if isinstance(version, int) and not isinstance(version, bool) and version > BASELINE_FORMAT:
        raise BaselineError(f"baseline {where}: format {version} (key 'driveeval_baseline') is newer than this "
                            f"pytest-driveeval reads ({BASELINE_FORMAT}); upgrade it")
    for key, kind in _SHAPE.items():
        if not isinstance(data.get(key), kind) or isinstance(data.get(key), bool):
            found = "missing" if key not in data else f"a {type(data[key]).__name__}"
            raise BaselineError(f"baseline {where} of {nodeid}: key '{key}' is {found}, not a {kind.__name__}; "
                                "rewrite it with --driveeval-baseline-update")
    if data["key"].get("nodeid") != nodeid:
        raise BaselineError(f"baseline {where}: key 'key.nodeid' says {data['key'].get('nodeid')!r}, "
                            f"the file's place is {nodeid!r}'s; move or rewrite it")
    problem = payload_problem(data)
    if problem:
        raise BaselineError(f"baseline {where} of {nodeid}: key {problem}; rewrite it with "
                            "--driveeval-baseline-update")
    return data


def _number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


# nested key -> what it must be when present (None is always allowed): what a comparison reads
_NESTED = {("run", "id"): (str,), ("run", "started"): (str,), ("run", "commit"): (str,), ("run", "dirty"): (bool,),
           ("fingerprint", "dataset"): (dict,), ("fingerprint", "settings"): (dict,),
           ("search", "minimal"): (dict,), ("search", "broke"): (bool,)}


def payload_problem(data: dict[str, Any]) -> str | None:
    """The first key of a reference (a baseline file's content, an earlier run's record) that a
    comparison cannot read, as ``'key' is ...``; None when it reads."""
    for key in ("units", "search", "fingerprint", "run", "figures"):
        if data.get(key) is not None and not isinstance(data[key], dict):
            return f"'{key}' is not a mapping"
    for (outer, inner), kinds in _NESTED.items():
        value = (data.get(outer) or {}).get(inner)
        if value is not None and not isinstance(value, kinds):
            return f"'{outer}.{inner}' is a {type(value).__name__}, not a {kinds[0].__name__}"
    if data.get("units"):
        from .units import Units

        try:
            Units.from_json(data["units"])
        except ValueError as exc:
            return f"'{exc}'"
    for group in ("figures", "search.minimal"):
        outer, _, inner = group.partition(".")
        values = ((data.get(outer) or {}).get(inner) if inner else data.get(outer)) or {}
        bad = [k for k, v in values.items() if not (v is None or _number(v))]
        if bad:
            return f"'{group}.{bad[0]}' is not a number"
        # JSON has no NaN or Infinity, but Python's reader takes them; no comparison can use one.
        odd = [(k, v) for k, v in values.items() if v is not None and not math.isfinite(v)]
        if odd:
            name, value = odd[0]
            said = "NaN" if value != value else "Infinity" if value > 0 else "-Infinity"
            return f"'{group}.{name}' is {said}, not a finite number"
    return None


class RunReference:
    """The records of an earlier run's summary.json, by node id."""

    def __init__(self, summary: Path):
        self.path = summary
        try:
            data = read_json(summary, MAX_SUMMARY_BYTES, where=display_path(summary))
        except JSONFileError as exc:
            raise BaselineError(f"{exc.where} is not a readable driveeval summary: {exc.reason}") from None
        try:
            records = data["results"]
            self.run = data.get("run") or {}
            assert isinstance(records, list) and isinstance(self.run, dict)
        except (KeyError, TypeError, AssertionError) as exc:
            raise BaselineError(f"{display_path(summary)} is not a readable driveeval summary: {exc}") from None
        self.records = {r.get("nodeid"): r for r in records if isinstance(r, dict)}

    def read(self, nodeid: str) -> dict[str, Any] | None:
        record = self.records.get(nodeid)
        if record is None:
            return None
        payload = record.get("baseline")
        if not isinstance(payload, dict):
            raise BaselineError(f"run {self.run.get('id')} ({display_path(self.path)}) kept no comparable record "
                                f"of {nodeid} (made before pytest-driveeval kept one, or it did not run)")
        payload = {**payload, "run": self.run}
        problem = payload_problem(payload)
        if problem:
            raise BaselineError(f"run {self.run.get('id')} ({display_path(self.path)}): the record of {nodeid} "
                                f"cannot be compared: key {problem}")
        return payload


#: ``last`` (the newest finished run) or ``last~N`` (N runs before it)
LAST = re.compile(r"last(?:~(\d+))?")


def finished_runs(output_dir: Path, skip: str | None = None) -> list[tuple[str, Path]]:
    """(run id, summary.json) of the history's finished runs whose summary is still there, newest
    first; ``skip`` leaves out one run (the session asking)."""
    return [(run.get("id"), summary) for run, summary in history_runs(output_dir)
            if run.get("id") != skip and summary.is_file()]


def resolve_compare(spec: str, output_dir: Path, current_run: str | None = None) -> Path:
    """``last``, ``last~N``, a run id, a summary.json or a run folder -> the summary.json to compare with."""
    last = LAST.fullmatch(spec)
    if last:
        back = int(last.group(1) or 0)
        runs = finished_runs(output_dir, skip=current_run)
        if back < len(runs):
            return runs[back][1]
        history = display_path(output_dir / HISTORY_NAME)
        if not runs:
            raise ValueError(f"no finished run in {history} to compare with; run once without "
                             "--driveeval-compare first")
        raise ValueError(f"{spec!r} is the run {back} before the last, and {history} has {len(runs)} finished "
                         f"run(s) with their summary (last~{len(runs) - 1} is the oldest)")
    runs = output_dir / RUNS_FOLDER / spec / "summary.json"
    if "/" not in spec and spec not in (".", "..") and runs.is_file():
        return runs
    path = Path(spec)
    if path.is_dir() and (path / "summary.json").is_file():
        return path / "summary.json"
    if path.is_file():
        return path
    raise ValueError(f"{spec!r} is neither 'last', 'last~N', a run id under {display_path(output_dir / RUNS_FOLDER)}, "
                     "nor a summary.json")
