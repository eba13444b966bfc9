"""The road of a blueprint: lanes as centre polylines with widths, and the drivable area.

Two vectorised queries serve the per-step loop:

* :meth:`Road.project` puts points (any leading shape) onto every lane at
  once: arclength ``s``, signed lateral offset ``d`` (positive to the left)
  and the lane's heading there.  Traffic uses it to find who is on which lane
  and how far ahead, the ego included.
* :meth:`Road.pose` is the inverse, ``(lane, s, d) -> (xy, heading)``, how
  traffic vehicles are placed on their lanes.

Both extrapolate past a lane's ends along its first and last segments, so a
vehicle that drives off the map end keeps a well-defined position.

The drivable area is the union of the lane outlines and any extra polygons
(a junction box), rasterised once into a boolean grid: testing the ego's
corners is then an index lookup per step instead of a polygon test.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from pytest_driveeval.geometry import points_in_polygon
from pytest_driveeval.metrics.episode_outcomes import cells_contain

__all__ = ["DrivableGrid", "Lane", "LaneProjection", "Road"]


@dataclass(frozen=True, eq=False)
class Lane:
    """A lane: its centre polyline (P, 2) in driving direction, and its width in metres."""

    centre: np.ndarray
    width: float
    name: str = ""

    def __post_init__(self):
        centre = np.asarray(self.centre, dtype=np.float64)
        if centre.ndim != 2 or centre.shape[1] != 2 or len(centre) < 2:
            raise ValueError(f"lane {self.name!r}: centre must be (P >= 2, 2) points, got shape {centre.shape}")
        if np.any(np.linalg.norm(np.diff(centre, axis=0), axis=1) <= 1e-9):
            raise ValueError(f"lane {self.name!r}: repeated consecutive points in the centre line")
        if not self.width > 0:
            raise ValueError(f"lane {self.name!r}: width must be > 0, got {self.width}")
        object.__setattr__(self, "centre", centre)

    @property
    def length(self) -> float:
        return float(np.linalg.norm(np.diff(self.centre, axis=0), axis=1).sum())

    def outline(self) -> np.ndarray:
        """The lane's area as a polygon: left border forward, right border back.

        Vertex normals are the mean of the adjacent segments' normals, scaled
        so the border keeps half the width from both segments (a mitre).
        """
        c = self.centre
        seg = np.diff(c, axis=0)
        n = np.stack([-seg[:, 1], seg[:, 0]], axis=1) / np.linalg.norm(seg, axis=1)[:, None]
        after = np.concatenate([n, n[-1:]])  # the normal of the segment leaving each vertex
        vn = np.concatenate([n[:1], n]) + after
        vn /= np.einsum("ij,ij->i", vn, after)[:, None]
        half = 0.5 * self.width
        return np.concatenate([c + half * vn, (c - half * vn)[::-1]])


class LaneProjection(NamedTuple):
    """Points put onto every lane; each field is (..., L)."""

    s: np.ndarray  # arclength along the lane, m (negative before its start, beyond its length after its end)
    d: np.ndarray  # signed lateral offset from the centre line, m, positive to the left
    heading: np.ndarray  # the lane's heading there, rad


class Footprint(NamedTuple):
    """Vehicle boxes seen from every lane; each field is (..., L)."""

    proj: LaneProjection  # the box centres put onto the lanes
    cos_rel: np.ndarray  # cosine of the box's heading relative to the lane's
    half_long: np.ndarray  # the box's half extent along the lane, m
    clearance: np.ndarray  # m from the box to the lane's ribbon sideways; negative: the box overlaps it


@dataclass(frozen=True, eq=False)
class DrivableGrid:
    """A boolean raster of the drivable area: ``mask[i, j]`` covers the cell whose
    lower-left corner is ``origin + (i, j) * resolution``."""

    mask: np.ndarray
    origin: np.ndarray
    resolution: float

    def contains(self, points: np.ndarray) -> np.ndarray:
        """(..., 2) points -> (...) True where the point's cell is drivable (outside the grid: False)."""
        return cells_contain(points, self.mask, self.origin, self.resolution)


#: cells of the drivable-area raster at most (one byte each): a 1 GiB grid at 0.1 m is a road of
#: 100 km by 1 km; a larger one is a typing slip, refused before it is allocated
MAX_GRID_CELLS = 2 ** 30


class RoadTooLarge(ValueError):
    """The drivable area's raster would not fit in memory (more than MAX_GRID_CELLS cells)."""


def _rasterise(polygons: Sequence[np.ndarray], resolution: float, pad: float) -> DrivableGrid:
    lo = np.min([p.min(axis=0) for p in polygons], axis=0) - pad
    hi = np.max([p.max(axis=0) for p in polygons], axis=0) + pad
    extent = np.ceil((hi - lo) / resolution)
    if float(np.prod(extent)) > MAX_GRID_CELLS:
        raise RoadTooLarge(f"the road's drivable area ({hi[0] - lo[0]:.6g} m x {hi[1] - lo[1]:.6g} m) would be "
                           f"a raster of {np.prod(extent):.3g} cells at {resolution:g} m, above the limit of "
                           f"{MAX_GRID_CELLS:.3g} cells ({MAX_GRID_CELLS / 2 ** 30:g} GiB)")
    shape = extent.astype(np.int64)
    mask = np.zeros(tuple(shape), dtype=bool)
    for poly in polygons:
        # Only the cells under the polygon's bounding box need testing.
        i0 = np.floor((poly.min(axis=0) - lo) / resolution).astype(np.int64)
        i1 = np.minimum(np.ceil((poly.max(axis=0) - lo) / resolution).astype(np.int64), shape)
        cx = lo[0] + (np.arange(i0[0], i1[0]) + 0.5) * resolution
        cy = lo[1] + (np.arange(i0[1], i1[1]) + 0.5) * resolution
        gx, gy = np.meshgrid(cx, cy, indexing="ij")
        inside = points_in_polygon(gx.ravel(), gy.ravel(), poly).reshape(gx.shape)
        mask[i0[0]:i1[0], i0[1]:i1[1]] |= inside
    return DrivableGrid(mask, lo, resolution)


@dataclass(frozen=True, eq=False)
class Road:
    """Lanes, who may change into which, where lanes end, and the drivable area.

    ``left[l]`` / ``right[l]``: the lane a vehicle on lane ``l`` may change
    into on that side (-1: none); both run in the same direction as ``l``.
    ``ends[l]``: the lane ends at its last point and its vehicles must leave
    it before (a merge); other lanes simply run off the map there.
    ``areas``: extra drivable polygons (a junction box) beside the lanes.
    ``lanes_drivable``: the lanes' outlines are drivable; False when ``areas``
    give the whole drivable area (a CommonRoad scene's lanelets, whose widths
    vary along them: a lane's one width would reach past them).
    """

    lanes: tuple[Lane, ...]
    left: tuple[int, ...] = ()
    right: tuple[int, ...] = ()
    ends: tuple[bool, ...] = ()
    areas: tuple[np.ndarray, ...] = ()
    resolution: float = 0.1
    lanes_drivable: bool = True
    drivable: DrivableGrid = field(init=False, repr=False)

    def __post_init__(self):
        n = len(self.lanes)
        if n == 0:
            raise ValueError("a road needs at least one lane")
        for name in ("left", "right"):
            value = tuple(getattr(self, name)) or (-1,) * n
            if len(value) != n or any(not -1 <= v < n for v in value):
                raise ValueError(f"road.{name} must hold one lane index (or -1) per lane, got {value}")
            object.__setattr__(self, name, value)
        ends = tuple(bool(e) for e in self.ends) or (False,) * n
        if len(ends) != n:
            raise ValueError(f"road.ends must hold one flag per lane, got {ends}")
        object.__setattr__(self, "ends", ends)
        object.__setattr__(self, "areas", tuple(np.asarray(a, dtype=np.float64) for a in self.areas))
        outlines = [l.outline() for l in self.lanes] if self.lanes_drivable else []
        if not outlines and not self.areas:
            raise ValueError("a road whose lanes are not drivable needs areas")
        object.__setattr__(self, "drivable", _rasterise(outlines + list(self.areas), self.resolution, pad=5.0))
        self._build_segments()

    def _build_segments(self):
        # Segments padded to the longest lane's count; padding never wins a projection
        # (infinite distance) nor a pose lookup (starts at +inf).
        counts = [len(l.centre) - 1 for l in self.lanes]
        n, smax = len(self.lanes), max(counts)
        a = np.zeros((n, smax, 2))
        u = np.tile(np.array([1.0, 0.0]), (n, smax, 1))
        start = np.full((n, smax), np.inf)
        lo = np.zeros((n, smax))
        hi = np.zeros((n, smax))
        pad = np.ones((n, smax), dtype=bool)
        for i, lane in enumerate(self.lanes):
            seg = np.diff(lane.centre, axis=0)
            length = np.linalg.norm(seg, axis=1)
            k = counts[i]
            a[i, :k], u[i, :k] = lane.centre[:-1], seg / length[:, None]
            start[i, :k] = np.concatenate([[0.0], np.cumsum(length)[:-1]])
            hi[i, :k] = length
            lo[i, 0], hi[i, k - 1] = -np.inf, np.inf  # extrapolate past both ends
            pad[i, :k] = False
        object.__setattr__(self, "_a", a)
        object.__setattr__(self, "_u", u)
        object.__setattr__(self, "_start", start)
        object.__setattr__(self, "_lo", lo)
        object.__setattr__(self, "_hi", hi)
        object.__setattr__(self, "_pad", pad)
        object.__setattr__(self, "_heading", np.arctan2(u[..., 1], u[..., 0]))
        object.__setattr__(self, "_straight", smax == 1)
        object.__setattr__(self, "lengths", np.array([l.length for l in self.lanes]))
        object.__setattr__(self, "widths", np.array([l.width for l in self.lanes]))
        # Where each lane's vehicles must have left it (inf: never).
        object.__setattr__(self, "end_s", np.where(self.ends, self.lengths, np.inf))
        # left / right as index arrays, for the per-step gathers of the traffic model.
        object.__setattr__(self, "left_of", np.asarray(self.left, dtype=np.int64))
        object.__setattr__(self, "right_of", np.asarray(self.right, dtype=np.int64))

    @property
    def num_lanes(self) -> int:
        return len(self.lanes)

    @property
    def straight_lanes(self) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """Each lane's start (L, 2), unit direction (L, 2) and heading (L,) when every lane is one
        straight segment (what :meth:`project` and :meth:`pose` then use), else None."""
        if not self._straight:
            return None
        return (np.ascontiguousarray(self._a[:, 0]), np.ascontiguousarray(self._u[:, 0]),
                np.ascontiguousarray(self._heading[:, 0]))

    @property
    def bounds(self) -> np.ndarray:
        """(xmin, ymin, xmax, ymax) of the drivable area, for normalising observations."""
        pts = np.concatenate([l.outline() for l in self.lanes] + list(self.areas))
        return np.concatenate([pts.min(axis=0), pts.max(axis=0)])

    def project(self, xy: np.ndarray) -> LaneProjection:
        """(..., 2) points -> their projection onto every lane, fields (..., L)."""
        xy = np.asarray(xy, dtype=np.float64)
        if self._straight:
            a, u = self._a[:, 0], self._u[:, 0]
            rx = xy[..., None, 0] - a[:, 0]
            ry = xy[..., None, 1] - a[:, 1]
            s = rx * u[:, 0] + ry * u[:, 1]
            d = u[:, 0] * ry - u[:, 1] * rx
            return LaneProjection(s, d, np.broadcast_to(self._heading[:, 0], s.shape))
        rx = xy[..., None, None, 0] - self._a[..., 0]
        ry = xy[..., None, None, 1] - self._a[..., 1]
        t = rx * self._u[..., 0] + ry * self._u[..., 1]
        d = self._u[..., 0] * ry - self._u[..., 1] * rx
        along = t - np.clip(t, self._lo, self._hi)
        dist = np.where(self._pad, np.inf, along * along + d * d)
        k = np.argmin(dist, axis=-1)[..., None]
        pick = lambda v: np.take_along_axis(np.broadcast_to(v, dist.shape), k, axis=-1)[..., 0]
        return LaneProjection(pick(self._start) + pick(t), pick(d), pick(self._heading))

    def footprint(self, xy: np.ndarray, yaw: np.ndarray, length: float, width: float) -> Footprint:
        """Boxes of ``length`` x ``width`` centred at ``xy`` (..., 2) heading ``yaw`` (...), on every lane:
        how far along each lane they reach and whether they overlap it sideways."""
        proj = self.project(xy)
        rel = np.asarray(yaw)[..., None] - proj.heading
        cos_rel, sin_rel = np.cos(rel), np.sin(rel)
        along, across = np.abs(cos_rel), np.abs(sin_rel)
        hl, hw = 0.5 * length, 0.5 * width
        clearance = np.abs(proj.d) - 0.5 * self.widths - (across * hl + along * hw)
        return Footprint(proj, cos_rel, along * hl + across * hw, clearance)

    def pose(self, lane: np.ndarray, s: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Lane indices, arclengths and lateral offsets (all broadcasting) -> (xy (..., 2), heading (...))."""
        lane = np.asarray(lane)
        s = np.asarray(s, dtype=np.float64)
        if self._straight:
            k = np.zeros_like(lane)
        else:
            k = np.count_nonzero(s[..., None] >= self._start[lane][..., 1:], axis=-1)
        a, u, start = self._a[lane, k], self._u[lane, k], self._start[lane, k]
        along = s - start
        x = a[..., 0] + along * u[..., 0] - d * u[..., 1]
        y = a[..., 1] + along * u[..., 1] + d * u[..., 0]
        return np.stack([x, y], axis=-1), self._heading[lane, k]
