"""One obstacle_segmentation frame: 200k points, 20 boxes and the non-detection area.

Prints the median time of ``evaluate_cloud`` (target <= 2 ms on one core) and
its ratio to a reference doing what perception_eval does: for each box and for
the area, a crossing-number point-in-polygon test over all points (numpy over
points, a Python loop over polygon vertices), boxes removed from the area's
points one after another.  Run: ``python benchmarks/bench_obstacle_frame.py``.
"""
from __future__ import annotations

import os
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")  # one core, as the target says

import numpy as np  # noqa: E402

from pytest_driveeval.metrics.pointcloud import Area, BoxSet, box_corners_3d, crop_reference, evaluate_cloud  # noqa

N_POINTS, N_BOXES, REPEAT = 200_000, 20, 101
AREA = np.array([[10.0, 1.5], [10.0, -1.5], [0.0, -1.5], [0.0, 1.5]])


def frame(seed: int = 0):
    """A lidar-like obstacle cloud (denser near the sensor) as Autoware publishes it: XYZIRC, float32."""
    rng = np.random.default_rng(seed)
    dtype = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "u1"), ("return_type", "u1"),
                      ("channel", "<u2")])
    cloud = np.zeros(N_POINTS, dtype)
    r = rng.exponential(18.0, N_POINTS) + 2.0
    th = rng.uniform(-np.pi, np.pi, N_POINTS)
    cloud["x"], cloud["y"] = r * np.cos(th), r * np.sin(th)
    cloud["z"] = rng.uniform(-0.3, 3.0, N_POINTS)
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


def median_ms(fn, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return 1e3 * float(np.median(times))


def main() -> None:
    cloud, boxes, area = frame()
    xyz = np.stack([cloud["x"], cloud["y"], cloud["z"]], axis=1).astype(np.float64)
    ours = evaluate_cloud(cloud, boxes, area)
    ref_counts, ref_area = reference(xyz, boxes)
    assert ours.counts.tolist() == ref_counts and len(ours.area_points) == ref_area, "results differ"
    fast = median_ms(lambda: evaluate_cloud(cloud, boxes, area), REPEAT)
    slow = median_ms(lambda: reference(xyz, boxes), 11)
    print(f"obstacle frame: {N_POINTS} points, {N_BOXES} boxes + area; {ours.candidates} candidate points")
    print(f"  vectorised (evaluate_cloud): median {fast:.2f} ms   (target <= 2 ms)")
    print(f"  reference (perception_eval-like): median {slow:.1f} ms")
    print(f"  speed-up: {slow / fast:.0f}x   (target >= 10x)")


if __name__ == "__main__":
    main()
