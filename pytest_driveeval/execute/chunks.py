"""Run a list of chunk descriptions through one function, locally or on Ray, results in chunk order."""
from __future__ import annotations

import os
import socket
import time
import traceback
from typing import Any, Callable, Sequence, TypeVar

from pytest_driveeval.execute.chunk_results import (ChunkError, ChunkRun, ExecutorError, Placement, Progress, Tally,
                                                    UnreachableCluster, describe_chunk, failure_message)
from pytest_driveeval.execute.spec import ExecutorSpec

__all__ = ["ChunkError", "ChunkRun", "ExecutorError", "Placement", "Progress", "UnreachableCluster", "describe_chunk",
           "run_chunks", "split"]

R = TypeVar("R")


def split(count: int, size: int) -> list[range]:
    """``count`` items as consecutive ranges of ``size`` (the last one shorter)."""
    if count < 0 or size < 1:
        raise ValueError(f"cannot split {count} items into chunks of {size}")
    return [range(start, min(start + size, count)) for start in range(0, count, size)]


def _top_level(task_fn: Callable) -> None:
    # A closure or lambda runs here but cannot be sent to a Ray worker by reference; refuse it
    # on both paths so that a use case that works locally also works on a cluster.
    qualname = getattr(task_fn, "__qualname__", "")
    if not callable(task_fn) or "<" in qualname or "." in qualname:
        raise TypeError(f"task_fn must be a module-level function (picklable by name), got {task_fn!r}")


def run_chunks(spec: ExecutorSpec, work: Sequence[Any], task_fn: Callable[..., R], *, shared: Any = None,
               progress: Progress | None = None) -> ChunkRun[R]:
    """``task_fn(chunk)`` (or ``task_fn(chunk, shared)`` when ``shared`` is given) for every chunk
    description in ``work``; the results come back in the order of ``work`` whatever order the
    chunks finish in.  Raises :class:`ChunkError` (with the finished chunks) when one fails."""
    _top_level(task_fn)
    work = list(work)
    if spec.is_local:
        return _run_local(work, task_fn, shared, progress)
    from pytest_driveeval.execute.ray_path import run_on_ray

    return run_on_ray(spec, work, task_fn, shared, progress)


def _run_local(work: list, task_fn: Callable, shared: Any, progress: Progress | None) -> ChunkRun:
    started = time.perf_counter()
    tally = Tally(len(work))
    host, pid = socket.gethostname(), os.getpid()
    if progress is not None:
        progress(0, len(work))
    for index, chunk in enumerate(work):
        begun = time.perf_counter()
        try:
            result = task_fn(chunk) if shared is None else task_fn(chunk, shared)
        except Exception as exc:
            message = failure_message(index, len(work), chunk, f"{host} pid {pid}", exc, traceback.format_exc())
            raise ChunkError(len(work), {index: message}, tally.results, tally.placements, exc) from exc
        seconds = time.perf_counter() - begun
        tally.done(index, result, Placement(index, "local", host, pid, 1, seconds, seconds), progress)
    return tally.finished("local", started)
