"""Which executor an item runs its chunks on, and what the report says about where they ran.

A scenario's use case may carry an ``Executor`` section (``Evaluation.Executor``: the
use cases that split their work into chunks read it; see :mod:`pytest_driveeval.execute`).
The session option ``--driveeval-executor`` (ini ``driveeval_executor``) sets the executor
for every item: each key it gives replaces the scenario's, the keys it leaves out keep the
scenario's values (``--driveeval-executor ray`` keeps a scenario's ``ChunkSize``).  With
neither, or ``Kind: local`` without a ``ChunkSize``, the item runs locally exactly as it always
has: one batch, no chunks.  ``Kind: local`` with a ``ChunkSize`` runs the chunks a Ray run would
run, one after the other in this process: a chunk's result depends on its description alone, so
this reproduces a Ray run bit for bit, also for a model whose float32 arithmetic rounds
differently with the batch size (the shipped planning model: ~1e-6 m on its displacements).
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Callable, Sequence

from pytest_driveeval.core.errors import DriveEvalError, display_path
from pytest_driveeval.execute import ChunkError, ChunkRun, ExecutorSpec, UnreachableCluster, run_chunks
from pytest_driveeval.execute.reuse import reused

__all__ = ["ChunkLedger", "chunked_executor", "executor_details", "item_executor", "kept_model", "run_item_chunks"]

#: models a process keeps for its next chunks (an item's policies and a few items' worth)
KEPT_MODELS = 4


def kept_model(spec: str, base: str | None) -> Any:
    """The model a chunk names by its loading spec, loaded with the safe loaders, or the one an
    earlier chunk in this process loaded from the same spec and unchanged file.  A factory alone
    names no file whose change could be seen, so it is built for every chunk, as before."""
    from pytest_driveeval.policies.loading import load_model, model_files

    folder = Path(base) if base else None
    files = model_files(spec, folder)
    if not files:
        return load_model(spec, base=folder)
    return reused("model", (spec.strip(), base), files, lambda: load_model(spec, base=folder), keep=KEPT_MODELS)


def chunked_executor(ctx: Any, scenario_spec: ExecutorSpec | None) -> ExecutorSpec | None:
    """The executor of this item's chunks, or None for the use case's own one-batch path (the
    default, and a local executor that names no ChunkSize)."""
    session: ExecutorSpec | None = getattr(ctx, "executor", None)
    if session is None:
        spec = scenario_spec
    elif scenario_spec is None:
        spec = session
    else:
        spec = scenario_spec.model_copy(update={key: getattr(session, key) for key in session.model_fields_set})
    return None if spec is None or (spec.is_local and spec.ChunkSize is None) else spec


def item_executor(ctx: Any, scenario_spec: ExecutorSpec | None, loaded: Any, model: Any, what: str
                  ) -> tuple[ExecutorSpec | None, dict]:
    """(the executor of the item's chunks or None, why the item stays local although one was
    asked for: details for the report, or {}).  ``loaded`` is the object the use case loaded
    from a spec (which a worker can load again), ``model`` the one the item was given."""
    executor = chunked_executor(ctx, scenario_spec)
    if executor is None:
        return None, {}
    if loaded is not model:
        # A conftest.py fixture's model is a live object: nothing a worker could load safely.
        return None, {"executor": "local", "summary": (
            f"ran locally, not on {executor.describe()}: the {what} is the driveeval_model fixture's "
            "object (conftest.py), which has no loading spec a worker could use")}
    return executor, {}


def run_item_chunks(ctx: Any, spec: ExecutorSpec, work: Sequence[Any], task_fn: Callable[..., Any], label: str,
                    *, shared: Any = None, show_progress: bool = True) -> ChunkRun:
    """``run_chunks`` with the item's progress bar.  A chunk that failed on bad data or a broken
    model fails the item as the same error would locally (a DataError stays one), the chunk
    and worker named in its message."""
    make_progress = getattr(ctx, "progress", None) if show_progress else None
    progress = make_progress(label) if make_progress is not None else None
    try:
        return run_chunks(spec, work, task_fn, shared=shared, progress=progress)
    except UnreachableCluster as exc:
        raise UnreachableCluster(f"{_address_key(ctx)}: {exc}", exc.address) from None
    except ChunkError as exc:
        if isinstance(exc.cause, DriveEvalError):
            try:
                same_kind = type(exc.cause)(str(exc))
            except TypeError:  # an error built from more than a message (ScenarioError)
                raise exc from None
            raise same_kind from exc
        raise


def _address_key(ctx: Any) -> str:
    """Where the item's executor address was set: the session option, or the scenario's line."""
    session: ExecutorSpec | None = getattr(ctx, "executor", None)
    given = session.model_fields_set if session is not None else set()
    option = "--driveeval-executor / driveeval_executor"
    if "Address" in given:
        return f"{option}: Address"
    scenario = ctx.scenario
    line = scenario.line_of("Evaluation", "Executor", "Address")
    if line is not None:
        return f"{display_path(scenario.path)}:{line}: Evaluation.Executor.Address"
    line = scenario.line_of("Evaluation", "Executor")
    if "Kind" in given or line is None:
        return f"{option}: Kind: ray with Ray's default address"
    return f"{display_path(scenario.path)}:{line}: Evaluation.Executor"


def _placements(run: ChunkRun, describe: Callable[[int], str]) -> list[dict]:
    return [{"chunk": p.chunk, "work": describe(p.chunk), "host": p.hostname, "node": p.node_id, "pid": p.pid,
             "attempts": p.attempts, "seconds": round(p.seconds, 3), "wall_seconds": round(p.wall_seconds, 3)}
            for p in run.placements]


def executor_details(run: ChunkRun, describe: Callable[[int], str]) -> dict:
    """``details["executor"]`` of an outcome: the one-line summary and where each chunk ran."""
    return {"executor": run.executor, "summary": run.summary(), "chunks": _placements(run, describe)}


class ChunkLedger:
    """Where the chunks of many runs went, for an item that runs chunks more than once (a search's
    generations): the report keeps counts per node, not one line per chunk."""

    def __init__(self) -> None:
        self.runs = 0
        self.chunks = 0
        self.seconds = 0.0
        self.executor = ""
        self.per_node: dict[str, int] = {}
        self.retried = 0

    def add(self, run: ChunkRun) -> None:
        self.runs += 1
        self.chunks += len(run.placements)
        self.seconds += run.seconds
        self.executor = run.executor
        self.retried += len(run.retried)
        for p in run.placements:
            key = p.hostname if p.node_id == "local" else f"{p.hostname}/{p.node_id[:8]}"
            self.per_node[key] = self.per_node.get(key, 0) + 1

    def run(self, ctx: Any, spec: ExecutorSpec, work: Sequence[Any], task_fn: Callable[..., Any]) -> ChunkRun:
        """One of the item's repeated chunk runs (a search's generation), counted here; no
        progress bar: one per generation would scroll the terminal."""
        run = run_item_chunks(ctx, spec, work, task_fn, "", show_progress=False)
        self.add(run)
        return run

    def details(self) -> dict:
        hosts = ", ".join(f"{h}: {n}" for h, n in sorted(self.per_node.items()))
        retried = f"; {self.retried} chunk(s) retried after a worker died" if self.retried else ""
        summary = (f"{self.chunks} chunks in {self.runs} batch(es) on {self.executor} in {self.seconds:.1f} s, "
                   f"{len(self.per_node)} node(s) ({hosts}){retried}")
        return {"executor": self.executor, "summary": summary, "chunks_per_node": dict(sorted(self.per_node.items()))}
