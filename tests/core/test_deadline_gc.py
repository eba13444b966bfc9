"""The time limit's alarm is not lost in a garbage-collector callback: raised there, Python would
report it as unraisable and go on (hypothesis times every collection with one), so the alarm
fires again 10 ms later, which ends the block."""
from __future__ import annotations

import gc
import signal
import time

import pytest

from pytest_driveeval.core.deadline import TimeLimitExceeded, _in_gc_callback, time_limit

pytestmark = pytest.mark.skipif(not hasattr(signal, "setitimer"), reason="needs SIGALRM")


def test_a_frame_inside_a_gc_callback_is_recognised():
    seen = []

    def callback(phase, info):
        import sys
        seen.append(_in_gc_callback(sys._getframe()))

    gc.callbacks.append(callback)
    try:
        gc.collect()
    finally:
        gc.callbacks.remove(callback)
    assert seen and all(seen)
    import sys
    assert not _in_gc_callback(sys._getframe())


def test_an_alarm_during_a_gc_callback_still_ends_the_block(recwarn):
    calls = []

    def slow_callback(phase, info):
        calls.append(phase)
        if len(calls) == 1:
            time.sleep(0.3)  # the first alarm (at 0.1 s) lands in here; the next, 10 ms after it, outside

    gc.callbacks.append(slow_callback)
    started = time.monotonic()
    try:
        with pytest.raises(TimeLimitExceeded):
            with time_limit(0.1, "block"):
                gc.collect()  # its callback sleeps through the first alarm
                while time.monotonic() - started < 10:
                    sum(i for i in range(1000))  # Python work of its own after the collection
    finally:
        gc.callbacks.remove(slow_callback)
    assert 0.3 < time.monotonic() - started < 1.0  # after the callback, before the timer's next second
    assert not [w for w in recwarn if "unraisable" in str(w.message).lower() or "Exception ignored" in str(w.message)]
