"""Road edges as the drivable area's border where a map gives no drivable polygon (Waymo's
``ROAD_EDGE_BOUNDARY`` / ``ROAD_EDGE_MEDIAN`` lines, as ScenarioNet keeps them).

Waymo orients its road edges with the road on their left (port) side, the convention its own
off-road metric reads (waymo_open_dataset's sim-agents ``map_metric_features``: negative signed
distance on the road).  A point is on the road when the nearest edge has it on its left; at a vertex
of an edge the side is the one of the two segments meeting there that the corner's convexity favours
(a point beyond an outward corner is outside if either segment says so, beyond an inward one only if
both do).  Only points already off every lane surface and drivable polygon are asked, so the search
over all segments is a few hundred points at most per scene.
"""
from __future__ import annotations

import numpy as np

#: squared metres: an edge whose ends are nearer than this is a closed ring (Waymo's tolerance)
CYCLIC_TOLERANCE_M2 = 1.0
#: points per block of the (points x segments) search: bounds its memory
BLOCK = 256


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


class RoadEdges:
    """Every edge's segments as one table, each with the segments before and after it on its edge."""

    def __init__(self, lines: list[np.ndarray]):
        lines = [np.asarray(line, dtype=np.float64)[:, :2] for line in lines]
        # a repeated point makes a segment of no direction: dropped, as it bounds nothing
        lines = [line[np.concatenate([[True], np.any(np.diff(line, axis=0) != 0, axis=1)])] for line in lines]
        lines = [line for line in lines if len(line) >= 2]
        self.lines = lines
        starts, ends, prior, after = [], [], [], []
        offset = 0
        for line in lines:
            n = len(line) - 1
            cyclic = float(np.sum((line[0] - line[-1]) ** 2)) < CYCLIC_TOLERANCE_M2
            index = np.arange(n) + offset
            starts.append(line[:-1])
            ends.append(line[1:])
            # an open edge's first and last segments have no neighbour: themselves (their own side decides)
            prior.append(np.roll(index, 1) if cyclic else np.concatenate([index[:1], index[:-1]]))
            after.append(np.roll(index, -1) if cyclic else np.concatenate([index[1:], index[-1:]]))
            offset += n
        self.start = np.concatenate(starts) if starts else np.zeros((0, 2))
        self.vector = (np.concatenate(ends) if ends else np.zeros((0, 2))) - self.start
        self.prior = np.concatenate(prior).astype(np.int64) if prior else np.zeros(0, np.int64)
        self.after = np.concatenate(after).astype(np.int64) if after else np.zeros(0, np.int64)

    def __len__(self) -> int:
        return len(self.start)

    def signed_distances(self, points: np.ndarray) -> np.ndarray:
        """(P,) distance to the nearest edge, negative on its road side (inf: no edges)."""
        points = np.asarray(points, dtype=np.float64)[:, :2]
        out = np.full(len(points), np.inf)
        if not len(self) or not len(points):
            return out
        length2 = np.einsum("ij,ij->i", self.vector, self.vector)
        for lo in range(0, len(points), BLOCK):
            p = points[lo:lo + BLOCK]
            rel = p[:, None, :] - self.start[None]
            t = np.einsum("pij,ij->pi", rel, self.vector) / length2
            foot = self.start[None] + self.vector[None] * np.clip(t, 0.0, 1.0)[..., None]
            distance = np.linalg.norm(p[:, None, :] - foot, axis=-1)
            nearest = np.argmin(distance, axis=1)
            rows = np.arange(len(p))
            t_n = t[rows, nearest]
            # +1 on the right of a segment (off the road), -1 on its left
            side = np.sign(_cross(rel[rows, nearest], self.vector[nearest]))
            before = np.sign(_cross(p - self.start[self.prior[nearest]], self.vector[self.prior[nearest]]))
            beyond = np.sign(_cross(p - self.start[self.after[nearest]], self.vector[self.after[nearest]]))
            convex_in = _cross(self.vector[self.prior[nearest]], self.vector[nearest]) > 0
            convex_out = _cross(self.vector[nearest], self.vector[self.after[nearest]]) > 0
            sign = np.where(t_n < 0.0, np.where(convex_in, np.maximum(side, before), np.minimum(side, before)),
                            np.where(t_n < 1.0, side,
                                     np.where(convex_out, np.maximum(side, beyond), np.minimum(side, beyond))))
            out[lo:lo + BLOCK] = np.where(sign > 0, 1.0, -1.0) * distance[rows, nearest]
        return out
