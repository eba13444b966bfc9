"""JSON files the plugin reads back (baselines, summaries, a history's lines), bounded in size and
depth before they are parsed.

Python's json parser recurses once per nested bracket: 100,000 of them in a few hundred KB raise a
bare RecursionError far from the file that did it.  The plugin's own files are a few levels deep,
so the nesting is measured first (at C speed, on the brackets outside strings) and a deeper or
larger file is refused with a message that names it and the bound.
"""
from __future__ import annotations

import json
import math
import os
import re
import stat
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import display_path

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


def read_json(path: Path, max_bytes: int, max_depth: int = MAX_DEPTH) -> Any:
    """The JSON value of the regular file at ``path``, read whole up to ``max_bytes``.  Raises
    :class:`JSONFileError` naming the file: unreadable, not a regular file, too large, too deep,
    not JSON."""
    where = display_path(path)
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
