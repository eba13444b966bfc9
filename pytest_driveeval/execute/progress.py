"""A one-line progress bar for chunks, drawn only where a person watches a terminal."""
from __future__ import annotations

from typing import TextIO

from pytest_driveeval.execute.chunks import Progress

__all__ = ["terminal_progress"]

_WIDTH = 30


def terminal_progress(stream: TextIO, label: str = "chunks") -> Progress | None:
    """A ``progress`` callback that redraws ``label  12/40 [#########.....]`` in place on
    ``stream``, or None when ``stream`` is not a terminal (a CI log gets no carriage returns)."""
    isatty = getattr(stream, "isatty", None)
    if not (isatty and isatty()):
        return None

    def draw(done: int, total: int) -> None:
        filled = _WIDTH * done // total if total else _WIDTH
        stream.write(f"\r{label} {done}/{total} [{'#' * filled}{'.' * (_WIDTH - filled)}]")
        if done == total:
            stream.write("\n")
        stream.flush()

    return draw
