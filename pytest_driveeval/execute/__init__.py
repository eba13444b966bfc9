"""Run one item's scenes or episodes as chunks, in this process or as Ray tasks on a cluster.

For whoever wires a use case to it
----------------------------------
1. Read the scenario's ``Executor`` section with :class:`ExecutorSpec` (a session option or
   ini key gives :func:`executor_from_option`'s spec; each key it gives replaces the scenario's).
2. Split the item's work into chunk descriptions, e.g. ``split(len(scenes), spec.ChunkSize or
   64)``.  A description is small, picklable and self-contained: file paths or object-store
   URIs of the data, the scene indices or episode seeds of the chunk, the item's seed, and
   the model's loading spec (the same string the scenario gives, loaded on the worker with
   the safe loaders, weights_only).  Never a live object: no open file, no model, no torch
   tensor, no generator whose state depends on the chunks before it.  Each chunk derives its
   randomness from the item's seed and its own indices (``np.random.default_rng((seed, first))``),
   never from a stream shared with other chunks, so a chunk's result does not depend on where
   or after what it ran.  Data loaded once on the driver and small enough to copy may go in
   ``shared`` instead (put in Ray's object store once, read by every task).
3. Pass a module-level ``task_fn(chunk)`` (``task_fn(chunk, shared)``) that loads what the
   description names (a model or map through :func:`reuse.reused`, so that a worker's next
   chunks of the item find it loaded while its files are unchanged), sets torch to one thread
   (so float sums are the same as a local run's), and returns plain data: numpy arrays,
   numbers, dataclasses of them; artefacts as bytes or as files it writes under a path the
   description gives.  On a real cluster the workers need this package installed (or
   ``RuntimeEnv: {py_modules: [...]}``).
4. ``run = run_chunks(spec, chunks, task_fn, progress=...)``; ``run.results`` is in chunk
   order whatever order they finished in, so merging is concatenation in that order, and the
   item's figures are computed from the merged arrays exactly as a local run computes them.
   ``run.summary()`` and ``run.placements`` say where each chunk ran (host, node, pid,
   attempts, seconds) for the report.
5. A chunk that raises comes back as :class:`ChunkError`: its message names the chunk and
   the worker, ``.cause`` is the chunk's own exception (a DataError or ModelError stays
   one), ``.results`` holds the chunks that finished.  A worker or node that dies costs a
   new attempt of its chunks (``Retries``), not the run.
6. Ray is optional (``pip install 'pytest-driveeval[ray]'``): only ``ray_path`` imports it.
   A cluster that does not answer raises :class:`UnreachableCluster` at once for every item
   after the first (one fast TCP probe of a host:port address per process, then ``ray.init``).
   :func:`disconnect` at the end of the session closes a connection this package opened and
   nothing else.
"""
from pytest_driveeval.execute.chunks import (ChunkError, ChunkRun, ExecutorError, Placement, Progress, UnreachableCluster,
                                             run_chunks, split)
from pytest_driveeval.execute.ray_path import disconnect
from pytest_driveeval.execute.spec import ExecutorSpec, executor_from_option

__all__ = ["ChunkError", "ChunkRun", "ExecutorError", "ExecutorSpec", "Placement", "Progress", "UnreachableCluster",
           "disconnect", "executor_from_option", "run_chunks", "split"]
