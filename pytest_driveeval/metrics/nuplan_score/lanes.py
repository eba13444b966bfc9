"""The map as nuPlan's closed-loop score reads it: lanes (surface polygon, baseline, speed limit,
successors), extra drivable polygons and intersections, with the point queries the terms ask.

Lookups are vectorised over points: a bounding-box test of every point against every polygon, then the
exact crossing-number test only for the polygons some point's box test admitted.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from pytest_driveeval.geometry.polygons import polygon_edges


def _bounds(polygons: list[np.ndarray]) -> np.ndarray:
    if not polygons:
        return np.zeros((0, 4))
    return np.array([[p[:, 0].min(), p[:, 1].min(), p[:, 0].max(), p[:, 1].max()] for p in polygons])


def _edge_tables(polygons: list[np.ndarray]) -> list[tuple[np.ndarray, ...]]:
    """Per polygon, the (xi, yi, yj, slope) columns of its non-horizontal edges (polygon_edges' table)."""
    out = []
    for polygon in polygons:
        table = polygon_edges(polygon)[0]
        table = table[table[:, 1] != table[:, 2]]
        out.append(tuple(np.ascontiguousarray(table[:, i]) for i in range(4)))
    return out


def _containing(points: np.ndarray, tables: list[tuple[np.ndarray, ...]], bounds: np.ndarray) -> np.ndarray:
    """(P, N) bool: point p lies in polygon n (the crossing-number rule of geometry.polygons)."""
    out = np.zeros((len(points), len(tables)), dtype=bool)
    if not len(tables) or not len(points):
        return out
    x, y = points[:, 0:1], points[:, 1:2]
    near = (x >= bounds[:, 0]) & (x <= bounds[:, 2]) & (y >= bounds[:, 1]) & (y <= bounds[:, 3])
    with np.errstate(over="ignore"):  # a nearly horizontal edge's slope: see geometry.polygons
        for n in np.flatnonzero(near.any(axis=0)):
            rows = np.flatnonzero(near[:, n])
            xi, yi, yj, slope = tables[n]
            px, py = points[rows, 0:1], points[rows, 1:2]
            crosses = ((yi <= py) != (yj <= py)) & (px < xi + (py - yi) * slope)
            out[rows, n] = (np.count_nonzero(crosses, axis=1) & 1).astype(bool)
    return out


def outline_distance(points: np.ndarray, outline: np.ndarray) -> np.ndarray:
    """(P,) distance from each point to a closed outline's edges."""
    a = outline
    ab = np.roll(outline, -1, axis=0) - a
    length2 = np.maximum((ab ** 2).sum(1), 1e-18)
    ap = points[:, None, :] - a[None]
    t = np.clip((ap * ab[None]).sum(2) / length2, 0.0, 1.0)
    gap = ap - t[..., None] * ab[None]
    return np.sqrt((gap ** 2).sum(2)).min(1)


def project(points: np.ndarray, line: np.ndarray, cumulative: np.ndarray) -> np.ndarray:
    """(P,) arc length along ``line`` of each point's nearest point on it (shapely's ``project``)."""
    a, ab = line[:-1], np.diff(line, axis=0)
    length2 = np.maximum((ab ** 2).sum(1), 1e-18)
    ap = points[:, None, :] - a[None]
    t = np.clip((ap * ab[None]).sum(2) / length2, 0.0, 1.0)
    gap = ap - t[..., None] * ab[None]
    nearest = np.argmin((gap ** 2).sum(2), axis=1)  # the first of equally near segments, as shapely
    rows = np.arange(len(points))
    return cumulative[nearest] + t[rows, nearest] * np.sqrt(length2[nearest])


def arc_lengths(line: np.ndarray) -> np.ndarray:
    return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(line, axis=0), axis=1))])


@dataclass
class ScoreMap:
    """Lanes and areas in the scene's world frame.  ``speed_limits``: m/s, NaN where the map has none.
    ``outgoing[i]``: indices of the lanes lane i leads into (empty where the map does not say)."""

    lane_ids: list[str]
    polygons: list[np.ndarray]
    baselines: list[np.ndarray]
    speed_limits: np.ndarray
    connector: np.ndarray
    outgoing: list[list[int]]
    drivable: list[np.ndarray] = field(default_factory=list)
    intersections: list[np.ndarray] = field(default_factory=list)
    #: why the map has no speed limits, where its source says (said in the term's reason)
    no_limits_reason: str | None = None

    def __post_init__(self):
        self.polygons = [np.asarray(p, dtype=np.float64)[:, :2] for p in self.polygons]
        self.baselines = [np.asarray(b, dtype=np.float64)[:, :2] for b in self.baselines]
        self.drivable = [np.asarray(p, dtype=np.float64)[:, :2] for p in self.drivable]
        self.intersections = [np.asarray(p, dtype=np.float64)[:, :2] for p in self.intersections]
        self.speed_limits = np.asarray(self.speed_limits, dtype=np.float64)
        self.connector = np.asarray(self.connector, dtype=bool)
        self.lane_bounds = _bounds(self.polygons)
        self.lane_edges = _edge_tables(self.polygons)
        self.drivable_edges = _edge_tables(self.drivable)
        self.intersection_edges = _edge_tables(self.intersections)
        self.drivable_bounds = _bounds(self.drivable)
        self.intersection_bounds = _bounds(self.intersections)
        self.cumulative = [arc_lengths(b) for b in self.baselines]
        self.headings = [np.arctan2(np.diff(b[:, 1]), np.diff(b[:, 0])) for b in self.baselines]

    @property
    def num_lanes(self) -> int:
        return len(self.lane_ids)

    @property
    def has_speed_limits(self) -> bool:
        return bool(np.any(np.isfinite(self.speed_limits) & (self.speed_limits > 0)))

    def lanes_at(self, points: np.ndarray) -> np.ndarray:
        """(P, N) bool: which lane surfaces hold each point."""
        return _containing(points, self.lane_edges, self.lane_bounds)

    def in_drivable(self, points: np.ndarray) -> np.ndarray:
        """(P,) bool: in one of the drivable polygons besides the lanes."""
        return _containing(points, self.drivable_edges, self.drivable_bounds).any(axis=1)

    def in_intersection(self, points: np.ndarray) -> np.ndarray:
        return _containing(points, self.intersection_edges, self.intersection_bounds).any(axis=1)

    def distance_to_drivable(self, points: np.ndarray, within: float) -> np.ndarray:
        """(P,) distance to the nearest lane surface or drivable polygon, inf beyond ``within`` (m)."""
        polygons = self.polygons + self.drivable
        bounds = np.concatenate([self.lane_bounds, self.drivable_bounds]) if polygons else np.zeros((0, 4))
        return self._distance(points, polygons, bounds, within)

    def distance_to_lanes(self, points: np.ndarray, lanes: list[np.ndarray], within: float) -> np.ndarray:
        """(P,) distance from point p to the nearest of the lanes ``lanes[p]``, inf beyond ``within``."""
        out = np.full(len(points), np.inf)
        for p, chosen in enumerate(lanes):
            for n in chosen:
                out[p] = min(out[p], float(outline_distance(points[p:p + 1], self.polygons[n])[0]))
        return np.where(out < within, out, np.inf)

    @staticmethod
    def _distance(points, polygons, bounds, within) -> np.ndarray:
        out = np.full(len(points), np.inf)
        if not polygons or not len(points):
            return out
        x, y = points[:, 0:1], points[:, 1:2]
        near = ((x >= bounds[:, 0] - within) & (x <= bounds[:, 2] + within)
                & (y >= bounds[:, 1] - within) & (y <= bounds[:, 3] + within))
        for n in np.flatnonzero(near.any(axis=0)):
            rows = np.flatnonzero(near[:, n])
            out[rows] = np.minimum(out[rows], outline_distance(points[rows], polygons[n]))
        return np.where(out < within, out, np.inf)

    def direction_at(self, lane: int, points: np.ndarray) -> np.ndarray:
        """(P,) heading of lane ``lane``'s baseline at each point's projection."""
        s = project(points, self.baselines[lane], self.cumulative[lane])
        segment = np.clip(np.searchsorted(self.cumulative[lane], s, side="right") - 1, 0,
                          len(self.headings[lane]) - 1)
        return self.headings[lane][segment]
