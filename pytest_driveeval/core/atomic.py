"""Files written whole or not at all, with the permissions the user's umask gives; and the JSON
files the plugin reads back (baselines, summaries, a history's lines), bounded in size and depth.

A reader (or a session killed half-way) sees the old file or the new one, never
half of one: every file goes to a temporary name beside its target and is
renamed onto it once complete.

Python's json parser recurses once per nested bracket: 100,000 of them in a few hundred KB raise a
bare RecursionError far from the file that did it.  The plugin's own files are a few levels deep,
so the nesting is measured first (at C speed, on the brackets outside strings) and a deeper or
larger file is refused with a message that names it and the bound.
"""
from __future__ import annotations

import functools
import json
import math
import os
import re
import stat
import tempfile
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterator

import numpy as np


def _umask() -> int:
    # os.umask can only be read by setting it, which races with other threads
    # creating files; Linux shows it in /proc without touching it.
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("Umask:"):
                return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    return _umask_by_setting()


@functools.lru_cache(maxsize=1)
def _umask_by_setting() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def file_mode() -> int:
    """The mode ``open(path, "w")`` would give a new file."""
    return 0o666 & ~_umask()


@contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """A temporary path beside ``path`` (same suffix, so writers that go by
    the suffix still work), renamed onto ``path`` when the block succeeds."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=f".tmp{path.suffix}", dir=path.parent)
    os.close(fd)
    try:
        yield Path(tmp)
        os.chmod(tmp, file_mode())  # mkstemp makes 0600
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def write_bytes_atomic(path: str | os.PathLike, data: bytes) -> None:
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)


def write_text_atomic(path: str | os.PathLike, text: str) -> None:
    write_bytes_atomic(path, text.encode("utf-8"))


def write_json_atomic(path: str | os.PathLike, data: Any) -> None:
    write_text_atomic(path, json.dumps(data, indent=2, allow_nan=False) + "\n")


def create_exclusive(path: str | os.PathLike, text: str) -> bool:
    """Write ``path`` whole unless it exists; False when it does (another process won)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as handle:
            handle.write(text)
        os.chmod(tmp, file_mode())
        os.link(tmp, path)  # unlike rename, refuses to replace an existing file
        return True
    except FileExistsError:
        return False
    finally:
        Path(tmp).unlink(missing_ok=True)


#: the plugin writes summaries and baselines under a dozen levels deep; a hand edit may add some
MAX_DEPTH = 64
#: a baseline file holds one item's figures and per-unit codes
MAX_BASELINE_BYTES = 32 * 2 ** 20
#: a summary holds every item of a session
MAX_SUMMARY_BYTES = 512 * 2 ** 20

_STRING = re.compile(r'"[^"\\]*(?:\\.[^"\\]*)*"', re.S)
_NOT_BRACKET = re.compile(r"[^\[\]{}]+")
_STEP = np.zeros(256, dtype=np.int8)
_STEP[[ord("["), ord("{")]] = 1
_STEP[[ord("]"), ord("}")]] = -1


class JSONFileError(ValueError):
    """A JSON file that cannot be read within the bounds; the message names the file, ``reason``
    says what is wrong without naming it."""

    def __init__(self, where: str, reason: str):
        self.where, self.reason = where, reason
        super().__init__(f"{where}: {reason}")


def nesting_depth(text: str) -> int:
    """How deeply ``text``'s arrays and objects nest (brackets inside strings do not count)."""
    brackets = _NOT_BRACKET.sub("", _STRING.sub("", text))
    if not brackets:
        return 0
    steps = _STEP[np.frombuffer(brackets.encode("ascii"), dtype=np.uint8)].astype(np.int32)
    return int(np.cumsum(steps).max())


def loads_bounded(text: str, where: str, max_depth: int = MAX_DEPTH) -> Any:
    """``json.loads`` of ``text`` (from ``where``, a file as messages name it) unless it nests deeper
    than ``max_depth``.  Raises :class:`JSONFileError` (nested too deep) or ``json``'s ValueError."""
    depth = nesting_depth(text) if text.count("[") + text.count("{") > max_depth else 0
    if depth > max_depth:
        raise JSONFileError(where, f"JSON nested {depth} levels deep, where the plugin's files are at most "
                                   f"{max_depth} levels deep: not one of them, or damaged")
    try:
        return json.loads(text)
    except RecursionError:  # a nesting the count above did not see: never a bare traceback
        raise JSONFileError(where, "JSON nested too deeply to read") from None


def read_regular(path: Path, limit: int) -> bytes | None:
    """Up to ``limit`` bytes of the regular file at ``path``; None when it is something else (a
    FIFO, whose open alone would wait for a writer forever, a device, a folder)."""
    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            return None
        with os.fdopen(fd, "rb") as handle:
            fd = -1
            return handle.read(limit)
    finally:
        if fd >= 0:
            os.close(fd)


def read_json(path: Path, max_bytes: int, max_depth: int = MAX_DEPTH, where: str = "") -> Any:
    """The JSON value of the regular file at ``path``, read whole up to ``max_bytes``.  Raises
    :class:`JSONFileError` naming the file (as ``where``, default the path): unreadable, not a
    regular file, too large, too deep, not JSON."""
    where = where or str(path)
    try:
        raw = read_regular(path, max_bytes + 1)
    except OSError as exc:
        raise JSONFileError(where, f"cannot be read: {exc.strerror or exc}") from None
    if raw is None:
        raise JSONFileError(where, "not a regular file")
    if len(raw) > max_bytes:
        size = f"{max_bytes / 2 ** 20:g} MiB" if max_bytes >= 2 ** 20 else f"{max_bytes} bytes"
        raise JSONFileError(where, f"larger than {size}, more than the plugin ever writes "
                                   "there: not one of its files, or damaged")
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise JSONFileError(where, f"not UTF-8 text: {exc}") from None
    try:
        return loads_bounded(text, where, max_depth)
    except JSONFileError:
        raise
    except ValueError as exc:
        raise JSONFileError(where, str(exc)) from None


def finite_json(value: Any, path: str = "", found: list[str] | None = None) -> Any:
    """``value`` with every NaN or infinite float replaced by its name as a string ("NaN",
    "Infinity", "-Infinity": what JavaScript and most JSON readers call them), which strict JSON
    cannot hold as a number; ``found`` gathers the key paths replaced."""
    if isinstance(value, float) and not math.isfinite(value):
        if found is not None:
            found.append(path or "(top)")
        return "NaN" if value != value else "Infinity" if value > 0 else "-Infinity"
    if isinstance(value, dict):
        return {k: finite_json(v, f"{path}.{k}" if path else str(k), found) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [finite_json(v, f"{path}[{i}]", found) for i, v in enumerate(value)]
    return value
