"""What ``Inputs.Map`` adds to a closed-loop step: l5kit's vectorised map keys, the route flags and the
goal, for every scene of the step at once, one core.

The real L5 scene on the map laid along its path with traffic lights (l5kit_oracle/compare_vectors.lit_map,
75 lanes abreast of the path every 15 m), stacked as ``--copies`` scenes stepping together; and the six
real nuScenes scenes (three places, each scene on its own map) where the shared data is.  Per case,
over every frame of the scenes, the best of ``--repeats`` passes: milliseconds per step for the map
inputs (closed_loop.map_inputs, what the engine calls), and as the reference measured in the same run,
the agent and ego inputs every vector policy already gets (sim.logreplay.inputs.build_batch), with
their ratio.  The map's one-off preparation (resampling, the route) is printed apart.

    python benchmarks/bench_map_inputs.py [--copies 64] [--repeats 3] [--smoke]
"""
from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import importlib.util  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import torch  # noqa: E402

from pytest_driveeval.io.l5.l5kit_zarr import L5Dataset  # noqa: E402
from pytest_driveeval.sim.logreplay import stack_scenes  # noqa: E402
from pytest_driveeval.sim.logreplay.inputs import build_batch  # noqa: E402
from pytest_driveeval.sim.logreplay.logarrays import window_columns  # noqa: E402
from pytest_driveeval.sim.logreplay.map_inputs import MapLimits  # noqa: E402
from pytest_driveeval.usecases.closed_loop.map_inputs import map_inputs, places  # noqa: E402
from pytest_driveeval.usecases.closed_loop.semantic_score_map import semantic_score_map  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
REAL_SCENE = ROOT / "fixtures" / "l5kit" / "single_scene.zarr"
SHARED = Path(os.environ.get("DRIVEEVAL_SHARED_DATA", ROOT.parent / "shared" / "data"))


def _lit_map(scene):
    spec = importlib.util.spec_from_file_location("compare_vectors", ROOT / "benchmarks" / "l5kit_oracle"
                                                  / "compare_vectors.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.lit_map(scene)


def measure(log, inputs, frames: range, repeats: int) -> tuple[float, float]:
    """(map inputs, agent inputs) in ms per step, best of ``repeats`` passes over ``frames``."""
    rows = np.arange(log.ego_xy.shape[0])
    candidates = window_columns(log, 10)
    best_map = best_agents = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        for t in frames:
            inputs(rows, t, log.ego_xy, log.ego_yaw)
        best_map = min(best_map, (time.perf_counter() - start) / len(frames))
        start = time.perf_counter()
        for t in frames:
            build_batch(log, rows, np.full(len(rows), t), log.ego_xy, log.ego_yaw, candidates=candidates)
        best_agents = min(best_agents, (time.perf_counter() - start) / len(frames))
    return 1e3 * best_map, 1e3 * best_agents


def report(name: str, scenes: int, prepare: float, map_ms: float, agent_ms: float) -> None:
    print(f"{name}: {scenes} scene(s), preparation {prepare:.2f} s once")
    print(f"  map inputs {map_ms:.2f} ms/step ({1e3 * map_ms / scenes:.0f} us per scene-step); "
          f"agent inputs (reference) {agent_ms:.2f} ms/step")
    print(f"  map / agent inputs: {map_ms / agent_ms:.2f}x")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--copies", type=int, default=64)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--smoke", action="store_true", help="2 copies, 10 frames, one pass")
    args = parser.parse_args()
    copies, repeats = (2, 1) if args.smoke else (args.copies, args.repeats)
    torch.set_num_threads(1)
    if args.smoke:
        print("smoke run: 2 copies, 10 frames, one pass; the figures mean nothing")

    scene = L5Dataset.open(REAL_SCENE).scene(0)
    start = time.perf_counter()
    smap = _lit_map(scene)
    log = stack_scenes([scene] * copies)
    score = semantic_score_map(smap, log.ego_xy[0, :scene.num_frames])
    inputs = map_inputs(MapLimits(), log, [scene] * copies, [smap], np.zeros(copies, np.int64), [score] * copies)
    prepare = time.perf_counter() - start
    frames = range(10) if args.smoke else range(scene.num_frames)
    report(f"real L5 scene x {copies}, laid map", copies, prepare, *measure(log, inputs, frames, repeats))

    nuscenes = SHARED / "scenarionet" / "nuscenes"
    if not nuscenes.is_dir():
        print(f"nuScenes: {nuscenes} absent, skipped")
        return
    from pytest_driveeval.io.scenarionet.scenarionet_l5 import ScenarioNetDataset
    from pytest_driveeval.usecases.closed_loop.score import dataset_score_maps

    dataset = ScenarioNetDataset.open(nuscenes)
    ids = list(range(dataset.num_scenes))[:2 if args.smoke else None]
    scenes = [dataset.scene(i) for i in ids]
    log = stack_scenes(scenes)
    score_maps = dataset_score_maps(dataset, ids)  # the score makes them anyway: not counted
    start = time.perf_counter()
    maps, place = places(dataset, ids, None)
    inputs = map_inputs(MapLimits(), log, scenes, maps, place, [score_maps[i] for i in ids])
    prepare = time.perf_counter() - start
    frames = range(10) if args.smoke else range(int(log.num_frames.min()))
    report(f"nuScenes, {len(ids)} real scenes, own maps", len(ids), prepare, *measure(log, inputs, frames, repeats))


if __name__ == "__main__":
    main()
