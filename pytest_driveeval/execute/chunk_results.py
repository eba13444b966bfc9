"""What a chunked run hands back, whichever path ran it: the results and placements so far, and the errors.

Shared by the local path (chunks) and the Ray path (ray_path), so neither imports the other's module for them.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, Callable, Generic, TypeVar

from pytest_driveeval.core.errors import DriveEvalError

__all__ = ["ChunkError", "ChunkRun", "ExecutorError", "Placement", "Progress", "Tally", "UnreachableCluster",
           "describe_chunk", "failure_message"]

R = TypeVar("R")
#: called with (chunks done, chunks in all), once with 0 before the first chunk ends
Progress = Callable[[int, int], None]

_DESCRIPTION_CHARS = 80


@dataclass(frozen=True)
class Placement:
    """Where and how one chunk ran: its last (successful or final) attempt."""

    chunk: int
    node_id: str          # Ray's node id; "local" in this process
    hostname: str
    pid: int
    attempts: int         # 1 unless a worker or node died under it
    seconds: float        # inside task_fn, on the worker
    wall_seconds: float   # from the last submission to the result back here: the cost of shipping it


@dataclass
class ChunkRun(Generic[R]):
    """The results of every chunk, in chunk order, and where each ran."""

    results: list[R]
    placements: list[Placement]
    executor: str
    seconds: float

    @property
    def nodes(self) -> set[str]:
        return {p.node_id for p in self.placements}

    @property
    def retried(self) -> list[int]:
        return [p.chunk for p in self.placements if p.attempts > 1]

    def summary(self) -> str:
        """One line for a report: how many chunks ran where."""
        per_host: dict[str, int] = {}
        for p in self.placements:
            key = p.hostname if p.node_id == "local" else f"{p.hostname}/{p.node_id[:8]}"
            per_host[key] = per_host.get(key, 0) + 1
        hosts = ", ".join(f"{h}: {n}" for h, n in sorted(per_host.items()))
        retried = f"; chunks retried after a worker died: {self.retried}" if self.retried else ""
        return (f"{len(self.placements)} chunks on {self.executor} in {self.seconds:.1f} s, "
                f"{len(per_host)} node(s) ({hosts}){retried}")


class ExecutorError(DriveEvalError):
    """The executor cannot run at all: Ray missing, no cluster at the address."""


class UnreachableCluster(ExecutorError):
    """No Ray cluster answers at the executor's address (``address``: as the spec gives it, or None
    for Ray's default); the item that asked for it can name the key that set it."""

    def __init__(self, message: str, address: str | None):
        super().__init__(message)
        self.address = address


class ChunkError(DriveEvalError):
    """A chunk failed: its function raised, or its worker died more often than Retries allows.

    The chunks that finished are not lost: ``results`` maps their index to their result,
    ``placements`` says where they ran; ``failures`` maps each failed chunk to its message.
    ``cause`` is the first failed chunk's own exception where there is one.
    """

    def __init__(self, total: int, failures: dict[int, str], results: dict[int, Any],
                 placements: dict[int, Placement], cause: BaseException | None = None):
        self.total = total
        self.failures = dict(sorted(failures.items()))
        self.results = results
        self.placements = placements
        self.cause = cause
        self.chunk = next(iter(self.failures))
        kept = f" ({len(results)} of {total} chunks finished and are kept)" if results else ""
        if len(self.failures) == 1:
            first, _, rest = self.failures[self.chunk].partition("\n")
            super().__init__(first + kept + ("\n" + rest if rest else ""))
        else:
            super().__init__(f"{len(self.failures)} chunks failed{kept}:\n" + "\n".join(self.failures.values()))


def describe_chunk(index: int, total: int, chunk: Any) -> str:
    text = repr(chunk)
    if len(text) > _DESCRIPTION_CHARS:
        text = text[:_DESCRIPTION_CHARS - 3] + "..."
    return f"chunk {index} of {total} ({text})"


def failure_message(index: int, total: int, chunk: Any, where: str, exc: BaseException, tb: str | None) -> str:
    """What went wrong in one chunk.  A DriveEvalError is shown without a traceback, so when
    the cause is a bug rather than the user's data or model the message carries the traceback."""
    head = f"{describe_chunk(index, total, chunk)} failed on {where}: {type(exc).__name__}: {exc}"
    if tb and not isinstance(exc, DriveEvalError):
        head += "\n" + tb.rstrip()
    return head


@dataclass
class Tally:
    """What a run has collected so far, whichever path runs it."""

    total: int
    results: dict[int, Any] = field(default_factory=dict)
    placements: dict[int, Placement] = field(default_factory=dict)

    def done(self, index: int, result: Any, placement: Placement, progress: Progress | None) -> None:
        self.results[index] = result
        self.placements[index] = placement
        if progress is not None:
            progress(len(self.results), self.total)

    def finished(self, executor: str, started: float) -> ChunkRun:
        return ChunkRun([self.results[i] for i in range(self.total)],
                        [self.placements[i] for i in range(self.total)], executor, time.perf_counter() - started)
