"""A time limit per item that also stops a model which never returns.

Two ways out of a hang, because one of them alone is not enough:

* SIGALRM (POSIX, main thread) interrupts Python code: a policy that sleeps
  or loops in Python.  It fires again every second until the block ends, and
  ``note`` and ``guarded_call`` raise once the time is up, so code that catches
  the first interruption (a search that retries what raised) meets another.  It cannot interrupt native code that holds no Python
  frame, such as a TorchScript ``while`` loop.
* ``guarded_call`` runs a model call on a helper thread and waits for it with
  the time that is left.  TorchScript releases the GIL, so the wait returns on
  time; the hung call is abandoned (it keeps a core busy until the session
  ends) and the item fails.

A call left behind cannot be stopped, and it cannot be left to Python's exit
either: a daemon thread that wants the GIL back while the interpreter finalizes
is ended by ``pthread_exit``, whose unwinding through torch's C++ frames calls
``std::terminate`` (SIGABRT, exit status 134, whatever pytest said).  So once a
call was left behind, the process leaves at exit by ``os._exit`` with pytest's
own exit code, its output flushed (:func:`session_ended` records the code).

Engines say where they are with ``note(...)``, so the failure names the scene,
episode or frame and the step that never finished.
"""
from __future__ import annotations

import atexit
import logging
import os
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
    def __init__(self, seconds: float, label: str, source: str) -> None:
        self.seconds = seconds
        self.label = label
        self.source = source
        self.ends = time.monotonic() + seconds
        self.where: dict[str, Any] = {}
        self.in_call = False

    def remaining(self) -> float:
        return self.ends - time.monotonic()

    def error(self, in_call: bool = False) -> TimeLimitExceeded:
        during = " in a model call that did not return" if in_call or self.in_call else ""
        where = ", ".join(f"{k} {v() if callable(v) else v}" for k, v in self.where.items())
        return TimeLimitExceeded(f"{self.label}: time limit of {self.seconds:g} s exceeded{during}"
                                 f"{f' at {where}' if where else ''} ({self.source})")


_active: _Limit | None = None


class _Worker:
    """One daemon thread that runs model calls.  Daemon, because a call that
    never returns must not keep the process from exiting at the end."""

    def __init__(self) -> None:
        self.jobs: queue.SimpleQueue = queue.SimpleQueue()
        self.busy = False
        threading.Thread(target=self._serve, daemon=True, name="driveeval-model").start()

    def _serve(self) -> None:
        while True:
            fn, args, done, box = self.jobs.get()
            self.busy = True
            try:
                box.append((True, fn(*args)))
            except BaseException as exc:  # noqa: BLE001 - handed to the caller as is
                box.append((False, exc))
            self.busy = False
            done.set()

    def call(self, fn: Callable[..., Any], args: tuple, timeout: float) -> tuple[bool, list]:
        done, box = threading.Event(), []
        self.jobs.put((fn, args, done, box))
        return done.wait(timeout), box


_worker: _Worker | None = None
# Workers whose call was given up on; one still busy at exit holds the process (see the top).
_abandoned: list[_Worker] = []
# pytest's exit code of the outermost session of this process, once it ended (see session_ended).
_exit_code: int | None = None
#: the xdist worker id of this process, None in the controller or a session without xdist
_xdist_worker: str | None = None
_sessions_running = 0


def note(**where: Any) -> None:
    """Where the evaluation is now (``scene=3, step=41``); cheap when no limit is set.  A value may
    be a callable, rendered only when the limit is hit: a step loop need not format every step."""
    if _active is not None:
        _active.where = where
        if _active.remaining() <= 0:
            raise _active.error()


def guarded_call(fn: Callable[..., Any], *args: Any) -> Any:
    """``fn(*args)``, given up on when the item's time runs out."""
    global _worker
    limit = _active
    if limit is None:
        return fn(*args)
    if limit.remaining() <= 0:
        raise limit.error()
    if _worker is None:
        _worker = _Worker()
    limit.in_call = True
    finished = False
    try:
        finished, box = _worker.call(_with_grad_mode(fn), args, max(limit.remaining(), 0.0))
    finally:
        limit.in_call = False
        if not finished:
            _abandoned.append(_worker)
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
def time_limit(seconds: float | None, label: str, source: str = "") -> Iterator[None]:
    """Limit the block to ``seconds`` (None or 0: no limit); ``source`` says who set the limit and
    how to change it, for the message."""
    global _active
    if not seconds:
        yield
        return
    limit = _Limit(float(seconds), label, source)
    use_alarm = (hasattr(signal, "setitimer") and threading.current_thread() is threading.main_thread()
                 # another timer (pytest-timeout's, say) is running: leave it alone
                 and signal.getitimer(signal.ITIMER_REAL)[0] == 0)
    previous = previous_hook = None
    if use_alarm:
        def on_alarm(signum, frame):
            if limit.in_call:
                # The main thread only waits for the helper thread, and that wait ends on time by its
                # own timeout.  Raised inside the wait's locking (queue.put, Event.wait), the error
                # could leave a lock released twice ("release unlocked lock", 2 blocks in 300).
                return
            raise limit.error()

        def on_unraisable(unraisable):
            # The alarm landed where Python cannot raise: a garbage-collector callback (hypothesis
            # times every collection), a finalizer, a weakref callback.  Python reports the error
            # and goes on, so the block would run to the next second's alarm, or past it if that
            # one is lost too.  It fires again in 10 ms instead, by then out of there.
            if isinstance(unraisable.exc_value, TimeLimitExceeded) and _active is limit:
                signal.setitimer(signal.ITIMER_REAL, 0.01, 1.0)
                return
            previous_hook(unraisable)

        previous = signal.signal(signal.SIGALRM, on_alarm)
        previous_hook, sys.unraisablehook = sys.unraisablehook, on_unraisable
        # Again every second after the first: code that swallows the first interruption (a hypothesis
        # search retries and shrinks what raised) meets the next one.
        signal.setitimer(signal.ITIMER_REAL, limit.seconds, 1.0)
    _active = limit
    try:
        yield
    finally:
        _active = None
        if use_alarm:
            signal.setitimer(signal.ITIMER_REAL, 0)
            signal.signal(signal.SIGALRM, previous)
            if sys.unraisablehook is on_unraisable:  # unless someone replaced it since
                sys.unraisablehook = previous_hook


@contextmanager
def session() -> Iterator[None]:
    """Around a whole pytest session (``pytest_cmdline_main``): sessions nest when a test runs
    pytest in-process (pytester), and only the outermost one's exit code is the process's."""
    global _sessions_running
    _sessions_running += 1
    try:
        yield
    finally:
        _sessions_running -= 1


def session_finishing(exit_code: int, worker: str | None = None) -> None:
    """The outermost session's exit status at ``pytest_sessionfinish``: an xdist worker is shut
    down from outside after it, and never returns from ``pytest_cmdline_main``.  ``worker``: the
    xdist worker's id, whose exit code is its own and not the session's (the controller's)."""
    global _exit_code, _xdist_worker
    if _sessions_running == 1:
        _exit_code = int(exit_code)
        _xdist_worker = worker


def session_ended(exit_code: int) -> None:
    """Record pytest's exit code: the one the process leaves with if a call is stuck at exit."""
    global _exit_code
    if _sessions_running == 0:
        _exit_code = int(exit_code)


def stuck_calls() -> int:
    """Model calls given up on that still run on their threads."""
    return sum(worker.busy for worker in _abandoned)


def _leave_before_a_stuck_call_aborts() -> None:
    stuck = stuck_calls()
    if not stuck or _exit_code is None:
        return
    # On a line of its own: pytest's last line of progress ("[100%]") may not have ended yet on the
    # terminal this shares.  A worker's code is not the session's, so it names none.
    leaving = (f"xdist worker {_xdist_worker} leaves without waiting for them (the session's exit status is the "
               f"controller's)" if _xdist_worker else f"leaving with pytest's exit code {_exit_code} without waiting")
    sys.stderr.write(f"\npytest-driveeval: {stuck} model call(s) that never returned still run (given up on at "
                     f"their time limit); {leaving}\n")
    logging.shutdown()
    for stream in (sys.stdout, sys.stderr, sys.__stdout__, sys.__stderr__):
        try:
            stream.flush()
        except (AttributeError, OSError, ValueError):
            pass
    os._exit(_exit_code)


# Registered at import, before torch or Ray register theirs: atexit runs handlers last-in first-out,
# so theirs (Ray's shutdown, say) still run before this one leaves.
atexit.register(_leave_before_a_stuck_call_aborts)
