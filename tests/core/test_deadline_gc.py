"""The time limit's alarm is not lost where Python cannot raise: in a garbage-collector callback
(hypothesis times every collection with one), a finalizer or a weakref callback, Python would report
it as unraisable and go on, so the alarm fires again 10 ms later, which ends the block."""
from __future__ import annotations

import gc
import signal
import sys
import time
import weakref

import pytest

from pytest_driveeval.core.deadline import TimeLimitExceeded, time_limit

pytestmark = pytest.mark.skipif(not hasattr(signal, "setitimer"), reason="needs SIGALRM")


def _run_into_the_limit(start_the_slow_part) -> float:
    """Seconds from the start until the 0.1 s limit ended the block, whose slow part (0.3 s) runs
    where Python cannot raise; afterwards the block does Python work of its own for up to 10 s."""
    started = time.monotonic()
    with pytest.raises(TimeLimitExceeded):
        with time_limit(0.1, "block"):
            start_the_slow_part()
            while time.monotonic() - started < 10:
                sum(i for i in range(1000))
    return time.monotonic() - started


def _no_unraisable(recwarn) -> bool:
    return not [w for w in recwarn if "unraisable" in str(w.message).lower()
                or "Exception ignored" in str(w.message)]


def test_an_alarm_during_a_gc_callback_still_ends_the_block(recwarn):
    calls = []

    def slow_callback(phase, info):
        calls.append(phase)
        if len(calls) == 1:
            time.sleep(0.3)  # the first alarm (at 0.1 s) lands in here

    gc.callbacks.append(slow_callback)
    try:
        took = _run_into_the_limit(gc.collect)
    finally:
        gc.callbacks.remove(slow_callback)
    assert 0.3 < took < 1.0  # after the callback, before the timer's next second
    assert _no_unraisable(recwarn)


def test_an_alarm_during_a_finalizer_still_ends_the_block(recwarn):
    class SlowToDie:
        def __del__(self):
            time.sleep(0.3)

    def drop_one():
        SlowToDie()  # its refcount drops at once: __del__ runs here, and the alarm lands in it

    assert _run_into_the_limit(drop_one) < 1.0
    assert _no_unraisable(recwarn)


def test_an_alarm_during_a_weakref_callback_still_ends_the_block(recwarn):
    class Target:
        pass

    def drop_one():
        target = Target()
        drop_one.ref = weakref.ref(target, lambda ref: time.sleep(0.3))
        del target

    assert _run_into_the_limit(drop_one) < 1.0
    assert _no_unraisable(recwarn)


def test_other_unraisable_errors_still_reach_the_previous_hook():
    seen = []
    previous, sys.unraisablehook = sys.unraisablehook, seen.append
    try:
        class Broken:
            def __del__(self):
                raise ValueError("not ours")

        with time_limit(5, "block"):
            Broken()
        assert sys.unraisablehook == seen.append  # put back after the block
    finally:
        sys.unraisablehook = previous
    assert [type(u.exc_value) for u in seen] == [ValueError]
