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

from dataclasses import dataclass, field
from functools import cached_property
from typing import Sequence

import numpy as np

from ..geometry.polygons import polygon_edges

__all__ = ["BoxSet", "Area", "CloudCounts", "box_scale", "xyz_columns", "evaluate_cloud", "crop_reference", "box_corners_3d"]


def box_scale(distance, box_scale_0m: float, box_scale_100m: float) -> np.ndarray:
    return box_scale_0m + 0.01 * (box_scale_100m - box_scale_0m) * np.asarray(distance, dtype=np.float64)


@dataclass
class BoxSet:
    """Ground-truth boxes in base_link, already scaled: centres (B, 3), half extents (B, 3)."""

    centers: np.ndarray
    half: np.ndarray  # half length (along yaw), half width, half height
    yaws: np.ndarray

    @classmethod
    def from_ground_truth(cls, centers, sizes_wlh, yaws, box_scale_0m=1.0, box_scale_100m=1.0) -> "BoxSet":
        centers = np.asarray(centers, dtype=np.float64).reshape(-1, 3)
        wlh = np.asarray(sizes_wlh, dtype=np.float64).reshape(-1, 3)
        scale = box_scale(np.linalg.norm(centers, axis=1), box_scale_0m, box_scale_100m)
        half = 0.5 * np.stack([wlh[:, 1] * scale, wlh[:, 0] * scale, wlh[:, 2]], axis=1)
        return cls(centers, half, np.asarray(yaws, dtype=np.float64).reshape(-1))

    def __len__(self) -> int:
        return len(self.yaws)

    def footprints(self) -> np.ndarray:
        """(B, 4, 2) corners in base_link, counter-clockwise."""
        c, s = np.cos(self.yaws), np.sin(self.yaws)
        sx = np.array([1, -1, -1, 1])[None, :] * self.half[:, :1]
        sy = np.array([1, 1, -1, -1])[None, :] * self.half[:, 1:2]
        return np.stack([self.centers[:, :1] + c[:, None] * sx - s[:, None] * sy,
                         self.centers[:, 1:2] + s[:, None] * sx + c[:, None] * sy], axis=-1)

    def aabbs(self) -> np.ndarray:
        """(B, 6) x0 y0 z0 x1 y1 z1."""
        c, s = np.abs(np.cos(self.yaws)), np.abs(np.sin(self.yaws))
        ex = c * self.half[:, 0] + s * self.half[:, 1]
        ey = s * self.half[:, 0] + c * self.half[:, 1]
        ext = np.stack([ex, ey, self.half[:, 2]], axis=1)
        return np.concatenate([self.centers - ext, self.centers + ext], axis=1)

    def contains(self, x, y, z) -> np.ndarray:
        """(M, B) inside mask; faces count as inside."""
        dx = np.asarray(x, np.float64)[:, None] - self.centers[:, 0]
        dy = np.asarray(y, np.float64)[:, None] - self.centers[:, 1]
        c, s = np.cos(self.yaws), np.sin(self.yaws)
        return ((np.abs(dx * c + dy * s) <= self.half[:, 0]) & (np.abs(dy * c - dx * s) <= self.half[:, 1])
                & (np.abs(np.asarray(z, np.float64)[:, None] - self.centers[:, 2]) <= self.half[:, 2]))


@dataclass
class Area:
    """Non-detection prism in base_link.  ``clips``: road polygons it is intersected
    with (None: no map, the polygon alone; empty: no road in it, nothing to check).
    Read-only once evaluated: its bounds and edge table are computed once."""

    polygon: np.ndarray
    z_min: float
    z_max: float
    clips: list[np.ndarray] | None = None

    @cached_property
    def _bounds(self) -> np.ndarray:
        lo, hi = self.polygon.min(axis=0), self.polygon.max(axis=0)
        if self.clips:
            clip = np.concatenate(self.clips)
            lo, hi = np.maximum(lo, clip.min(axis=0)), np.minimum(hi, clip.max(axis=0))
        bounds = np.array([lo[0], lo[1], self.z_min, hi[0], hi[1], self.z_max], dtype=np.float64)
        bounds.flags.writeable = False
        return bounds

    def aabb(self) -> np.ndarray:
        """x0 y0 z0 x1 y1 z1 (read-only)."""
        return self._bounds

    @cached_property
    def edge_table(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``polygon_edges`` of the polygon then the clips, and each clip's x0 y0 x1 y1."""
        clips = self.clips or []
        edges, ends = polygon_edges(self.polygon, *clips)
        boxes = np.array([[*c.min(axis=0), *c.max(axis=0)] for c in clips], dtype=np.float64).reshape(-1, 4)
        return edges, ends, boxes

    @property
    def empty(self) -> bool:
        if self.clips is not None and not self.clips:
            return True
        box = self.aabb()
        return bool(box[3] < box[0] or box[4] < box[1])


@dataclass
class CloudCounts:
    counts: np.ndarray            # (B,) points inside each box
    nearest: np.ndarray           # (B, 3) point nearest base_link in each box, NaN when none
    area_points: np.ndarray       # (K, 3) points in the non-detection area outside every box
    candidates: int = 0           # points that needed an exact test (diagnostic)
    extra: dict = field(default_factory=dict)


def xyz_columns(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """x, y, z views of a structured cloud or an (N, >=3) array; no copy."""
    if points.dtype.names:
        return points["x"], points["y"], points["z"]
    return points[:, 0], points[:, 1], points[:, 2]


def evaluate_cloud(points: np.ndarray, boxes: BoxSet, area: Area | None = None,
                   kernel: str | None = None) -> CloudCounts:
    """Points per box, nearest point per box, and the points failing the non-detection area.

    ``kernel``: "numba" (compiled, the default when numba is installed) or "numpy";
    both give the same result, point for point."""
    from . import cloud_jit, cloud_numpy

    if kernel not in (None, "numba", "numpy"):
        raise ValueError(f"kernel must be 'numba' or 'numpy', not {kernel!r}")
    if kernel == "numba" and not cloud_jit.AVAILABLE:
        raise ImportError("kernel='numba' needs numba: pip install 'pytest-driveeval[obstacle]'")
    x = xyz_columns(points)[0]
    nb = len(boxes)
    for name, values in (("centre", boxes.centers), ("size", boxes.half), ("yaw", boxes.yaws)):
        bad = np.flatnonzero(~np.isfinite(values.reshape(nb, -1 if nb else 1)).all(axis=1))
        if len(bad):  # the grids would be garbage
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
