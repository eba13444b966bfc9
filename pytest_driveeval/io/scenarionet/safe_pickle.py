"""Pickles read as data: an unpickler that builds numpy arrays, numpy dtypes and builtin
containers and scalars, and refuses anything else before it is called.

A pickle names the callables that rebuild it (``module.name``), and the standard unpickler imports
and calls whatever it names: a data file could run any code.  ScenarioNet's scenario files are
pickles of dicts of arrays, so the few callables those need are allowed by name (what
``torch.load(weights_only=True)`` does for weights); a file that asks for another is refused with
its name, and nothing it names is imported.
"""
from __future__ import annotations

import collections
import io
import pickle
from pathlib import Path
from typing import Any

import numpy as np

from ...core.errors import DataError, display_path


class UnsafePickleError(DataError, ValueError):
    """A pickle that names a callable outside the allowed set, or that is not a readable pickle."""


def _numpy_reconstruct() -> Any:
    # numpy 2 moved the module; pickles written by numpy 1 name the old one.
    core = getattr(np, "_core", None) or np.core
    return core.multiarray._reconstruct


def _numpy_scalar() -> Any:
    core = getattr(np, "_core", None) or np.core
    return core.multiarray.scalar


#: (module, name) -> what it builds: numpy arrays and scalars, and builtin data types only
ALLOWED: dict[tuple[str, str], Any] = {
    ("numpy", "ndarray"): np.ndarray,
    ("numpy", "dtype"): np.dtype,
    ("numpy.core.multiarray", "_reconstruct"): _numpy_reconstruct(),
    ("numpy._core.multiarray", "_reconstruct"): _numpy_reconstruct(),
    ("numpy.core.multiarray", "scalar"): _numpy_scalar(),
    ("numpy._core.multiarray", "scalar"): _numpy_scalar(),
    ("collections", "defaultdict"): collections.defaultdict,
    ("collections", "OrderedDict"): collections.OrderedDict,
    **{("builtins", t.__name__): t for t in (dict, list, tuple, set, frozenset, int, float, complex, str, bytes,
                                             bytearray, bool)},
    # numpy's scalar types, as dtype(...) and scalar(...) name them in older pickles
    **{("numpy", t.__name__): t for t in (np.float64, np.float32, np.float16, np.int64, np.int32, np.int16, np.int8,
                                          np.uint64, np.uint32, np.uint16, np.uint8, np.bool_, np.str_, np.bytes_)},
}


class _DataUnpickler(pickle.Unpickler):
    def __init__(self, handle: Any, where: str):
        super().__init__(handle)
        self.where = where

    def find_class(self, module: str, name: str) -> Any:
        found = ALLOWED.get((module, name))
        if found is None:
            raise UnsafePickleError(f"{self.where} asks for {module}.{name}, which a data file may not name: "
                                    "only numpy arrays and dtypes and builtin containers are read from pickles; "
                                    "nothing was run")
        return found

    def persistent_load(self, pid: Any) -> Any:
        raise UnsafePickleError(f"{self.where} refers to a persistent object ({str(pid)[:40]!r}): not data")


def load_data_pickle(path: str | Path, data: bytes | None = None) -> Any:
    """The object pickled in ``path`` (or in ``data``, read from it), built from allowed types only."""
    where = display_path(path)
    try:
        raw = Path(path).read_bytes() if data is None else data
    except OSError as exc:
        raise DataError(f"{where} cannot be read: {exc.strerror or exc}") from None
    if not raw.startswith(b"\x80"):
        raise UnsafePickleError(f"{where} is not a pickle (protocol 2 or later): it starts with {raw[:8]!r}")
    try:
        return _DataUnpickler(io.BytesIO(raw), where).load()
    except UnsafePickleError:
        raise
    except (pickle.UnpicklingError, EOFError, ValueError, TypeError, AttributeError, IndexError,
            KeyError, MemoryError, OverflowError, UnicodeDecodeError) as exc:
        reason = "truncated" if isinstance(exc, EOFError) else f"{type(exc).__name__}: {exc}"
        raise UnsafePickleError(f"{where} is not a readable pickle ({reason})") from None
