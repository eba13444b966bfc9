"""A time limit that runs out while the main thread waits for a guarded model call ends the block
with TimeLimitExceeded, and the next block's calls still work: the alarm never interrupts the
wait's own locking (it once left a lock released twice: "release unlocked lock", reported as
the policy's error)."""
from __future__ import annotations

import signal

import pytest

from pytest_driveeval.core.deadline import TimeLimitExceeded, guarded_call, time_limit

pytestmark = pytest.mark.skipif(not hasattr(signal, "setitimer"), reason="needs SIGALRM")


def busy():
    return sum(i * i for i in range(300))


def test_a_limit_that_ends_during_guarded_calls_always_ends_the_block_as_a_time_limit():
    outcomes = {}
    for _ in range(500):
        calls = 0
        try:
            with time_limit(0.01, "block"):
                while True:
                    guarded_call(busy)
                    calls += 1
        except Exception as exc:  # noqa: BLE001 - the kind of exception is what is checked
            outcomes[type(exc).__name__] = outcomes.get(type(exc).__name__, 0) + 1
    assert outcomes == {"TimeLimitExceeded": 500}
    with time_limit(5, "after"):
        assert guarded_call(int, "7") == 7
