"""A closed-loop item's scenes as chunks of scene indices on Ray workers (issue 15).

A chunk names the dataset by its path (a shared file system, or the same path on every
worker), its scene indices, the scenario's closed-loop section (plain pydantic data) and the
policy by its loading spec; the worker opens the dataset, loads the policy with the safe
loaders, unrolls and judges its scenes and draws the GIFs the scenario wants, and returns
the verdicts, the collision events and the GIFs as bytes.  Stacked scenes are padded to the
widest of their batch, so a chunk never returns its unroll: the driver merges per-scene
results only.  The engine keeps scenes apart (a batch-invariant policy gives the one-batch
run's figures bit for bit); a model's float32 arithmetic may round differently with the batch
size, which ``Kind: local`` with the same ChunkSize reproduces exactly.
"""
from __future__ import annotations

import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

from pytest_driveeval.execute import ExecutorSpec, split
from pytest_driveeval.usecases.closed_loop.config import ClosedLoopConfig
from pytest_driveeval.usecases.closed_loop.evaluate import SceneVerdict

__all__ = ["DEFAULT_CHUNK_SIZE", "SceneChunk", "SceneResults", "SearchChunk", "run_scene_chunk", "run_search_chunk",
           "scene_chunks", "search_chunks"]

#: scenes per task unless the Executor section says otherwise: a few seconds of the planning
#: model's unroll, against opening the dataset on the worker (the model and semantic map are
#: loaded by a worker's first chunk of the item and kept: execute.reuse)
DEFAULT_CHUNK_SIZE = 8


@dataclass(frozen=True)
class SceneChunk:
    dataset: str                 # the zarr's path, as the workers see it
    scenes: tuple[int, ...]
    config: ClosedLoopConfig     # Unroll, Conditions, Artefacts, ConstantVelocity: what the worker needs
    model: str                   # a baseline's name or a model spec
    base: str | None             # the folder a relative model path (and the semantic map) resolves against
    scenario_folder: str

    def __repr__(self) -> str:
        return f"scenes {self.scenes[0]}..{self.scenes[-1]} of {Path(self.dataset).name}"


@dataclass(frozen=True)
class SceneResults:
    verdicts: list[SceneVerdict]
    events: list[list[dict]]        # collision events per scene
    errors: list[str]               # the engine's message per scene ('' when none)
    gifs: dict[int, bytes]          # scene -> GIF, for the scenes the scenario animates


def _policy(chunk: SceneChunk) -> Any:
    from pytest_driveeval.usecases.closed_loop.baselines import BASELINES, baseline
    from pytest_driveeval.usecases.executor import kept_model

    if chunk.model in BASELINES:
        return baseline(chunk.model, chunk.config)
    return kept_model(chunk.model, chunk.base)


def run_scene_chunk(chunk: SceneChunk) -> SceneResults:
    """A chunk's scenes unrolled, judged and drawn, on whichever process runs it."""
    from pytest_driveeval.usecases.closed_loop.datasets import open_dataset
    from pytest_driveeval.sim.torch_threads import one_torch_thread
    from pytest_driveeval.usecases.closed_loop.config import replayed_agents
    from pytest_driveeval.usecases.closed_loop.artefacts import animated, scene_drawn_map, scene_gif
    from pytest_driveeval.usecases.closed_loop.evaluate import collision_events, judge_scene, unroll_scenes
    from pytest_driveeval.usecases.closed_loop.names import caption, scene_identity

    config, spec = chunk.config, chunk.config.Unroll
    dataset = open_dataset(chunk.dataset)
    from pytest_driveeval.usecases.closed_loop.raster_inputs import semantic_map_for

    semantic_map = semantic_map_for(spec.Inputs, dataset.path, chunk.scenario_folder, dataset, chunk.scenes,
                                    kept=True)
    ids = list(chunk.scenes)
    with one_torch_thread():  # as the design of run_chunks asks: the same float sums wherever it runs
        unroll = unroll_scenes(dataset, _policy(chunk), ids, **spec.unroll_options(),
                               agents=replayed_agents(spec.Agents), semantic_map=semantic_map)
    verdicts = [judge_scene(unroll, row, config.Conditions) for row in range(len(ids))]
    gifs: dict[int, bytes] = {}
    with tempfile.TemporaryDirectory(prefix="driveeval-chunk-") as folder:
        for row, verdict in enumerate(verdicts):
            if animated(config, verdict):
                # the scene's map from the dataset the worker opened
                path = scene_gif(Path(folder) / f"scene_{verdict.scene}.gif", unroll, row, verdict.scene,
                                 drawn_map=scene_drawn_map(dataset, verdict.scene), markers=verdict.markers,
                                 title=caption(verdict.scene, scene_identity(dataset, verdict.scene)))
                if path is not None:
                    gifs[verdict.scene] = path.read_bytes()
    return SceneResults(verdicts, [collision_events(unroll, row) for row in range(len(ids))],
                        [unroll.result.errors[row] for row in range(len(ids))], gifs)


def scene_chunks(dataset: str, ids: Sequence[int], config: ClosedLoopConfig, model: str, base: str | None,
                 scenario_folder: str, executor: ExecutorSpec) -> list[SceneChunk]:
    size = executor.ChunkSize or DEFAULT_CHUNK_SIZE
    return [SceneChunk(dataset, tuple(int(ids[i]) for i in part), config, model, base, scenario_folder)
            for part in split(len(ids), size)]


def merged(results: Sequence[SceneResults]) -> SceneResults:
    return SceneResults([v for r in results for v in r.verdicts], [e for r in results for e in r.events],
                        [m for r in results for m in r.errors], {s: g for r in results for s, g in r.gifs.items()})


@dataclass(frozen=True)
class SearchChunk:
    """Some of a robustness search generation's examples: ``scenes`` names the item's scenes (all
    of them, which the examples' cases index) and how to load them and the model."""

    scenes: SceneChunk
    examples: tuple   # search.engine.Example: (case, StartPerturbation)

    def __repr__(self) -> str:
        return f"{len(self.examples)} search example(s) on {Path(self.scenes.dataset).name}"


def run_search_chunk(chunk: SearchChunk) -> list:
    """The chunk's examples judged as the local search judges them (robustness.closed_loop_searchable)."""
    from pytest_driveeval.usecases.closed_loop.datasets import open_dataset
    from pytest_driveeval.sim.torch_threads import one_torch_thread
    from pytest_driveeval.usecases.closed_loop.config import replayed_agents
    from pytest_driveeval.usecases.closed_loop.robustness import closed_loop_searchable

    scenes = chunk.scenes
    dataset = open_dataset(scenes.dataset)
    searchable = closed_loop_searchable(scenes.config, dataset, _policy(scenes), list(scenes.scenes),
                                        replayed_agents(scenes.config.Unroll.Agents), show=None)
    with one_torch_thread():
        return searchable.evaluate_many(list(chunk.examples))


def search_chunks(scenes: SceneChunk, examples: Sequence[Any], executor: ExecutorSpec) -> list[SearchChunk]:
    size = executor.ChunkSize or DEFAULT_CHUNK_SIZE
    return [SearchChunk(scenes, tuple(examples[i] for i in part)) for part in split(len(examples), size)]
