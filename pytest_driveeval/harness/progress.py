"""How far a long item is, on one status line, where a person watches a terminal.

The line is drawn right of the cursor and the cursor is put back where it was (ANSI save and
restore, no wrapping), so pytest's own dots and names continue as if nothing were there, and
it is erased when the item ends.  An xdist worker cannot write to the controller's terminal
writer; it writes to the terminal it inherited as stderr, so under ``-n 2`` the line shows
whichever worker drew last, prefixed with its id.  Nothing is drawn when pytest's output is no
terminal (a CI log, a pipe), when ``CI`` is set, or for ``TERM=dumb``.
"""
from __future__ import annotations

import os
import sys
import time
from typing import Callable

import pytest

__all__ = ["StatusLine", "item_progress", "open_terminal", "close_terminal", "share_with_worker"]

_FD_KEY = pytest.StashKey["int | None"]()
_WORKER_INPUT = "driveeval_status_line"
_WIDTH = 20
#: redraws of one line at most this often: a 40 s unroll of 400 steps needs no 400 writes
INTERVAL = 0.2

SAVE, RESTORE, NO_WRAP, WRAP, ERASE_RIGHT = "\x1b7", "\x1b8", "\x1b[?7l", "\x1b[?7h", "\x1b[K"


def _watched(fd: int) -> bool:
    return os.isatty(fd) and not os.environ.get("CI") and os.environ.get("TERM") != "dumb"


def open_terminal(config: pytest.Config) -> None:
    """Decide once, at configure (output capture is off then), where status lines go: a copy of
    the terminal's descriptor, which the capture of each test's output does not redirect."""
    worker = getattr(config, "workerinput", None)
    if worker is not None:
        # stdout carries xdist's messages; stderr is the terminal the controller inherited.
        fd = 2 if worker.get(_WORKER_INPUT) and _watched(2) else None
    else:
        fd = sys.stdout.fileno() if _stdout_fd_watched() else None
    config.stash[_FD_KEY] = os.dup(fd) if fd is not None else None


def _stdout_fd_watched() -> bool:
    try:
        return _watched(sys.stdout.fileno())
    except (AttributeError, OSError, ValueError):  # a stdout without a descriptor
        return False


def close_terminal(config: pytest.Config) -> None:
    fd = config.stash.get(_FD_KEY, None)
    if fd is not None:
        os.close(fd)
        config.stash[_FD_KEY] = None


def share_with_worker(config: pytest.Config, workerinput: dict) -> None:
    """Tell an xdist worker whether the person running pytest watches a terminal."""
    workerinput[_WORKER_INPUT] = config.stash.get(_FD_KEY, None) is not None


class StatusLine:
    """``label: what done/total [####......]`` drawn by ``write`` and erased by ``clear``."""

    def __init__(self, write: Callable[[str], None], label: str, clock: Callable[[], float] = time.monotonic):
        self.write = write
        self.label = label
        self.clock = clock
        self.drawn_at: float | None = None

    def update(self, what: str, done: int, total: int) -> None:
        now = self.clock()
        if self.drawn_at is not None and now - self.drawn_at < INTERVAL and done < total:
            return
        self.drawn_at = now
        total = max(total, done)
        filled = _WIDTH * done // total if total else _WIDTH
        text = f"  {self.label}: {what} {done}/{total} [{'#' * filled}{'.' * (_WIDTH - filled)}]"
        self.write(SAVE + NO_WRAP + text + ERASE_RIGHT + WRAP + RESTORE)

    def clear(self) -> None:
        if self.drawn_at is not None:
            self.write(ERASE_RIGHT)
            self.drawn_at = None

    def progress(self, what: str) -> Callable[[int, int], None]:
        """A ``(done, total)`` callback for the loop over ``what`` (steps, episodes, ...)."""
        return lambda done, total: self.update(what, done, total)


def item_progress(item: pytest.Item) -> StatusLine | None:
    """The status line of ``item``, or None where no one watches a terminal."""
    fd = item.config.stash.get(_FD_KEY, None)
    if fd is None:
        return None
    worker = getattr(item.config, "workerinput", None)
    # The node id, not the name: four files of the demo share closed_loop[nuscenes_boston].
    label = f"[{worker['workerid']}] {item.nodeid}" if worker is not None else item.nodeid

    def write(text: str) -> None:
        try:
            os.write(fd, text.encode("utf-8", "replace"))
        except OSError:  # the terminal went away: the run goes on without its status line
            pass

    return StatusLine(write, label)
