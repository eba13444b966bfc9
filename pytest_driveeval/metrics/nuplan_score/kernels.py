"""The score's point-in-lane, distance and time-to-collision loops compiled with numba, where it is
installed; the numpy paths in :mod:`.lanes` and :mod:`.ttc` stay, and both give the same numbers bit
for bit: each kernel computes the numpy expressions of its caller in the same order (no fastmath, so
no fused multiply-adds), and the cosines and sines come in from numpy.

When: importing numba costs a process about half a second, more than scoring a handful of scenes
saves.  So the compiled paths run once numba is loaded anyway (the closed loop's engine loads it for
a large unroll), or once the numpy paths have cost the process that much more than the compiled ones
would have (rent until the rent paid equals the price, then buy; as sim.logreplay.jit decides).
"""
from __future__ import annotations

import importlib.util
import sys

import numpy as np

START_SECONDS = 0.5  # importing numba and starting its compiler (sim.logreplay.jit measured it)
#: what share of the numpy paths' time the compiled ones save (measured on real scenes: about 90 %)
SAVED_SHARE = 0.9


def _installed() -> bool:
    if "numba" in sys.modules:  # None there means imports of it are blocked
        return sys.modules["numba"] is not None
    return importlib.util.find_spec("numba") is not None


AVAILABLE = _installed()
_forgone = 0.0
_kernels = None


def wanted() -> bool:
    """Whether the next scene takes the compiled paths."""
    if not AVAILABLE:
        return False
    return sys.modules.get("numba") is not None or _forgone >= START_SECONDS


def spent_without(seconds: float) -> None:
    """A scene took ``seconds`` on the numpy paths."""
    global _forgone
    _forgone += SAVED_SHARE * seconds


def kernels():
    """The compiled kernels (:mod:`.kernels_jit`, whose import imports numba; each is compiled, or loaded
    from numba's cache, on its first call)."""
    global _kernels
    if _kernels is None:
        from . import kernels_jit

        _kernels = kernels_jit
    return _kernels
