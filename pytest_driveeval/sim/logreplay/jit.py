"""When the closed loop takes its numba paths (:mod:`.agents_jit`, :mod:`.logarrays_jit`).

Both paths give the same arrays bit for bit; only their cost differs.  A
process pays once, at its first compiled call, for importing numba and
starting its compiler (~0.5 s, even when the kernels come from numba's cache),
and that is more than a small unroll or a few scenes' loading saves: a
one-scene scenario under a time limit of a few seconds would spend most of it
there.  So each call site estimates what the compiled path would save on the work
it is about to do, and the process starts numba once those savings, summed
over the calls that went without it, reach the start's cost (renting until
the rent paid equals the price, then buying: never more than twice the best
choice made knowing the future).  Calls after that take the compiled paths.
:func:`start` starts it up front (benchmarks, long sessions).
"""
from __future__ import annotations

import importlib.util
import sys

__all__ = ["AVAILABLE", "START_SECONDS", "start", "wanted"]


def _installed() -> bool:
    if "numba" in sys.modules:  # None there means imports of it are blocked
        return sys.modules["numba"] is not None
    return importlib.util.find_spec("numba") is not None


AVAILABLE = _installed()
START_SECONDS = 0.5  # importing numba and starting its compiler, measured on a 2-core machine
_started = False
_forgone = 0.0  # what the numpy paths cost more so far in this process


def wanted(seconds_saved: float) -> bool:
    """Whether to take the compiled path for work the numpy path would do ``seconds_saved`` slower."""
    global _started, _forgone
    if not AVAILABLE:
        return False
    if not _started:
        _forgone += seconds_saved
        _started = _forgone >= START_SECONDS
    return _started


def start() -> bool:
    """Take the compiled paths from now on in this process (False: numba is not installed)."""
    global _started
    _started = AVAILABLE
    return _started
