"""l5kit 1.5's vectorised map keys (``Vectorizer._vectorize_map``), built for many rows at once.

A row is one (scene, frame) with the ego's driven pose there.  Per row, in that pose's agent frame::

    lanes (2L, P, 3)              lanes_availabilities (2L, P) bool
        lane i's left boundary at 2i, its right at 2i+1; the third value is 0
    lanes_mid (L, P, 3)           lanes_mid_availabilities (L, P) bool
        the centre lines; the third value is the lane's traffic-light feature
    crosswalks (C, Q, 3)          crosswalks_availabilities (C, Q) bool
        the third value is 0

L = ``max_lanes``, P = ``max_points_per_lane``, C = ``max_crosswalks``, Q =
``max_points_per_crosswalk``.  What l5kit does, restated:

* A lane is a candidate when its box (both boundaries), grown by ``max_distance``
  each side, strictly holds the ego's position (``indices_in_bounds``).
* Each boundary is resampled to P points equally spaced along it; the centre
  line is the mean of the two, resampled again to P points.  Candidates are
  ordered by the smallest distance from the ego to a centre-line point, nearest
  first (ties in map order), and the first L kept.
* A point farther than ``max_distance`` from the ego is not available.
* The traffic-light feature: 4 when none of the lane's traffic controls is a
  traffic light, else the highest of the lane's faces lit this frame (green 1,
  yellow 2, red 3), 0 when none is lit.
* Crosswalks: those whose box, grown likewise, holds the ego, in map order, the
  first C; each its first Q points as given (not resampled), all available.

Where we differ: l5kit measures lengths along a boundary in 3-D (the map's
height); the maps here are 2-D.  A face listed by a lane whose light the map
knows (ScenarioNet's lights, which their reader lists per lane as faces) counts
as that lane's light as well as a light element the lane lists.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pytest_driveeval.geometry.planar import resampled

__all__ = ["MapLimits", "NO_LIGHT", "VectorMap"]

#: the traffic-light feature of a lane that no light controls (l5kit's "none")
NO_LIGHT = 4
# The map's face colour codes (unknown, red, yellow, green) -> l5kit's priority index.
_PRIORITY = np.array([0, 3, 2, 1], np.float32)


@dataclass(frozen=True)
class MapLimits:
    """l5kit's ``lane_params`` (defaults: its Urban Driver configuration)."""

    max_lanes: int = 30
    max_points_per_lane: int = 20
    max_crosswalks: int = 20
    max_points_per_crosswalk: int = 20
    max_distance: float = 35.0


class _Place:
    """One place's map, resampled: what :class:`VectorMap` concatenates."""

    def __init__(self, smap, limits: MapLimits):
        p = limits.max_points_per_lane
        lane_ids = smap.lane_ids.tolist()
        seen: set = set()
        keep = [i for i, lane in enumerate(lane_ids) if not (lane in seen or seen.add(lane))
                and len(smap.lanes_left[i]) and len(smap.lanes_right[i])]
        self.lane_ids = np.array([lane_ids[i] for i in keep], dtype=str)
        n = len(keep)
        self.left = np.zeros((n, p, 2))
        self.right = np.zeros((n, p, 2))
        self.mid = np.zeros((n, p, 2))
        for k, i in enumerate(keep):
            self.left[k] = resampled(smap.lanes_left[i], p)
            self.right[k] = resampled(smap.lanes_right[i], p)
            self.mid[k] = resampled((self.left[k] + self.right[k]) / 2, p)
        self.bounds = smap.lane_bounds[np.array(keep, np.int64)] if n else np.zeros((0, 4))
        self._lights(smap, keep)
        cw_ids = smap.crosswalk_ids.tolist()
        seen = set()
        cw_keep = [j for j, c in enumerate(cw_ids) if not (c in seen or seen.add(c)) and len(smap.crosswalks[j])]
        q = limits.max_points_per_crosswalk
        self.crosswalk_points = np.zeros((len(cw_keep), q, 2))
        self.crosswalk_counts = np.zeros(len(cw_keep), np.int64)
        for k, j in enumerate(cw_keep):
            points = smap.crosswalks[j][:q]
            self.crosswalk_points[k, :len(points)] = points
            self.crosswalk_counts[k] = len(points)
        self.crosswalk_bounds = smap.crosswalks.bounds[cw_keep] if cw_keep else np.zeros((0, 4))

    def _lights(self, smap, keep: list[int]) -> None:
        """Per kept lane, whether a light controls it, and its faces as a (lanes, most faces) table (-1: none)."""
        faces = {face: f for f, face in enumerate(smap.face_ids.tolist())}
        lights = set(smap.traffic_light_ids.tolist())
        of_light = np.asarray(smap.face_light_index, np.int64)
        self.face_ids = smap.face_ids
        self.face_priority = _PRIORITY[np.clip(np.asarray(smap.face_colours, np.int64), 0, 3)]
        self.has_light = np.zeros(len(keep), bool)
        lane_faces = []
        for k, i in enumerate(keep):
            controls = smap.lane_controls(i).tolist()
            own = [faces[c] for c in controls if c in faces]
            self.has_light[k] = any(c in lights for c in controls) or any(of_light[f] >= 0 for f in own)
            lane_faces.append(own)
        width = max([len(f) for f in lane_faces] + [1])
        self.lane_faces = np.full((len(keep), width), -1, np.int64)
        for k, own in enumerate(lane_faces):
            self.lane_faces[k, :len(own)] = own


class VectorMap:
    """Semantic maps (io.l5.l5_semantic_map.SemanticMap) resampled once into the arrays each step reads.

    Lanes or crosswalks repeated under one id in a place's map (several ScenarioNet scenes of one place,
    merged) are kept once.  Lanes whose boundaries hold no point are never candidates."""

    def __init__(self, semantic_maps, limits: MapLimits = MapLimits()):
        """``semantic_maps``: one map, or a list of maps of different places (a row sees the lanes of
        its own place only: two cities' coordinates overlap)."""
        self.limits = limits
        if not isinstance(semantic_maps, (list, tuple)):
            semantic_maps = [semantic_maps]
        parts = [_Place(smap, limits) for smap in semantic_maps]
        offsets = np.cumsum([0] + [len(part.face_ids) for part in parts])
        for part, offset in zip(parts, offsets):
            part.lane_faces[part.lane_faces >= 0] += offset
        for name in ("lane_ids", "left", "right", "mid", "bounds", "has_light", "face_ids", "face_priority",
                     "crosswalk_points", "crosswalk_counts", "crosswalk_bounds"):
            setattr(self, name, np.concatenate([getattr(part, name) for part in parts]))
        width = max(part.lane_faces.shape[1] for part in parts)
        self.lane_faces = np.concatenate([np.pad(part.lane_faces, ((0, 0), (0, width - part.lane_faces.shape[1])),
                                                 constant_values=-1) for part in parts])
        self.lane_place = np.repeat(np.arange(len(parts)), [len(part.lane_ids) for part in parts])
        self.crosswalk_place = np.repeat(np.arange(len(parts)), [len(part.crosswalk_counts) for part in parts])

    def face_index(self, face_ids) -> np.ndarray:
        """Face ids (str) as indices into this map's faces, -1 for faces it lacks."""
        index = {face: f for f, face in enumerate(self.face_ids.tolist())}
        return np.array([index.get(f, -1) for f in np.asarray(face_ids).tolist()], np.int64)

    def __call__(self, centre: np.ndarray, cos: np.ndarray, sin: np.ndarray, lit: np.ndarray | None = None,
                 place: np.ndarray | None = None) -> tuple[dict[str, np.ndarray], np.ndarray]:
        """The six keys for B rows with the ego at ``centre`` (B, 2) heading (cos, sin) (B,), ``lit``
        (B, faces) the faces lit at each row's frame (None: none) and ``place`` (B,) each row's map (None:
        the first).  Also returns (B, L) the kept lanes' indices into :attr:`lane_ids`, -1 for empty slots
        (the route and tests read them)."""
        place = np.zeros(len(centre), np.int64) if place is None else np.asarray(place, np.int64)
        lim = self.limits
        b, n_l, p = len(centre), lim.max_lanes, lim.max_points_per_lane
        d_max = lim.max_distance
        rows, lanes = _in_bounds(centre, self.bounds, d_max, place, self.lane_place)
        gap = self.mid[lanes] - centre[rows, None, :]
        nearest = np.sqrt((gap ** 2).sum(-1)).min(axis=1) if len(rows) else np.zeros(0)
        order = np.lexsort((nearest, rows))  # stable: ties stay in map order
        rows, lanes = rows[order], lanes[order]
        rank = np.arange(len(rows)) - np.searchsorted(rows, rows)
        kept = rank < n_l
        rows, lanes, rank = rows[kept], lanes[kept], rank[kept]
        chosen = np.full((b, n_l), -1, np.int64)
        chosen[rows, rank] = lanes

        # Each kept lane's points gathered once, (K, P, 2) float32, then written into flat slot indices.
        c, s, o = cos[rows, None], sin[rows, None], centre[rows, None, :]
        left = _to_agent(self.left[lanes], o, c, s).astype(np.float32)
        right = _to_agent(self.right[lanes], o, c, s).astype(np.float32)
        middle = _to_agent(self.mid[lanes], o, c, s).astype(np.float32)
        slot = rows * n_l + rank
        bounds = np.zeros((b * 2 * n_l, p, 3), np.float32)
        bounds_ok = np.zeros((b * 2 * n_l, p), bool)
        bounds[2 * slot, :, :2] = left
        bounds[2 * slot + 1, :, :2] = right
        bounds_ok[2 * slot] = _norm(left) < d_max  # on the float32 values, as l5kit
        bounds_ok[2 * slot + 1] = _norm(right) < d_max
        mid = np.zeros((b * n_l, p, 3), np.float32)
        mid_ok = np.zeros((b * n_l, p), bool)
        mid[slot, :, :2] = middle
        mid[slot, :, 2] = self._light_feature(rows, lanes, lit)[:, None]
        mid_ok[slot] = _norm(middle) < d_max
        bounds, bounds_ok = bounds.reshape(b, 2 * n_l, p, 3), bounds_ok.reshape(b, 2 * n_l, p)
        mid, mid_ok = mid.reshape(b, n_l, p, 3), mid_ok.reshape(b, n_l, p)

        n_c, q = lim.max_crosswalks, lim.max_points_per_crosswalk
        walks = np.zeros((b, n_c, q, 3), np.float32)
        walks_ok = np.zeros((b, n_c, q), bool)
        w_rows, w_idx = _in_bounds(centre, self.crosswalk_bounds, d_max, place, self.crosswalk_place)
        w_rank = np.arange(len(w_rows)) - np.searchsorted(w_rows, w_rows)
        kept = w_rank < n_c
        w_rows, w_idx, w_rank = w_rows[kept], w_idx[kept], w_rank[kept]
        walks[w_rows, w_rank, :, :2] = _to_agent(self.crosswalk_points[w_idx], centre[w_rows, None, :],
                                                 cos[w_rows, None], sin[w_rows, None])
        filled = np.arange(q) < self.crosswalk_counts[w_idx][:, None]
        walks_ok[w_rows, w_rank] = filled
        walks[w_rows, w_rank] *= filled[..., None]  # l5kit leaves the slots past a crosswalk's points zero
        out = {"lanes": bounds, "lanes_availabilities": bounds_ok, "lanes_mid": mid, "lanes_mid_availabilities": mid_ok,
               "crosswalks": walks, "crosswalks_availabilities": walks_ok}
        return out, chosen

    def _light_feature(self, rows: np.ndarray, lanes: np.ndarray, lit: np.ndarray | None) -> np.ndarray:
        feature = np.full(len(rows), float(NO_LIGHT), np.float32)
        controlled = self.has_light[lanes]
        if not controlled.any():
            return feature
        faces = self.lane_faces[lanes[controlled]]
        on = faces >= 0
        if lit is not None and lit.shape[1]:
            on &= lit[rows[controlled][:, None], np.maximum(faces, 0)]
        else:
            on[:] = False
        priority = np.where(on, self.face_priority[np.maximum(faces, 0)] if len(self.face_priority) else 0, 0)
        feature[controlled] = priority.max(axis=1)
        return feature


def _in_bounds(centre: np.ndarray, bounds: np.ndarray, half: float, place: np.ndarray,
               element_place: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(rows, elements) pairs of one place whose box grown by ``half`` strictly holds the row's centre,
    row-major, each row's elements in map order (l5kit's ``indices_in_bounds``; NaN boxes hold nothing)."""
    if not len(bounds):
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    x, y = centre[:, :1], centre[:, 1:2]
    inside = ((x > bounds[:, 0] - half) & (y > bounds[:, 1] - half)
              & (x < bounds[:, 2] + half) & (y < bounds[:, 3] + half) & (place[:, None] == element_place))
    rows, elements = np.nonzero(inside)
    return rows.astype(np.int64), elements.astype(np.int64)


def _norm(points: np.ndarray) -> np.ndarray:
    """|point| over the last axis, computed as l5kit's ``np.linalg.norm`` of float32 values."""
    return np.sqrt(np.einsum("...i,...i->...", points, points))


def _to_agent(points: np.ndarray, origin: np.ndarray, cos: np.ndarray, sin: np.ndarray) -> np.ndarray:
    """World points (K, P, 2) into the agent frames of their rows (origin (K, 1, 2), cos/sin (K, 1))."""
    dx, dy = points[..., 0] - origin[..., 0], points[..., 1] - origin[..., 1]
    return np.stack([cos * dx + sin * dy, cos * dy - sin * dx], axis=-1)
