"""A policy benchmark's episodes as chunks of seeds on Ray workers (issue 15).

Each chunk names what its worker needs and nothing live: the blueprint by name and
parameters (a CommonRoad scene by its file's absolute path, planning problem and traffic),
the chunk's seeds (and perturbation rows, for a search), and the policy by its loading
spec with the folder a relative path resolves against; the worker loads the policy
with the safe loaders and runs :func:`run_policy` on its seeds.  An episode depends on its
own seed alone (every baseline, and a model called on a batch whose rows do not mix, which
is what a policy is), so the merged arrays are those of one batch of every seed, bit for bit.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from pytest_driveeval.execute import ChunkRun, ExecutorSpec, split
from pytest_driveeval.usecases.executor import kept_model, run_item_chunks
from pytest_driveeval.usecases.policy_benchmark.config import BASELINES
from pytest_driveeval.usecases.policy_benchmark.evaluate import PolicyRun, run_policy

__all__ = ["COMMONROAD", "DEFAULT_CHUNK_SIZE", "EpisodeChunk", "EpisodeResults", "PolicySource", "chunk_blueprint",
           "episode_chunks", "run_episode_chunk", "run_policies_chunked"]

#: episodes per task unless the Executor section says otherwise: ~0.3 s of the shipped GNN's
#: merging episodes, against ~3 ms of building the blueprint on the worker; the policy (~1 s to load
#: an exported program) is loaded by a worker's first chunk of the item and kept (execute.reuse)
DEFAULT_CHUNK_SIZE = 64


@dataclass(frozen=True)
class PolicySource:
    """How a worker loads a policy: a baseline's name or a model spec, and the absolute folder
    a relative model path in it resolves against (the scenario's, or the working directory of
    --driveeval-model)."""

    spec: str
    base: str | None

    def load(self) -> Any:
        """The policy; a model file this process loaded for an earlier chunk and unchanged since
        serves again (a baseline is built afresh: it is cheap, and may keep state)."""
        from pytest_driveeval.usecases.policy_benchmark.baselines import baseline

        if self.spec in BASELINES:
            return baseline(self.spec)
        return kept_model(self.spec, self.base)


@dataclass(frozen=True)
class EpisodeChunk:
    policy: str                      # the policy's name in the scenario
    source: PolicySource
    blueprint: str
    params: tuple[tuple[str, Any], ...]   # make_blueprint's keyword arguments
    seeds: tuple[int, ...]
    agent_limit: int
    perturbation: tuple[tuple[float, ...], ...] | None = None   # one row per seed, or none

    def __repr__(self) -> str:
        # What a failure message names: a chunk's description is cut at 80 characters.
        perturbed = ", perturbed" if self.perturbation is not None else ""
        return f"{self.policy} seeds {self.seeds[0]}..{self.seeds[-1]}{perturbed}"


@dataclass(frozen=True)
class EpisodeResults:
    outcome: np.ndarray
    returns: np.ndarray
    steps: np.ndarray


#: EpisodeChunk.blueprint of a CommonRoad scene; its params are commonroad_scene's, with the file's
#: absolute ``path``, the ``problem`` id and the ``traffic``
COMMONROAD = "commonroad"


def chunk_blueprint(blueprint: Any, params: dict[str, Any]) -> tuple[str, dict[str, Any]]:
    """What a chunk names to rebuild ``blueprint`` on a worker: a blueprint's name and parameters, or
    a CommonRoad scene's file, planning problem and traffic with its parameters."""
    if getattr(blueprint, "problem", None) is None:
        return blueprint.name, params
    return COMMONROAD, {**params, "path": str(Path(blueprint.scenario.path).resolve()),
                        "problem": int(blueprint.problem.id), "traffic": blueprint.traffic}


def _rebuilt(name: str, params: dict[str, Any]) -> Any:
    if name == COMMONROAD:
        from pytest_driveeval.sim.commonroad_scene import commonroad_scene

        p = dict(params)
        return commonroad_scene(p.pop("path"), p.pop("problem"), p.pop("traffic"), **p)
    from pytest_driveeval.sim.blueprints import make_blueprint

    return make_blueprint(name, **params)


def run_episode_chunk(chunk: EpisodeChunk) -> EpisodeResults:
    """A chunk's episodes, on whichever process runs it (torch on one thread: run_policy sees to it)."""
    blueprint = _rebuilt(chunk.blueprint, dict(chunk.params))
    rows = None if chunk.perturbation is None else np.array(chunk.perturbation, dtype=np.float64)
    done = run_policy(blueprint, np.array(chunk.seeds, dtype=np.int64), chunk.source.load(), chunk.policy,
                      agent_limit=chunk.agent_limit, perturbation=rows)
    return EpisodeResults(done.outcome, done.returns, done.steps)


def episode_chunks(policy: str, source: PolicySource, blueprint: str, params: dict[str, Any], seeds: np.ndarray,
                   agent_limit: int, size: int, perturbation: np.ndarray | None = None) -> list[EpisodeChunk]:
    params_items = tuple(sorted(params.items()))
    return [EpisodeChunk(policy, source, blueprint, params_items, tuple(int(s) for s in seeds[part]), agent_limit,
                         None if perturbation is None else tuple(tuple(float(v) for v in row)
                                                                for row in perturbation[part]))
            for part in (slice(r.start, r.stop) for r in split(len(seeds), size))]


def merged(results: Sequence[EpisodeResults]) -> EpisodeResults:
    return EpisodeResults(*(np.concatenate([getattr(r, name) for r in results])
                            for name in ("outcome", "returns", "steps")))


def run_policies_chunked(ctx: Any, executor: ExecutorSpec, blueprint: Any, params: dict[str, Any],
                         seeds: np.ndarray, strata: np.ndarray, sources: dict[str, PolicySource],
                         agent_limit: int) -> tuple[dict[str, PolicyRun], ChunkRun, list[str]]:
    """Every policy of ``sources`` on every seed, all their chunks in one run (so the cluster is
    busy with the baselines' chunks too): a PolicyRun per policy as run_policy returns it, where
    the chunks ran, and what each chunk was."""
    size = executor.ChunkSize or DEFAULT_CHUNK_SIZE
    work: list[EpisodeChunk] = []
    spans: dict[str, slice] = {}
    for name, source in sources.items():
        chunks = episode_chunks(name, source, *chunk_blueprint(blueprint, params), seeds, agent_limit, size)
        spans[name] = slice(len(work), len(work) + len(chunks))
        work += chunks
    run = run_item_chunks(ctx, executor, work, run_episode_chunk, "chunks")
    runs = {}
    for name, span in spans.items():
        done = merged(run.results[span])
        runs[name] = PolicyRun(name, blueprint.name, np.asarray(seeds, dtype=np.int64), np.asarray(strata),
                               done.outcome, done.returns, done.steps)
    return runs, run, [repr(chunk) for chunk in work]
