"""The time limit's alarm is not lost where Python cannot raise: in a garbage-collector callback
(hypothesis times every collection with one), a finalizer or a weakref callback, Python would report
it as unraisable and go on, so the alarm fires again 10 ms later, which ends the block."""
from __future__ import annotations

import gc
import os
import re
import signal
import subprocess
import sys
import time
import weakref

import pytest

from conftest import REPO_ROOT

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


GC_CALLBACK_CASE = """
import gc, time
from pytest_driveeval.core.deadline import TimeLimitExceeded, time_limit

calls = []

def slow_callback(phase, info):
    calls.append(phase)
    if len(calls) == 1:
        time.sleep(0.3)  # the first alarm (at 0.1 s) lands in here

gc.callbacks.append(slow_callback)
started = time.monotonic()
try:
    with time_limit(0.1, "block"):
        gc.collect()
        while time.monotonic() - started < 10:
            sum(i for i in range(1000))
except TimeLimitExceeded:
    print(f"ended after {time.monotonic() - started:.3f} s")
"""


def test_an_alarm_during_a_gc_callback_still_ends_the_block():
    # In a fresh interpreter: in the suite's own process the collections of other tests' garbage (and
    # hypothesis's callbacks) make when the first alarm lands a matter of chance.
    done = subprocess.run([sys.executable, "-c", GC_CALLBACK_CASE], capture_output=True, text=True, timeout=60,
                          env={**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(REPO_ROOT),
                                                                                         os.environ.get("PYTHONPATH")]))})
    assert done.returncode == 0, done.stderr
    took = float(re.fullmatch(r"ended after ([0-9.]+) s\n", done.stdout).group(1))
    # the alarm ends the callback's sleep where it lands; the error is lost there and fires again 10 ms
    # later: well before the timer's next second
    assert took < 1.0
    assert "Exception ignored" not in done.stderr


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
