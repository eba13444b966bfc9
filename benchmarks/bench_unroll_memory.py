"""Peak memory of a large unroll: 1,000 generated scenes x 250 frames.

Scenes are generated in memory (no zarr) and streamed through the engine in
chunks of the batch size, so the peak is one chunk's arrays plus the
per-frame records kept for every scene.  Prints peak RSS (target < 2 GB).

    python benchmarks/bench_unroll_memory.py [--scenes 1000] [--frames 250] [--batch 64] [--smoke]
"""
from __future__ import annotations

import argparse
import resource
import time

import numpy as np
import torch

from pytest_driveeval.policies.baselines import ConstantVelocityPolicy
from pytest_driveeval.sim.logreplay import UnrollConfig, scenes_from_arrays, stack_scenes, unroll
from pytest_driveeval.synth.scenegen import generate_scenes

SMOKE_HELP = "every part at tiny sizes in seconds, reference venvs skipped: checks the script runs, measures nothing"


def _peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # Linux reports KiB


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenes", type=int, default=1000)
    parser.add_argument("--frames", type=int, default=250)
    parser.add_argument("--batch", type=int, default=64)
    parser.add_argument("--smoke", action="store_true", help=SMOKE_HELP)
    args = parser.parse_args()
    if args.smoke:
        args.scenes, args.frames, args.batch = 4, 20, 2
        print("smoke run: tiny sizes; the figures mean nothing")
    torch.set_num_threads(1)
    policy = torch.jit.script(ConstantVelocityPolicy())
    cfg = UnrollConfig(drift_threshold=10.0, freeze_on_collision=True)
    print(f"baseline RSS {_peak_rss_mb():.0f} MB")
    gen_time = sim_time = harness = 0.0
    steps = collisions = errors = 0
    kept = []  # what a report needs of every scene: per-frame collision kinds and displacement
    for chunk, first in enumerate(range(0, args.scenes, args.batch)):
        n = min(args.batch, args.scenes - first)
        t0 = time.perf_counter()
        log = stack_scenes(scenes_from_arrays(generate_scenes(n, args.frames, seed=chunk)),
                           scene_ids=np.arange(first, first + n))
        gen_time += time.perf_counter() - t0
        result = unroll(log, policy, cfg)
        sim_time += result.total_time
        harness += result.harness_time
        steps += result.scene_steps
        collisions += int((result.collision_kind != 0).sum())
        errors += sum(e is not None for e in result.errors)
        kept.append((result.collision_kind, result.displacement_error.astype(np.float32)))
        del log, result
    print(f"{args.scenes} scenes x {args.frames} frames in chunks of {args.batch}: generation {gen_time:.1f} s, "
          f"unroll {sim_time:.1f} s (harness {harness:.1f} s, {steps / harness:,.0f} scene-steps/s), "
          f"{collisions} collision frames, {errors} errors")
    print(f"peak RSS {_peak_rss_mb():.0f} MB (target < 2048 MB)")


if __name__ == "__main__":
    main()
