"""The inputs and output of one obstacle frame's evaluation: scaled boxes, the non-detection area, the counts.

Both kernels (cloud_jit, cloud_numpy) and ``pointcloud.evaluate_cloud``, which picks one, read these.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from ..geometry.polygons import polygon_edges

__all__ = ["Area", "BoxSet", "CloudCounts", "box_scale", "xyz_columns"]


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
