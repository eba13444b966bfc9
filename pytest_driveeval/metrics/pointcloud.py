"""Point-cloud geometry of the obstacle_segmentation evaluation, vectorised over points.

One frame asks two questions of every point: which (scaled) ground-truth boxes
hold it, and does it lie in the non-detection area (a prism over a polygon,
clipped to road lanelets, minus every box).  Both are answered after a single
pass over all points: a coarse uint8 occupancy grid of the boxes' and the
area's bounds flags the few points worth an exact test, so the per-frame cost
is a handful of array operations over N plus exact tests on the survivors.

Semantics follow perception_eval's sensing evaluation: a box is scaled in x/y
only, by ``box_scale_0m + (box_scale_100m - box_scale_0m) * d / 100`` with d the
3-D distance of its centre from base_link; z spans centre +- height / 2.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

__all__ = ["BoxSet", "Area", "CloudCounts", "box_scale", "polygon_signed_area", "polygon_self_intersects",
           "points_in_polygon", "xyz_columns", "evaluate_cloud", "crop_reference", "box_corners_3d"]


def box_scale(distance, box_scale_0m: float, box_scale_100m: float) -> np.ndarray:
    return box_scale_0m + 0.01 * (box_scale_100m - box_scale_0m) * np.asarray(distance, dtype=np.float64)


def polygon_signed_area(vertices: np.ndarray) -> float:
    """Shoelace area: negative for clockwise vertices (x forward, y left)."""
    v = np.asarray(vertices, dtype=np.float64)
    x, y = v[:, 0], v[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def polygon_self_intersects(vertices: np.ndarray) -> bool:
    """True if two non-adjacent edges touch or cross (all pairs at once)."""
    v = np.asarray(vertices, dtype=np.float64)
    n = len(v)
    if n < 4:
        return False
    a, b = v, np.roll(v, -1, axis=0)
    i, j = np.triu_indices(n, k=2)
    keep = ~((i == 0) & (j == n - 1))  # first and last edge share a vertex
    i, j = i[keep], j[keep]
    p, p2, q, q2 = a[i], b[i], a[j], b[j]

    def cross(o, s, t):
        return (s[:, 0] - o[:, 0]) * (t[:, 1] - o[:, 1]) - (s[:, 1] - o[:, 1]) * (t[:, 0] - o[:, 0])

    d1, d2, d3, d4 = cross(q, q2, p), cross(q, q2, p2), cross(p, p2, q), cross(p, p2, q2)
    proper = (np.sign(d1) * np.sign(d2) < 0) & (np.sign(d3) * np.sign(d4) < 0)

    def on_segment(o, s, t, d):  # t collinear with o-s and within its bounds
        lo, hi = np.minimum(o, s), np.maximum(o, s)
        return (np.abs(d) < 1e-12) & np.all((t >= lo - 1e-12) & (t <= hi + 1e-12), axis=1)

    touching = on_segment(q, q2, p, d1) | on_segment(q, q2, p2, d2) | on_segment(p, p2, q, d3) | on_segment(p, p2, q2, d4)
    return bool(np.any(proper | touching))


def points_in_polygon(x: np.ndarray, y: np.ndarray, vertices: np.ndarray, chunk: int = 1 << 15) -> np.ndarray:
    """Crossing-number test (perception_eval's rule: half-open in y), points x edges at once."""
    v = np.asarray(vertices, dtype=np.float64)
    xi, yi = v[:, 0], v[:, 1]
    xj, yj = np.roll(xi, -1), np.roll(yi, -1)
    dy = yj - yi
    flat = dy == 0
    slope = np.where(flat, 0.0, (xj - xi) / np.where(flat, 1.0, dy))
    out = np.zeros(len(x), dtype=bool)
    # Chunks bound the (points x edges) temporaries for long lanelet outlines.
    for s in range(0, len(x), chunk):
        px = np.asarray(x[s:s + chunk], dtype=np.float64)[:, None]
        py = np.asarray(y[s:s + chunk], dtype=np.float64)[:, None]
        straddles = (yi <= py) != (yj <= py)
        crosses = straddles & (px < xi + (py - yi) * slope)
        out[s:s + chunk] = (np.count_nonzero(crosses, axis=1) & 1).astype(bool)
    return out


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
    with (None: no map, the polygon alone; empty: no road in it, nothing to check)."""

    polygon: np.ndarray
    z_min: float
    z_max: float
    clips: list[np.ndarray] | None = None

    def aabb(self) -> np.ndarray:
        lo, hi = self.polygon.min(axis=0), self.polygon.max(axis=0)
        if self.clips:
            clip = np.concatenate(self.clips)
            lo, hi = np.maximum(lo, clip.min(axis=0)), np.minimum(hi, clip.max(axis=0))
        return np.array([lo[0], lo[1], self.z_min, hi[0], hi[1], self.z_max])

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


MULTI = -2  # grid label of a cell touched by several boxes


def _grid_candidates(x, y, boxes: np.ndarray, area: np.ndarray | None, cell_budget: int = 1 << 16):
    """Indices of points whose grid cell touches a box or the area, with each
    cell's flags (bit 1: some box, bit 2: area) and box label (index, or MULTI)."""
    regions = boxes if area is None else np.concatenate([boxes, area[None]])
    lo, hi = regions[:, :2].min(axis=0), regions[:, 3:5].max(axis=0)
    span = np.maximum(hi - lo, 1e-3)
    cell = max(float(np.sqrt(span[0] * span[1] / cell_budget)), 0.25)
    shape = (np.floor(span / cell).astype(np.int64) + 3)  # one empty cell of padding on each side
    origin = lo - cell
    flags = np.zeros(shape[::-1], dtype=np.uint8)  # rows: y, cols: x
    labels = np.full(shape[::-1], -1, dtype=np.int16)
    i0 = np.floor((regions[:, :2] - origin) / cell).astype(np.int64)
    i1 = np.floor((regions[:, 3:5] - origin) / cell).astype(np.int64) + 1
    for k, ((a, b), (c, d)) in enumerate(zip(i0, i1)):  # loop over regions (tens), not points
        if k < len(boxes):
            flags[b:d, a:c] |= 1
            sub = labels[b:d, a:c]
            sub[...] = np.where(sub == -1, k, MULTI)
        else:
            flags[b:d, a:c] |= 2
    inv = np.float32(1.0 / cell)
    fx = np.subtract(x, np.float32(origin[0]), dtype=np.float32)
    fx *= inv
    np.clip(fx, 0, shape[0] - 1, out=fx)
    fy = np.subtract(y, np.float32(origin[1]), dtype=np.float32)
    fy *= inv
    np.clip(fy, 0, shape[1] - 1, out=fy)
    key = fy.astype(np.int32)
    key *= np.int32(shape[0])
    key += fx.astype(np.int32)
    hit = flags.reshape(-1).take(key)
    idx = np.flatnonzero(hit)
    return idx, hit[idx], labels.reshape(-1).take(key[idx])


def _box_pairs(boxes: BoxSet, x, y, z, labels) -> tuple[np.ndarray, np.ndarray]:
    """(point, box) index pairs with the point inside the box.  A point in a
    single-box cell is tested against that box only; MULTI cells against all."""
    single = np.flatnonzero(labels >= 0)
    b = labels[single].astype(np.intp)
    cos, sin = np.cos(boxes.yaws), np.sin(boxes.yaws)
    dx, dy = x[single] - boxes.centers[b, 0], y[single] - boxes.centers[b, 1]
    c, s = cos[b], sin[b]
    ok = ((np.abs(dx * c + dy * s) <= boxes.half[b, 0]) & (np.abs(dy * c - dx * s) <= boxes.half[b, 1])
          & (np.abs(z[single] - boxes.centers[b, 2]) <= boxes.half[b, 2]))
    multi = np.flatnonzero(labels == MULTI)
    mp, mb = np.nonzero(boxes.contains(x[multi], y[multi], z[multi]))
    return np.concatenate([single[ok], multi[mp]]), np.concatenate([b[ok], mb])


def _nearest_per_box(dist2: np.ndarray, box: np.ndarray) -> np.ndarray:
    """Per box id, the index (into dist2) of its smallest value (-1 for absent ids)."""
    order = np.argsort(box.astype(np.int16), kind="stable")  # radix sort on small ints
    sb, sd = box[order], dist2[order]
    new_group = np.r_[True, sb[1:] != sb[:-1]]
    mins = np.minimum.reduceat(sd, np.flatnonzero(new_group))
    group = np.cumsum(new_group) - 1
    cand = np.flatnonzero(sd == mins[group])
    first = cand[np.r_[True, group[cand][1:] != group[cand][:-1]]]
    out = np.full(int(box.max()) + 1, -1, dtype=np.intp)
    out[sb[first]] = order[first]
    return out


def evaluate_cloud(points: np.ndarray, boxes: BoxSet, area: Area | None = None) -> CloudCounts:
    """Points per box, nearest point per box, and the points failing the non-detection area."""
    x, y, z = xyz_columns(points)
    nb = len(boxes)
    counts = np.zeros(nb, dtype=np.int64)
    nearest = np.full((nb, 3), np.nan)
    use_area = area is not None and not area.empty
    if (not nb and not use_area) or len(x) == 0:
        return CloudCounts(counts, nearest, np.zeros((0, 3)))
    idx, flags, labels = _grid_candidates(x, y, boxes.aabbs().reshape(-1, 6), area.aabb() if use_area else None)
    cx, cy, cz = (np.asarray(c[idx], dtype=np.float64) for c in (x, y, z))

    if nb:
        pi, bi = _box_pairs(boxes, cx, cy, cz, labels)
        counts = np.bincount(bi, minlength=nb).astype(np.int64)
        if len(pi):
            nearest_idx = _nearest_per_box(cx[pi] ** 2 + cy[pi] ** 2 + cz[pi] ** 2, bi)
            has = np.flatnonzero(counts)
            take = pi[nearest_idx[has]]
            nearest[has] = np.stack([cx[take], cy[take], cz[take]], axis=1)
    area_points = np.zeros((0, 3))
    if use_area:
        keep = (flags & 2).astype(bool) & (cz >= area.z_min) & (cz <= area.z_max)
        sel = np.flatnonzero(keep)
        inside = points_in_polygon(cx[sel], cy[sel], area.polygon)
        sel = sel[inside]
        if area.clips is not None:
            on_road = np.zeros(len(sel), dtype=bool)
            for clip in area.clips:  # loop over lanelets, each test vectorised over points
                on_road |= points_in_polygon(cx[sel], cy[sel], clip)
            sel = sel[on_road]
        if nb and len(sel):
            in_box, _ = _box_pairs(boxes, cx[sel], cy[sel], cz[sel], labels[sel])
            outside = np.ones(len(sel), dtype=bool)
            outside[in_box] = False
            sel = sel[outside]
        area_points = np.stack([cx[sel], cy[sel], cz[sel]], axis=1)
    return CloudCounts(counts, nearest, area_points, candidates=len(idx))


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
    for i in range(n):
        p, q = poly[i], poly[i + 1]
        flags = ((p[1] <= py) & (q[1] > py)) | ((p[1] > py) & (q[1] <= py))
        vt = (py - p[1]) / (q[1] - p[1]) if q[1] != p[1] else px
        flags &= px < p[0] + vt * (q[0] - p[0])
        count[flags] += 1
    mask = (count % 2 != 0) & (points[:, 2] >= min(zs)) & (points[:, 2] <= max(zs))
    return points[mask] if inside else points[~mask]
