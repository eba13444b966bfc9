"""What a process keeps from one chunk to the next (issue 25).

A Ray worker runs chunk after chunk of an item, and a local run with a ChunkSize does the same
here; loading the model (an exported program: ~1 s) or the semantic map (~0.3 s full size) for
each of them cost as much as the chunk's own work.  :func:`reused` keeps what a chunk loaded for
the next one that names the same thing.

An entry's key is what the caller says identifies it (the loading spec and the folder it
resolves against: two items whose specs differ never share an entry) and the identity of each
file it was read from: resolved path, size, mtime_ns, inode and device, taken again at every
lookup (one ``stat`` per file), so a file rewritten or replaced is read again.  A file changed
within the last :data:`RACY_SECONDS` (or while it was read) may change again without its size or
mtime showing it (a coarse clock on some shared file systems), so what was read from it is used
once and not kept.  Only objects that the local path already reuses across calls belong here (a
loaded model serves every batch of an item; a map is only read): a chunk's result must be the
same whether its model came from the file or from the chunk before.

Bounded: each kind keeps its last ``keep`` entries (least recently used dropped first).  Set
:data:`SWITCH` to ``0`` in the environment (``RuntimeEnv: {env_vars: {DRIVEEVAL_REUSE: "0"}}`` on
Ray) to load everything for every chunk, as before.
"""
from __future__ import annotations

import os
import time
from collections import OrderedDict
from pathlib import Path
from typing import Any, Callable, Hashable, Iterable, TypeVar

__all__ = ["RACY_SECONDS", "SWITCH", "file_identity", "forget", "held", "loads", "reused"]

T = TypeVar("T")

#: environment variable: "0" turns reuse off in this process
SWITCH = "DRIVEEVAL_REUSE"
#: a file modified this recently is not trusted to show its next change in size or mtime
RACY_SECONDS = 2.0

_kept: dict[str, OrderedDict[Hashable, Any]] = {}
#: loads per kind in this process (what the tests and the benchmark count)
loads: dict[str, int] = {}


def file_identity(path: str | os.PathLike) -> tuple:
    """(resolved path, size, mtime_ns, inode, device) of a file as it is now."""
    resolved = Path(path).resolve()
    st = resolved.stat()
    return str(resolved), st.st_size, st.st_mtime_ns, st.st_ino, st.st_dev


def _settled(identities: tuple) -> bool:
    now_ns = time.time_ns()
    return all(now_ns - mtime_ns >= RACY_SECONDS * 1e9 for _, _, mtime_ns, _, _ in identities)


def reused(kind: str, key: Hashable, files: Iterable[str | os.PathLike], load: Callable[[], T], *,
           keep: int = 2) -> T:
    """``load()``'s result, or what an earlier call with the same ``kind``, ``key`` and unchanged
    ``files`` got from it.  A file that cannot be stat'ed is left to ``load`` to report; nothing
    is kept when ``load`` raises."""
    if os.environ.get(SWITCH, "1") == "0":
        return _load(kind, load)
    try:
        identities = tuple(file_identity(f) for f in files)
    except OSError:
        return _load(kind, load)
    entries = _kept.setdefault(kind, OrderedDict())
    full_key = (key, identities)
    if full_key in entries:
        entries.move_to_end(full_key)
        return entries[full_key]
    value = _load(kind, load)
    try:
        unchanged = tuple(file_identity(f) for f in files) == identities
    except OSError:
        unchanged = False
    if unchanged and _settled(identities):
        # An older version of the same thing is never asked for again while its files stay new.
        for stale in [k for k in entries if k[0] == key]:
            del entries[stale]
        entries[full_key] = value
        while len(entries) > keep:
            entries.popitem(last=False)
    return value


def _load(kind: str, load: Callable[[], T]) -> T:
    value = load()
    loads[kind] = loads.get(kind, 0) + 1
    return value


def held(kind: str) -> int:
    """How many entries of ``kind`` this process keeps now."""
    return len(_kept.get(kind, ()))


def forget() -> None:
    """Drop everything kept and the load counts (tests)."""
    _kept.clear()
    loads.clear()
