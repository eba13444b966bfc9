"""A time limit per item that also stops a model which never returns.

Two ways out of a hang, because one of them alone is not enough:

* SIGALRM (POSIX, main thread) interrupts Python code: a policy that sleeps
  or loops in Python.  It cannot interrupt native code that holds no Python
  frame, such as a TorchScript ``while`` loop.
* ``guarded_call`` runs a model call on a helper thread and waits for it with
  the time that is left.  TorchScript releases the GIL, so the wait returns on
  time; the hung call is abandoned (it keeps a core busy until the session
  ends) and the item fails.

Engines say where they are with ``note(...)``, so the failure names the scene,
episode or frame and the step that never finished.
"""
from __future__ import annotations

import queue
import signal
import sys
import threading
import time
from contextlib import contextmanager
from typing import Any, Callable, Iterator

from .errors import DriveEvalError


class TimeLimitExceeded(DriveEvalError):
    """The item ran longer than its time limit."""


class _Limit:
    def __init__(self, seconds: float, label: str) -> None:
        self.seconds = seconds
        self.label = label
        self.ends = time.monotonic() + seconds
        self.where: dict[str, Any] = {}
        self.in_call = False

    def remaining(self) -> float:
        return self.ends - time.monotonic()

    def error(self, in_call: bool = False) -> TimeLimitExceeded:
        during = " in a model call that did not return" if in_call or self.in_call else ""
        where = ", ".join(f"{k} {v() if callable(v) else v}" for k, v in self.where.items())
        return TimeLimitExceeded(f"{self.label}: time limit of {self.seconds:g} s exceeded{during}"
                                 f"{f' at {where}' if where else ''} (TimeLimit in the scenario, or "
                                 "--driveeval-time-limit)")


_active: _Limit | None = None


class _Worker:
    """One daemon thread that runs model calls.  Daemon, because a call that
    never returns must not keep the process from exiting at the end."""

    def __init__(self) -> None:
        self.jobs: queue.SimpleQueue = queue.SimpleQueue()
        threading.Thread(target=self._serve, daemon=True, name="driveeval-model").start()

    def _serve(self) -> None:
        while True:
            fn, args, done, box = self.jobs.get()
            try:
                box.append((True, fn(*args)))
            except BaseException as exc:  # noqa: BLE001 - handed to the caller as is
                box.append((False, exc))
            done.set()

    def call(self, fn: Callable[..., Any], args: tuple, timeout: float) -> tuple[bool, list]:
        done, box = threading.Event(), []
        self.jobs.put((fn, args, done, box))
        return done.wait(timeout), box


_worker: _Worker | None = None


def note(**where: Any) -> None:
    """Where the evaluation is now (``scene=3, step=41``); cheap when no limit is set.  A value may
    be a callable, rendered only when the limit is hit: a step loop need not format every step."""
    if _active is not None:
        _active.where = where


def guarded_call(fn: Callable[..., Any], *args: Any) -> Any:
    """``fn(*args)``, given up on when the item's time runs out."""
    global _worker
    limit = _active
    if limit is None:
        return fn(*args)
    if _worker is None:
        _worker = _Worker()
    limit.in_call = True
    finished = False
    try:
        finished, box = _worker.call(_with_grad_mode(fn), args, max(limit.remaining(), 0.0))
    finally:
        limit.in_call = False
        if not finished:
            _worker = None  # it cannot be stopped; a fresh thread serves the next call
    if not finished:
        raise limit.error(in_call=True)
    ok, value = box[0]
    if not ok:
        raise value
    return value


def _with_grad_mode(fn: Callable[..., Any]) -> Callable[..., Any]:
    # torch's grad mode is per thread: the helper thread must see the caller's.
    torch = sys.modules.get("torch")
    if torch is None:
        return fn
    enabled = torch.is_grad_enabled()

    def call(*args: Any) -> Any:
        with torch.set_grad_enabled(enabled):
            return fn(*args)

    return call


@contextmanager
def time_limit(seconds: float | None, label: str) -> Iterator[None]:
    """Limit the block to ``seconds`` (None: no limit)."""
    global _active
    if not seconds:
        yield
        return
    limit = _Limit(float(seconds), label)
    use_alarm = (hasattr(signal, "setitimer") and threading.current_thread() is threading.main_thread()
                 # another timer (pytest-timeout's, say) is running: leave it alone
                 and signal.getitimer(signal.ITIMER_REAL)[0] == 0)
    previous = None
    if use_alarm:
        def on_alarm(signum, frame):
            raise limit.error()

        previous = signal.signal(signal.SIGALRM, on_alarm)
        signal.setitimer(signal.ITIMER_REAL, limit.seconds)
    _active = limit
    try:
        yield
    finally:
        _active = None
        if use_alarm:
            signal.setitimer(signal.ITIMER_REAL, 0)
            signal.signal(signal.SIGALRM, previous)
