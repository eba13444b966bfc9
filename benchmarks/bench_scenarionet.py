"""Reading a real ScenarioNet scenario into arrays against unrolling it (issue 23's target: reading
a ScenarioNet scenario into arrays costs less than unrolling it).

Per scene, in the same run:

* read: the pickle through the safe unpickler into arrays (``read_scenario``), the scene in the
  l5kit layout the engine replays (``l5_scene``) and its map as the semantic map rasters draw
  (``scenario_map``): what a closed-loop run does once per scene;
* stack: ``stack_scenes`` of that one scene (the engine's padded arrays), printed beside it;
* unroll: the shipped planning model (fixtures/models/planning_model.pt2) driving the whole scene,
  one scene per batch, as bench_unroll.py times it: harness + model (``UnrollResult.total_time``).

Then all the scenes as a closed-loop item runs them, in one batch: reading every scene (and
stacking them) against unrolling them together, where the model's forwards are shared, so each
scene's share of the unroll is smaller than its unroll alone.

Each figure is the median of ``--repeats`` after one warm-up (page cache, numba kernels, torch's
first forwards).  The scenes: the repository's three (fixtures/scenarionet/nuscenes) and, when
present, the shared data's six (``--shared``, default ../shared/data/scenarionet/nuscenes beside
the clone, or DRIVEEVAL_SHARED_DATA).  Single-threaded like bench_unroll.py (``--threads``).
Nothing is asserted: the figures are printed.

    python benchmarks/bench_scenarionet.py [--repeats 5] [--steps N] [--threads 1] [--shared DIR] [--smoke]
"""
from __future__ import annotations

import argparse
import os
import statistics
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")  # before numpy and torch start their thread pools

import torch

from pytest_driveeval.io.scenarionet.scenarionet import read_scenario, scenario_files
from pytest_driveeval.io.scenarionet.scenarionet_l5 import l5_scene
from pytest_driveeval.io.scenarionet.scenarionet_map import scenario_map
from pytest_driveeval.policies.loading import load_model
from pytest_driveeval.sim.logreplay import UnrollConfig, jit, stack_scenes, unroll

REPO = Path(__file__).resolve().parents[1]
FIXTURES = REPO / "fixtures" / "scenarionet" / "nuscenes"
SHARED = Path(os.environ.get("DRIVEEVAL_SHARED_DATA", REPO.parent / "shared" / "data")) / "scenarionet" / "nuscenes"
MODEL = REPO / "fixtures" / "models" / "planning_model.pt2"
CONFIG = UnrollConfig(history_frames=10, future_frames=12, max_agents=30, agents_radius=35.0,
                      drift_threshold=10.0, freeze_on_collision=True)
SMOKE_HELP = "one scene, a few steps, one repeat: checks the script runs, measures nothing"


def read(path: Path):
    """The scene as the closed loop reads it: seconds, and the L5 scene."""
    t0 = time.perf_counter()
    source = read_scenario(path)
    scene = l5_scene(source)
    scenario_map(source)
    return time.perf_counter() - t0, scene


def stacked(scene):
    t0 = time.perf_counter()
    log = stack_scenes([scene])
    return time.perf_counter() - t0, log


def median_run(repeats: int, run, seconds):
    """The run with the median ``seconds(run())`` of ``repeats``, after a warm-up."""
    run()
    runs = sorted((run() for _ in range(repeats)), key=seconds)
    return runs[len(runs) // 2]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=5, help="timed runs per figure (median)")
    parser.add_argument("--steps", type=int, default=None, help="unroll steps per scene (default: to its end)")
    parser.add_argument("--threads", type=int, default=1, help="torch threads (the figures are comparable at 1)")
    parser.add_argument("--shared", default=str(SHARED), help="a folder of more scenes, used when present")
    parser.add_argument("--smoke", action="store_true", help=SMOKE_HELP)
    args = parser.parse_args()
    files = scenario_files(FIXTURES)
    if Path(args.shared).is_dir():
        files += [p for p in scenario_files(args.shared) if p.name not in {f.name for f in files}]
    else:
        print(f"{args.shared}: absent; the repository's {len(files)} scenes only")
    if args.smoke:
        files, args.repeats, args.steps = files[:1], 1, 5
        print("smoke run: one scene, 5 steps, one repeat; the figures mean nothing")
    torch.set_num_threads(args.threads)
    print(f"threads: torch {torch.get_num_threads()}, OMP_NUM_THREADS={os.environ['OMP_NUM_THREADS']}; "
          f"numba paths: {'on' if jit.start() else 'off'}")
    model = load_model(str(MODEL))
    config = UnrollConfig(**{**CONFIG.__dict__, "num_steps": args.steps})
    print(f"model {MODEL.relative_to(REPO)}; median of {args.repeats} after a warm-up; unroll = harness + model\n")
    print(f"{'scene':<40} {'MB':>5} {'frames':>6} {'agents':>7} {'ms read':>8} {'ms stack':>8} "
          f"{'ms unroll':>9} {'ms model':>8} {'read/unroll':>11}")
    ratios = []
    for path in files:
        first = lambda pair: pair[0]  # noqa: E731
        read_s, scene = median_run(args.repeats, lambda: read(path), first)
        stack_s, log = median_run(args.repeats, lambda: stacked(scene), first)
        res = median_run(args.repeats, lambda: unroll(log, model, config), lambda r: r.total_time)
        ratios.append(read_s / res.total_time)
        print(f"{path.stem.removeprefix('sd_nuscenes_v1.0-mini_'):<40} {path.stat().st_size / 1e6:5.2f} "
              f"{scene.num_frames:6d} {len(scene.agents):7d} {1e3 * read_s:8.1f} {1e3 * stack_s:8.1f} "
              f"{1e3 * res.total_time:9.1f} {1e3 * res.model_time:8.1f} {ratios[-1]:11.2f}")
    print(f"\nmedian read/unroll over {len(ratios)} scene(s): {statistics.median(ratios):.2f}x "
          f"(target < 1: {'met' if statistics.median(ratios) < 1 else 'NOT met'}; "
          f"worst scene {max(ratios):.2f}x)")

    def read_all():
        t0 = time.perf_counter()
        log = stack_scenes([read(path)[1] for path in files])
        return time.perf_counter() - t0, log

    read_s, log = median_run(args.repeats, read_all, first)
    res = median_run(args.repeats, lambda: unroll(log, model, config), lambda r: r.total_time)
    print(f"all {len(files)} scene(s) in one batch: read + stack {1e3 * read_s:.1f} ms vs unroll "
          f"{1e3 * res.total_time:.1f} ms (model {1e3 * res.model_time:.1f} ms): read/unroll "
          f"{read_s / res.total_time:.2f}x")


if __name__ == "__main__":
    main()
