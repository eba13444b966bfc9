"""Oriented boxes, vectorised over leading axes.

Conventions (shared with l5kit so logged data can be used unchanged):

* a box ``extent``/``size`` is ``(length, width[, height])`` with *length along
  the heading* (yaw, counter-clockwise from the world x axis);
* :func:`box_corners` returns corners in the order front-left, front-right,
  rear-right, rear-left, so edge ``k`` runs from corner ``k`` to ``k+1``:
  0 front, 1 right, 2 rear, 3 left (see ``EDGE_*``).

Every function broadcasts over leading dimensions; none loops in Python over
boxes or points.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .planar import norm2d

EDGE_FRONT, EDGE_RIGHT, EDGE_REAR, EDGE_LEFT = 0, 1, 2, 3

# Unit corner offsets in the box frame (x forward, y left), scaled by the
# half-extents; the order fixes the edge numbering above.
_UNIT_CORNERS = np.array([[1.0, 1.0], [1.0, -1.0], [-1.0, -1.0], [-1.0, 1.0]])


def box_corners(centroid: np.ndarray, yaw: np.ndarray, extent: np.ndarray) -> np.ndarray:
    """(..., 2) centroid, (...) yaw, (..., >=2) extent -> (..., 4, 2) corners.

    Order: front-left, front-right, rear-right, rear-left (l5kit's order).
    """
    centroid = np.asarray(centroid, dtype=np.float64)
    yaw = np.asarray(yaw, dtype=np.float64)
    half = 0.5 * np.asarray(extent, dtype=np.float64)[..., :2]
    local = half[..., None, :] * _UNIT_CORNERS  # (..., 4, 2)
    c, s = np.cos(yaw)[..., None], np.sin(yaw)[..., None]
    x = centroid[..., None, 0] + c * local[..., 0] - s * local[..., 1]
    y = centroid[..., None, 1] + s * local[..., 0] + c * local[..., 1]
    return np.stack([x, y], axis=-1)


def _project(corners: np.ndarray, axis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    # Only the extreme projections matter for separation.
    p = corners[..., 0] * axis[..., None, 0] + corners[..., 1] * axis[..., None, 1]
    return p.min(axis=-1), p.max(axis=-1)


def boxes_overlap(a_corners: np.ndarray, b_corners: np.ndarray, tol: float = 0.0) -> np.ndarray:
    """Separating-axis test for rectangles given as (..., 4, 2) corners.

    Leading dimensions broadcast (e.g. ego ``(S, 1, 4, 2)`` vs agents
    ``(S, A, 4, 2)`` -> ``(S, A)``).  Boxes that merely touch count as
    overlapping, like shapely's ``intersects``; ``tol`` (metres, >= 0) widens
    that contact band, a negative ``tol`` demands that much penetration.
    Rectangles only need their two edge directions each as candidate axes.
    """
    a = np.asarray(a_corners, dtype=np.float64)
    b = np.asarray(b_corners, dtype=np.float64)
    a, b = np.broadcast_arrays(a, b)
    result = np.ones(a.shape[:-2], dtype=bool)
    for box in (a, b):
        for edge in (box[..., 1, :] - box[..., 0, :], box[..., 2, :] - box[..., 1, :]):
            norm = norm2d(edge)
            # Degenerate (zero-length) edges give no axis; leave them unseparated.
            axis = edge / np.where(norm > 0, norm, 1.0)[..., None]
            amin, amax = _project(a, axis)
            bmin, bmax = _project(b, axis)
            result &= (amax >= bmin - tol) & (bmax >= amin - tol)
    return result


def oriented_boxes_overlap(
    centroid_a: np.ndarray,
    yaw_a: np.ndarray,
    extent_a: np.ndarray,
    centroid_b: np.ndarray,
    yaw_b: np.ndarray,
    extent_b: np.ndarray,
    tol: float = 0.0,
) -> np.ndarray:
    """Same test as :func:`boxes_overlap`, straight from pose and extent.

    Centroids (..., 2), yaws (...), extents (..., >=2), all broadcasting ->
    (...) bool.  For two rectangles the separating-axis projections have a
    closed form (the half-extents weighted by |cos|/|sin| of the relative
    yaw), so no corners and no min/max reductions are needed: the cheap path
    for many pairs.
    """
    ca, sa = np.cos(yaw_a), np.sin(yaw_a)
    cb, sb = np.cos(yaw_b), np.sin(yaw_b)
    ea = 0.5 * np.asarray(extent_a, dtype=np.float64)
    eb = 0.5 * np.asarray(extent_b, dtype=np.float64)
    al, aw, bl, bw = ea[..., 0], ea[..., 1], eb[..., 0], eb[..., 1]
    d = np.asarray(centroid_b, dtype=np.float64) - centroid_a
    dx, dy = d[..., 0], d[..., 1]
    cos_rel = np.abs(ca * cb + sa * sb)
    sin_rel = np.abs(ca * sb - sa * cb)
    ok = np.abs(dx * ca + dy * sa) <= al + cos_rel * bl + sin_rel * bw + tol
    ok &= np.abs(dy * ca - dx * sa) <= aw + sin_rel * bl + cos_rel * bw + tol
    ok &= np.abs(dx * cb + dy * sb) <= bl + cos_rel * al + sin_rel * aw + tol
    ok &= np.abs(dy * cb - dx * sb) <= bw + sin_rel * al + cos_rel * aw + tol
    return ok


def _clip_to_box(seg_start, seg_end, centroid, yaw, extent) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(lo, hi, d): the segment's parameters [lo, hi] (within [0, 1]) inside or on the oriented box, and
    its direction in the box's frame.  Liang-Barsky clipping in the box frame, where the box is axis aligned."""
    # Rotate into the box frame directly: cheaper than building 3x3 matrices
    # for the small batches this is called with.
    yaw = np.asarray(yaw, dtype=np.float64)
    c, s = np.cos(yaw), np.sin(yaw)
    start = np.asarray(seg_start, dtype=np.float64)
    rel = start - centroid
    vec = np.asarray(seg_end, dtype=np.float64) - start
    p0 = np.stack([rel[..., 0] * c + rel[..., 1] * s, rel[..., 1] * c - rel[..., 0] * s], axis=-1)
    d = np.stack([vec[..., 0] * c + vec[..., 1] * s, vec[..., 1] * c - vec[..., 0] * s], axis=-1)
    half = 0.5 * np.asarray(extent, dtype=np.float64)[..., :2]
    # A direction so small that the division overflows gives +-inf, which the slab test below
    # reads as it reads a parallel segment: the same answer, so no warning is due.
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        ta = (-half - p0) / d
        tb = (half - p0) / d
    # A segment parallel to a slab is either wholly inside it (no constraint)
    # or wholly outside (empty); lying exactly on the border counts as inside,
    # as with shapely.
    parallel = d == 0
    in_slab = (p0 >= -half) & (p0 <= half)
    tmin = np.where(parallel, np.where(in_slab, -np.inf, np.inf), np.minimum(ta, tb))
    tmax = np.where(parallel, np.where(in_slab, np.inf, -np.inf), np.maximum(ta, tb))
    return np.maximum(tmin.max(axis=-1), 0.0), np.minimum(tmax.min(axis=-1), 1.0), d


def segment_box_overlap_length(
    seg_start: np.ndarray, seg_end: np.ndarray, centroid: np.ndarray, yaw: np.ndarray, extent: np.ndarray
) -> np.ndarray:
    """Length of the part of each segment lying inside (or on) an oriented box.

    All inputs broadcast: segments (..., 2) endpoints, box (..., 2) centroid,
    (...) yaw, (..., >=2) extent -> (...) lengths.
    """
    lo, hi, d = _clip_to_box(seg_start, seg_end, centroid, yaw, extent)
    return np.maximum(hi - lo, 0.0) * norm2d(d)


def segment_meets_box(
    seg_start: np.ndarray, seg_end: np.ndarray, centroid: np.ndarray, yaw: np.ndarray, extent: np.ndarray
) -> np.ndarray:
    """(...) bool: the segment has a point inside or on the oriented box (shapely's ``intersects``: a
    segment touching a corner or an edge meets it), broadcasting as :func:`segment_box_overlap_length`."""
    lo, hi, _ = _clip_to_box(seg_start, seg_end, centroid, yaw, extent)
    return hi >= lo


class PointsInBoxes(NamedTuple):
    counts: np.ndarray  # (B,) int64 points inside each box
    mask: np.ndarray | None  # (N, B) bool, or None when not requested


def points_in_boxes(
    points: np.ndarray,
    centers: np.ndarray,
    yaws: np.ndarray,
    sizes: np.ndarray,
    *,
    margin: float = 0.0,
    return_mask: bool = True,
    cell: float | None = None,
) -> PointsInBoxes:
    """Which points lie inside which oriented boxes.

    points (N, 2|3); centers (B, 2|3); yaws (B,); sizes (B, 2|3) as
    (length, width[, height]).  The z test is applied only when points,
    centers and sizes all carry z.  Boundaries count as inside; ``margin``
    (m) grows every box by that much on every side.

    Speed: a coarse occupancy grid of the boxes' axis-aligned bounds
    discards most points with O(N) work, then one small matrix product maps
    the surviving points into every box frame at once.  ``cell`` sets the grid
    pitch (default: derived from the boxes).
    """
    pts = np.asarray(points, dtype=np.float64)
    ctr = np.asarray(centers, dtype=np.float64).reshape(-1, np.shape(centers)[-1])
    yaw = np.asarray(yaws, dtype=np.float64).reshape(-1)
    size = np.asarray(sizes, dtype=np.float64).reshape(-1, np.shape(sizes)[-1])
    n, b = pts.shape[0], yaw.shape[0]
    use_z = pts.shape[1] >= 3 and ctr.shape[1] >= 3 and size.shape[1] >= 3
    if b == 0 or n == 0:
        return PointsInBoxes(np.zeros(b, np.int64), np.zeros((n, b), bool) if return_mask else None)

    half = 0.5 * size + margin
    c, s = np.cos(yaw), np.sin(yaw)
    # Axis-aligned half-extents of each rotated box.
    ex = np.abs(c) * half[:, 0] + np.abs(s) * half[:, 1]
    ey = np.abs(s) * half[:, 0] + np.abs(c) * half[:, 1]
    lo = np.stack([ctr[:, 0] - ex, ctr[:, 1] - ey], axis=1)
    hi = np.stack([ctr[:, 0] + ex, ctr[:, 1] + ey], axis=1)

    cand = _grid_prefilter(pts[:, :2], lo, hi, cell)
    if use_z:
        zlo, zhi = (ctr[:, 2] - half[:, 2]).min(), (ctr[:, 2] + half[:, 2]).max()
        z = pts[cand, 2]
        cand = cand[(z >= zlo) & (z <= zhi)]

    sub = pts[cand]
    # Box-frame coordinates divided by the half-extent: inside <=> all |.| <= 1.
    # u = ((x - cx) c + (y - cy) s) / hl, v = (-(x - cx) s + (y - cy) c) / hw.
    inv_l, inv_w = 1.0 / np.maximum(half[:, 0], 1e-12), 1.0 / np.maximum(half[:, 1], 1e-12)
    mu = np.stack([c * inv_l, s * inv_l, -(ctr[:, 0] * c + ctr[:, 1] * s) * inv_l])
    mv = np.stack([-s * inv_w, c * inv_w, (ctr[:, 0] * s - ctr[:, 1] * c) * inv_w])
    cols = [mu, mv]
    if use_z:
        inv_h = 1.0 / np.maximum(half[:, 2], 1e-12)
        cols.append(np.stack([np.zeros(b), np.zeros(b), -ctr[:, 2] * inv_h]))
    homog = np.empty((sub.shape[0], 3))
    homog[:, :2] = sub[:, :2]
    homog[:, 2] = 1.0
    local = homog @ np.concatenate(cols, axis=1)  # (M, 2B or 3B)
    if use_z:
        local[:, 2 * b:] += sub[:, 2:3] * inv_h
    # Tiny slack so points exactly on a face survive the rounding of the product.
    inside = (np.abs(local) <= 1.0 + 1e-9).reshape(sub.shape[0], -1, b).all(axis=1)
    counts = inside.sum(axis=0, dtype=np.int64)
    mask = None
    if return_mask:
        mask = np.zeros((n, b), dtype=bool)
        mask[cand] = inside
    return PointsInBoxes(counts, mask)


def _grid_prefilter(xy: np.ndarray, lo: np.ndarray, hi: np.ndarray, cell: float | None) -> np.ndarray:
    """Indices of points falling in grid cells touched by any box AABB."""
    glo, ghi = lo.min(axis=0), hi.max(axis=0)
    span = np.maximum(ghi - glo, 1e-6)
    if cell is None:
        # About the size of the smallest box, but never more than ~1M cells.
        cell = max(float(np.min(hi - lo)) * 0.5, float(np.sqrt(span[0] * span[1] / 1e6)), 1e-3)
    shape = np.floor(span / cell).astype(np.int64) + 1
    # Mark covered cells with a 2-D difference array + cumulative sums:
    # O(cells) regardless of the number of boxes.
    i0 = np.floor((lo - glo) / cell).astype(np.int64)
    i1 = np.floor((hi - glo) / cell).astype(np.int64) + 1
    diff = np.zeros((shape[0] + 1, shape[1] + 1), dtype=np.int32)
    np.add.at(diff, (i0[:, 0], i0[:, 1]), 1)
    np.add.at(diff, (i1[:, 0], i0[:, 1]), -1)
    np.add.at(diff, (i0[:, 0], i1[:, 1]), -1)
    np.add.at(diff, (i1[:, 0], i1[:, 1]), 1)
    covered = diff.cumsum(axis=0).cumsum(axis=1)[: shape[0], : shape[1]] > 0

    # Cheap global AABB cut first, then the grid lookup on the survivors.
    x, y = xy[:, 0], xy[:, 1]
    idx = np.flatnonzero((x >= glo[0]) & (x <= ghi[0]) & (y >= glo[1]) & (y <= ghi[1]))
    g = np.floor((xy[idx] - glo) / cell).astype(np.int64)
    np.minimum(g, shape - 1, out=g)
    return idx[covered[g[:, 0], g[:, 1]]]
