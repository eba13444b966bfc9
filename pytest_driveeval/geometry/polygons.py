"""Simple polygons in the plane, as (V, 2) vertex arrays (x forward, y left).

The point-in-polygon rule is perception_eval's crossing number, half-open in
y; :func:`polygon_edges` is the edge table that both point-cloud kernels of
:mod:`pytest_driveeval.metrics` test with, so they agree bit for bit.
"""
from __future__ import annotations

import numpy as np


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


def polygon_edges(*polygons: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Edge table of one or more polygons, and where each polygon's edges end.

    Per edge (row): x and y of its first vertex, y of its second, and dx/dy (0 for a
    horizontal edge, which never straddles a point's y).  Both evaluation kernels test
    ``px < x + (py - y) * slope`` with these very numbers, so they agree bit for bit."""
    lens = np.array([len(p) for p in polygons], dtype=np.int64)
    ends = np.cumsum(lens)
    if not len(ends) or ends[-1] == 0:
        return np.zeros((0, 4)), ends
    v = np.concatenate(polygons, dtype=np.float64).reshape(-1, 2)
    nxt = np.arange(1, len(v) + 1)
    closing = lens > 0
    nxt[ends[closing] - 1] = (ends - lens)[closing]  # each polygon closes on its first vertex
    table = np.empty((len(v), 4))
    table[:, :2] = v
    table[:, 2] = v[nxt, 1]
    dx, dy = v[nxt, 0] - v[:, 0], table[:, 2] - table[:, 1]
    flat = dy == 0
    dy[flat] = 1.0
    dx[flat] = 0.0
    np.divide(dx, dy, out=table[:, 3])
    return table, ends


def points_in_polygon(x: np.ndarray, y: np.ndarray, vertices: np.ndarray, chunk: int = 1 << 15) -> np.ndarray:
    """Crossing-number test (perception_eval's rule: half-open in y), points x edges at once."""
    # A nearly horizontal edge has a huge slope: x + dy * slope overflows to +-inf, which compares
    # as the crossing it is the limit of, so the overflow is no error to warn about.
    with np.errstate(over="ignore"):
        return _crossings(x, y, vertices, chunk)


def _crossings(x: np.ndarray, y: np.ndarray, vertices: np.ndarray, chunk: int) -> np.ndarray:
    xi, yi, yj, slope = polygon_edges(vertices)[0].T
    flat = yi == yj
    if np.count_nonzero(~flat) <= 8:
        # Few edges: one pass per edge (horizontal edges never straddle a point's y).
        out = np.zeros(len(x), dtype=bool)
        px, py = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
        for e in np.flatnonzero(~flat):
            straddles = (yi[e] <= py) != (yj[e] <= py)
            straddles &= px < xi[e] + (py - yi[e]) * slope[e]
            out ^= straddles
        return out
    out = np.zeros(len(x), dtype=bool)
    # Chunks bound the (points x edges) temporaries for long lanelet outlines.
    for s in range(0, len(x), chunk):
        px = np.asarray(x[s:s + chunk], dtype=np.float64)[:, None]
        py = np.asarray(y[s:s + chunk], dtype=np.float64)[:, None]
        out[s:s + chunk] = odd_crossings(px, py, xi, yi, yj, slope)
    return out


def odd_crossings(px: np.ndarray, py: np.ndarray, xi: np.ndarray, yi: np.ndarray, yj: np.ndarray,
                  slope: np.ndarray) -> np.ndarray:
    """(P,) whether a ray from each point (``px``, ``py``: (P, 1)) crosses the edges (columns of
    :func:`polygon_edges`' table, (E,)) an odd number of times: the point is inside.  The caller
    silences overflow (see :func:`points_in_polygon`)."""
    crosses = ((yi <= py) != (yj <= py)) & (px < xi + (py - yi) * slope)
    return (np.count_nonzero(crosses, axis=1) & 1).astype(bool)


def segment_projections(points: np.ndarray, a: np.ndarray, ab: np.ndarray) \
        -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each point (P, 2) against each segment from ``a`` (S, 2) along ``ab`` (S, 2): (the fraction
    along the segment of the point's nearest point on it (P, S), the squared distance to it (P, S),
    the squared lengths (S,), a degenerate segment's floored so that it divides)."""
    length2 = np.maximum((ab ** 2).sum(1), 1e-18)
    ap = points[:, None, :] - a[None]
    t = np.clip((ap * ab[None]).sum(2) / length2, 0.0, 1.0)
    gap = ap - t[..., None] * ab[None]
    return t, (gap ** 2).sum(2), length2


def outline_distance(points: np.ndarray, outline: np.ndarray) -> np.ndarray:
    """(P,) distance from each point (P, 2) to the edges of a closed outline (K, 2)."""
    _, distance2, _ = segment_projections(points, outline, np.roll(outline, -1, axis=0) - outline)
    return np.sqrt(distance2).min(1)
