"""One obstacle_segmentation frame: 200k points, 20 boxes and the non-detection area.

Prints the median time of ``evaluate_cloud`` (target <= 0.3 ms on one core) with
each kernel (numba, the default where installed, and numpy), and its ratios to two
references of the same run: what perception_eval does (for each box and for the
area, a crossing-number point-in-polygon test over all points, numpy over points,
a Python loop over polygon vertices, boxes removed from the area's points one
after another), and reading the cloud's bytes once (numpy's OR over them as
uint64: the memory traffic no kernel avoids).  The kernels and the read are timed
in alternation, so all see the same load.
Run: ``taskset -c 0 python benchmarks/bench_obstacle_frame.py [--smoke]``.
"""
from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")  # one core, as the target says

import numpy as np  # noqa: E402

from pytest_driveeval.metrics import cloud_jit  # noqa: E402
from pytest_driveeval.metrics.pointcloud import Area, BoxSet, box_corners_3d, crop_reference, evaluate_cloud  # noqa

N_POINTS, N_BOXES, REPEAT = 200_000, 20, 101
SMOKE_HELP = "every part at tiny sizes in seconds, reference venvs skipped: checks the script runs, measures nothing"
AREA = np.array([[10.0, 1.5], [10.0, -1.5], [0.0, -1.5], [0.0, 1.5]])


def frame(seed: int = 0, n_points: int = N_POINTS):
    """A lidar-like obstacle cloud (denser near the sensor) as Autoware publishes it: XYZIRC, float32."""
    rng = np.random.default_rng(seed)
    dtype = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "u1"), ("return_type", "u1"),
                      ("channel", "<u2")])
    cloud = np.zeros(n_points, dtype)
    r = rng.exponential(18.0, n_points) + 2.0
    th = rng.uniform(-np.pi, np.pi, n_points)
    cloud["x"], cloud["y"] = r * np.cos(th), r * np.sin(th)
    cloud["z"] = rng.uniform(-0.3, 3.0, n_points)
    centers = np.c_[rng.uniform(-50, 50, N_BOXES), rng.uniform(-30, 30, N_BOXES), rng.uniform(0.7, 1.0, N_BOXES)]
    sizes = np.c_[rng.uniform(1.6, 2.6, N_BOXES), rng.uniform(3.5, 12.0, N_BOXES), rng.uniform(1.4, 3.2, N_BOXES)]
    boxes = BoxSet.from_ground_truth(centers, sizes, rng.uniform(-np.pi, np.pi, N_BOXES), 1.0, 1.2)
    return cloud, boxes, Area(AREA, 0.0, 1.5)


def reference(xyz: np.ndarray, boxes: BoxSet) -> tuple[list[int], int]:
    counts = [len(crop_reference(xyz, corners)) for corners in box_corners_3d(boxes)]
    area = crop_reference(xyz, [(x, y, 0.0) for x, y in AREA] + [(x, y, 1.5) for x, y in AREA])
    for corners in box_corners_3d(boxes):
        area = crop_reference(area, corners, inside=False)
    return counts, len(area)


def median_ms(fns: dict, repeat: int) -> dict:
    """Median milliseconds of each callable, calling them in turn ``repeat`` times."""
    times = {name: [] for name in fns}
    for _ in range(repeat):
        for name, fn in fns.items():
            t0 = time.perf_counter()
            fn()
            times[name].append(time.perf_counter() - t0)
    return {name: 1e3 * float(np.median(t)) for name, t in times.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--smoke", action="store_true", help=SMOKE_HELP)
    args = parser.parse_args()
    n_points, repeat, reference_repeat = (N_POINTS, REPEAT, 11) if not args.smoke else (2_000, 3, 1)
    if args.smoke:
        print("smoke run: tiny sizes; the figures mean nothing")
    cloud, boxes, area = frame(n_points=n_points)
    xyz = np.stack([cloud["x"], cloud["y"], cloud["z"]], axis=1).astype(np.float64)
    kernels = ["numba", "numpy"] if cloud_jit.AVAILABLE else ["numpy"]
    t0 = time.perf_counter()
    results = {k: evaluate_cloud(cloud, boxes, area, kernel=k) for k in kernels}
    first_call = time.perf_counter() - t0  # numba: compiling, or loading its on-disk cache
    ref_counts, ref_area = reference(xyz, boxes)
    for k, ours in results.items():
        assert ours.counts.tolist() == ref_counts and len(ours.area_points) == ref_area, f"{k} differs"
    raw = cloud.view(np.uint64)
    timed = {k: (lambda k=k: evaluate_cloud(cloud, boxes, area, kernel=k)) for k in kernels}
    timed["read"] = lambda: np.bitwise_or.reduce(raw)
    fast = median_ms(timed, repeat)
    slow = median_ms({"reference": lambda: reference(xyz, boxes)}, reference_repeat)["reference"]
    print(f"obstacle frame: {n_points} points, {N_BOXES} boxes + area; {results[kernels[0]].candidates} candidate points")
    for k in kernels:
        print(f"  evaluate_cloud, {k} kernel: median {fast[k]:.3f} ms   (target <= 0.3 ms)   "
              f"speed-up {slow / fast[k]:.0f}x over the reference, {fast[k] / fast['read']:.1f}x the read")
    print(f"  reference (perception_eval-like): median {slow:.1f} ms")
    print(f"  reading the cloud once ({raw.nbytes / 1e6:.1f} MB): median {fast['read']:.3f} ms")
    print(f"  first calls (numba compiles or loads its cache): {first_call:.1f} s")


if __name__ == "__main__":
    main()
