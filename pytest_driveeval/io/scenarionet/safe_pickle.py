"""Pickles read as data: an unpickler that builds numpy arrays, numpy dtypes and builtin
containers and scalars, and refuses anything else before it is called.

A pickle names the callables that rebuild it (``module.name``), and the standard unpickler imports
and calls whatever it names: a data file could run any code.  ScenarioNet's scenario files are
pickles of dicts of arrays, so the few callables those need are allowed by name (what
``torch.load(weights_only=True)`` does for weights); a file that asks for another is refused with
its name, and nothing it names is imported.

Nor may the file decide how much memory is used:

- only a regular file is read (not a device, a FIFO or a link to one), of at most
  :data:`MAX_FILE_BYTES`;
- each allowed callable checks its arguments (:mod:`.safe_pickle_makers`): a size the file asks
  for (``bytearray(3 << 30)``, ``numpy.ndarray((3e7,))``) is refused, only sizes its bytes hold are
  built, and BUILD sets state on numpy arrays and dtypes only (on an ``OrderedDict`` it would set
  its ``get``);
- dict keys and set items are plain values (hashing a 3,000,000-deep tuple crashes Python);
- what was built is measured as a reader expands it (:mod:`.safe_pickle_bounds`): at most
  :data:`~.safe_pickle_bounds.MAX_UNPACKED_BYTES`, counting shared references at each use, and
  :data:`~.safe_pickle_bounds.MAX_DEPTH` levels deep.

Python's own pure-Python unpickler runs the opcodes (its C twin cannot be told how to build and
grows its memo table to any index a file names); each file is read once per scene.
"""
from __future__ import annotations

import io
import os
import pickle
import stat
import struct
from pathlib import Path
from typing import Any

from ...core.errors import DataError, display_path
from .safe_pickle_bounds import MAX_DEPTH, MAX_UNPACKED_BYTES, check_bounds
from .safe_pickle_makers import MAKERS, Maker, Refused, build, is_scalar

#: the largest data pickle read (ScenarioNet's scenes are a few MB; a Waymo or nuPlan one tens)
MAX_FILE_BYTES = 256 << 20

__all__ = ["ALLOWED", "MAX_DEPTH", "MAX_FILE_BYTES", "MAX_UNPACKED_BYTES", "UnsafePickleError", "load_data_pickle",
           "read_regular_file"]

#: (module, name) a data pickle may name
ALLOWED = frozenset(MAKERS)


class UnsafePickleError(DataError, ValueError):
    """A pickle that names a callable outside the allowed set, or that is not a readable pickle."""


_KINDS = ((stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"), (stat.S_ISFIFO, "a FIFO (pipe)"),
          (stat.S_ISSOCK, "a socket"), (stat.S_ISDIR, "a folder"))


def read_regular_file(path: str | Path, limit: int | None = None) -> bytes:
    """The bytes of ``path`` if it is a regular file (after links) of at most ``limit`` bytes; a
    device, FIFO or socket is refused without reading it (opened without blocking, so a FIFO does
    not wait for a writer)."""
    where = display_path(path)
    limit = MAX_FILE_BYTES if limit is None else limit
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0))
    except OSError as exc:
        link = " (a link whose target is missing)" if Path(path).is_symlink() else ""
        raise DataError(f"{where} cannot be read{link}: {exc.strerror or exc}") from None
    with os.fdopen(fd, "rb") as handle:
        info = os.fstat(fd)
        if not stat.S_ISREG(info.st_mode):
            kind = next((name for test, name in _KINDS if test(info.st_mode)), "not a regular file")
            target = f" (a link to {os.path.realpath(path)})" if Path(path).is_symlink() else ""
            raise DataError(f"{where}{target} is {kind}, not a regular file: only regular files are read as data; "
                            "remove it or point it at a scenario file")
        if info.st_size > limit:
            raise DataError(f"{where} is {_mib(info.st_size)}, more than the {_mib(limit)} a data file may be: split it "
                            "(ScenarioNet writes one scenario per file)")
        raw = handle.read(limit + 1)
    if len(raw) > limit:  # it grew while read
        raise DataError(f"{where} is more than the {_mib(limit)} a data file may be")
    return raw


def _mib(size: int) -> str:
    return f"{size / 2 ** 20:.3g} MiB"


def _scalar_keys(items: list, what: str) -> None:
    for item in items:
        if not is_scalar(item):
            raise Refused(f"{what} a {type(item).__name__}: keys and set items must be plain values (numbers, text, "
                          "bytes); hashing anything else the file built can recurse without bound")


class _DataUnpickler(pickle._Unpickler):  # type: ignore[name-defined]
    """Python's unpickler with the opcodes that call, set state or hash replaced by checked ones."""

    dispatch = dict(pickle._Unpickler.dispatch)  # type: ignore[attr-defined]

    def __init__(self, handle: Any, size: int):
        super().__init__(handle)
        self.size = size

    def find_class(self, module: str, name: str) -> Any:
        found = MAKERS.get((module, name))
        if found is None:
            raise Refused(f"asks for {module}.{name}, which a data file may not name: only numpy arrays and dtypes "
                          "and builtin containers are read from pickles; nothing was run")
        return found

    def persistent_load(self, pid: Any) -> Any:
        raise Refused(f"refers to a persistent object ({str(pid)[:40]!r}): not data")

    def load_reduce(self) -> None:
        args = self.stack.pop()
        func = self.stack[-1]
        if not isinstance(func, Maker) or not isinstance(args, tuple):
            raise Refused(f"calls a {type(func).__name__}, which is no allowed callable")
        self.stack[-1] = func.call(*args)

    def load_build(self) -> None:
        state = self.stack.pop()
        build(self.stack[-1], state)

    def refuse(self) -> None:
        raise Refused("makes an object of a class (NEWOBJ, OBJ or INST): a data file is numpy arrays and builtin "
                      "containers")

    def load_setitem(self) -> None:
        value, key = self.stack.pop(), self.stack.pop()
        self._set_items([key, value])

    def load_setitems(self) -> None:
        self._set_items(self.pop_mark())

    def _set_items(self, items: list) -> None:
        target = self.stack[-1]
        if not isinstance(target, dict):
            raise Refused(f"sets items of a {type(target).__name__}: only dicts take items so")
        _scalar_keys(items[::2], "has a dict key that is")
        for i in range(0, len(items), 2):
            target[items[i]] = items[i + 1]

    def load_dict(self) -> None:
        items = self.pop_mark()
        _scalar_keys(items[::2], "has a dict key that is")
        self.append({items[i]: items[i + 1] for i in range(0, len(items), 2)})

    def load_additems(self) -> None:
        items = self.pop_mark()
        target = self.stack[-1]
        if not isinstance(target, set):
            raise Refused(f"adds set items to a {type(target).__name__}")
        _scalar_keys(items, "has a set item that is")
        target.update(items)

    def load_frozenset(self) -> None:
        items = self.pop_mark()
        _scalar_keys(items, "has a set item that is")
        self.append(frozenset(items))

    def load_append(self) -> None:
        value = self.stack.pop()
        self._append_items([value])

    def load_appends(self) -> None:
        self._append_items(self.pop_mark())

    def _append_items(self, items: list) -> None:
        target = self.stack[-1]
        if not isinstance(target, list):
            raise Refused(f"appends to a {type(target).__name__}: only lists take items so")
        target.extend(items)

    def load_bytearray8(self) -> None:
        # Python's own allocates the length it reads before reading the bytes
        size, = struct.unpack("<Q", self.read(8))
        if size > self.size:
            raise Refused(f"declares a bytearray of {size} bytes in a file of {self.size}")
        data = self.read(size)
        if len(data) != size:
            raise EOFError
        self.append(bytearray(data))


for _opcode, _method in ((pickle.REDUCE, _DataUnpickler.load_reduce), (pickle.BUILD, _DataUnpickler.load_build),
                         (pickle.NEWOBJ, _DataUnpickler.refuse), (pickle.NEWOBJ_EX, _DataUnpickler.refuse),
                         (pickle.OBJ, _DataUnpickler.refuse), (pickle.INST, _DataUnpickler.refuse),
                         (pickle.SETITEM, _DataUnpickler.load_setitem), (pickle.SETITEMS, _DataUnpickler.load_setitems),
                         (pickle.DICT, _DataUnpickler.load_dict), (pickle.ADDITEMS, _DataUnpickler.load_additems),
                         (pickle.FROZENSET, _DataUnpickler.load_frozenset), (pickle.APPEND, _DataUnpickler.load_append),
                         (pickle.APPENDS, _DataUnpickler.load_appends),
                         (pickle.BYTEARRAY8, _DataUnpickler.load_bytearray8)):
    _DataUnpickler.dispatch[_opcode[0]] = _method


def load_data_pickle(path: str | Path, data: bytes | None = None) -> Any:
    """The object pickled in ``path`` (or in ``data``, read from it), built from allowed types only,
    within the bounds above."""
    where = display_path(path)
    raw = read_regular_file(path) if data is None else data
    if not raw.startswith(b"\x80"):
        raise UnsafePickleError(f"{where} is not a pickle (protocol 2 or later): it starts with {raw[:8]!r}")
    try:
        value = _DataUnpickler(io.BytesIO(raw), len(raw)).load()
        check_bounds(value)
        return value
    except Refused as exc:
        raise UnsafePickleError(f"{where} {exc}" if str(exc).startswith("asks") or str(exc).startswith("refers")
                                else f"{where} is refused: {exc}") from None
    except (pickle.UnpicklingError, EOFError, ValueError, TypeError, AttributeError, IndexError, KeyError,
            MemoryError, OverflowError, UnicodeDecodeError, RecursionError, struct.error) as exc:
        cut = isinstance(exc, EOFError) or "exhausted" in str(exc)
        reason = "truncated" if cut else f"{type(exc).__name__}: {exc}"
        raise UnsafePickleError(f"{where} is not a readable pickle ({reason})") from None
