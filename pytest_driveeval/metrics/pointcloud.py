"""Point-cloud geometry of the obstacle_segmentation evaluation.

One frame asks two questions of every point: which (scaled) ground-truth boxes
hold it, and does it lie in the non-detection area (a prism over a polygon,
clipped to road lanelets, minus every box).  ``evaluate_cloud`` answers both, in
``cloud_jit`` (numba) or ``cloud_numpy``: a grid over the boxes and the area flags
the few points worth an exact float64 test.  ``crop_reference`` is the rule as
perception_eval writes it, kept as the oracle of tests and benchmarks.

Semantics follow perception_eval's sensing evaluation: a box is scaled in x/y
only, by ``box_scale_0m + (box_scale_100m - box_scale_0m) * d / 100`` with d the
3-D distance of its centre from base_link; z spans centre +- height / 2.
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from .cloud_types import Area, BoxSet, CloudCounts, box_scale, xyz_columns

__all__ = ["BoxSet", "Area", "CloudCounts", "box_scale", "xyz_columns", "evaluate_cloud", "crop_reference", "box_corners_3d"]


def evaluate_cloud(points: np.ndarray, boxes: BoxSet, area: Area | None = None,
                   kernel: str | None = None) -> CloudCounts:
    """Points per box, nearest point per box, and the points failing the non-detection area.

    ``kernel``: "numba" (compiled, the default when numba is installed) or "numpy";
    both give the same result, point for point."""
    from . import cloud_jit, cloud_numpy  # here, so that numba loads only once a cloud is evaluated

    if kernel not in (None, "numba", "numpy"):
        raise ValueError(f"kernel must be 'numba' or 'numpy', not {kernel!r}")
    if kernel == "numba" and not cloud_jit.AVAILABLE:
        raise ImportError("kernel='numba' needs numba: pip install 'pytest-driveeval[obstacle]'")
    x = xyz_columns(points)[0]
    nb = len(boxes)
    fields = (("centre", boxes.centers), ("size", boxes.half), ("yaw", boxes.yaws))
    # Non-finite boxes would make the grids garbage.  NaN and inf survive a sum (a finite
    # sum that overflows only costs the look below); three sums cost a third of the checks.
    if not math.isfinite(float(boxes.centers.sum()) + float(boxes.half.sum()) + float(boxes.yaws.sum())):
        for name, values in fields:
            bad = np.flatnonzero(~np.isfinite(values.reshape(nb, -1 if nb else 1)).all(axis=1))
            if len(bad):
                raise ValueError(f"box {int(bad[0])} has a non-finite {name}: {values[bad[0]]}")
    use_area = area is not None and not area.empty
    if (not nb and not use_area) or len(x) == 0:
        return CloudCounts(np.zeros(nb, dtype=np.int64), np.full((nb, 3), np.nan), np.zeros((0, 3)))
    impl = cloud_jit if (kernel or ("numba" if cloud_jit.AVAILABLE else "numpy")) == "numba" else cloud_numpy
    return impl.evaluate(points, boxes, area if use_area else None)


# -- reference: what perception_eval does, for the benchmark and cross-checks ------------
def box_corners_3d(boxes: BoxSet) -> list[list[tuple[float, float, float]]]:
    """perception_eval's 8-corner prism (upper footprint, then lower) per box."""
    out = []
    for fp, c, h in zip(boxes.footprints(), boxes.centers, boxes.half[:, 2]):
        upper = [(float(px), float(py), float(c[2] + h)) for px, py in fp]
        lower = [(float(px), float(py), float(c[2] - h)) for px, py in fp]
        out.append(upper + lower)
    return out


def crop_reference(points: np.ndarray, area: Sequence[Sequence[float]], inside: bool = True) -> np.ndarray:
    """perception_eval's crop_pointcloud: numpy over points, Python over polygon vertices."""
    n = len(area) // 2
    zs = [p[2] for p in area]
    poly = list(area[:n]) + [area[0]]
    count = np.zeros(points.shape[0], dtype=np.uint8)
    px, py = points[:, 0], points[:, 1]
    # As in points_in_polygon: an edge's overflow to +-inf is the limit of its crossing, not an error.
    with np.errstate(over="ignore"):
        for i in range(n):
            p, q = poly[i], poly[i + 1]
            flags = ((p[1] <= py) & (q[1] > py)) | ((p[1] > py) & (q[1] <= py))
            vt = (py - p[1]) / (q[1] - p[1]) if q[1] != p[1] else px
            flags &= px < p[0] + vt * (q[0] - p[0])
            count[flags] += 1
    mask = (count % 2 != 0) & (points[:, 2] >= min(zs)) & (points[:, 2] <= max(zs))
    return points[mask] if inside else points[~mask]
