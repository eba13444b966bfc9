"""The oracle's own reader of ScenarioNet scenario files (pickles), for the nuplan-devkit venv.

A pickle names the callables that rebuild it and the standard unpickler imports and calls whatever
it names, so a data file could run any code.  This unpickler admits only what a scenario file of
numpy arrays in builtin containers needs: numpy's array reconstruction (``_reconstruct``,
``ndarray``, ``dtype``, ``scalar``, under numpy 1's ``numpy.core`` or numpy 2's ``numpy._core``
module names) and a few builtin containers; anything else is refused by name before it is imported.
It imports nothing from pytest_driveeval (the oracle must not share the project's reader).

    load_scenario(path) -> dict
"""
from __future__ import annotations

import builtins
import io
import os
import pickle
import stat
from pathlib import Path
from typing import Any

import numpy as np

try:  # numpy 2 (the project's python, where the tests read this module)
    from numpy._core import multiarray
except ImportError:  # numpy 1 (the oracle venv's)
    from numpy.core import multiarray

#: a scenario file is a few MB (nuScenes) to tens of MB (Waymo, nuPlan)
MAX_FILE_BYTES = 256 << 20

_NUMPY = {"_reconstruct": multiarray._reconstruct, "scalar": multiarray.scalar,
          "ndarray": np.ndarray, "dtype": np.dtype}
#: (module, name) -> what it rebuilds; numpy 2 writes numpy._core.multiarray, numpy 1 numpy.core.multiarray
ALLOWED = {**{(module, name): made for module in ("numpy.core.multiarray", "numpy._core.multiarray")
              for name, made in _NUMPY.items() if name != "ndarray" and name != "dtype"},
           ("numpy", "ndarray"): np.ndarray, ("numpy", "dtype"): np.dtype,
           **{("builtins", name): getattr(builtins, name)
              for name in ("set", "frozenset", "list", "dict", "tuple", "bytearray", "complex")}}


class RefusedPickle(ValueError):
    """A scenario file that names a callable the oracle does not admit, or is not a readable pickle."""


class _ScenarioUnpickler(pickle.Unpickler):
    def __init__(self, data: bytes, where: str):
        super().__init__(io.BytesIO(data))
        self._where = where

    def find_class(self, module: str, name: str) -> Any:
        made = ALLOWED.get((module, name))
        if made is None:
            raise RefusedPickle(f"{self._where}: the pickle asks for {module}.{name}; a scenario file needs only "
                                "numpy arrays and builtin containers, so it was not read (nothing it names was "
                                "imported)")
        return made

    def persistent_load(self, pid: Any) -> Any:
        raise RefusedPickle(f"{self._where}: the pickle asks for a persistent object ({pid!r}); refused")


def load_scenario(path: str | Path) -> dict:
    """The scenario dict of a ScenarioNet file: a regular file of at most MAX_FILE_BYTES, read with the
    restricted unpickler above."""
    path = Path(path)
    info = os.stat(path)
    if not stat.S_ISREG(info.st_mode):
        raise RefusedPickle(f"{path}: not a regular file; only regular files are read as data")
    if info.st_size > MAX_FILE_BYTES:
        raise RefusedPickle(f"{path}: {info.st_size} bytes, more than the {MAX_FILE_BYTES} a scenario file may be")
    data = path.read_bytes()
    try:
        scenario = _ScenarioUnpickler(data, str(path)).load()
    except RefusedPickle:
        raise
    except Exception as error:  # a truncated or garbled file
        raise RefusedPickle(f"{path}: not a readable pickle ({type(error).__name__}: {error})") from None
    if not isinstance(scenario, dict) or not {"tracks", "map_features", "metadata"} <= set(scenario):
        raise RefusedPickle(f"{path}: not a ScenarioNet scenario (a dict with tracks, map_features and metadata)")
    return scenario
