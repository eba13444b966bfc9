"""The obstacle frame compiled with numba: ``evaluate_cloud``'s path when numba is installed.

Three kernels.  ``_grid`` lists, for each cell of a grid over the boxes and the
area, the boxes whose footprint touches it.  ``_scan`` is the only pass over all
points: it copies the points of flagged cells out, in cloud order.  ``_judge``
tests those candidates exactly with the float64 expressions of
``BoxSet.contains`` and ``points_in_polygon``, so its verdicts are those of the
numpy path point for point.
"""
from __future__ import annotations

import threading

import numpy as np

from .cloud_types import Area, BoxSet, CloudCounts, xyz_columns

try:
    from numba import njit
except ImportError:  # pragma: no cover - exercised where numba is absent
    njit = None

AVAILABLE = njit is not None
# Columns of the box table handed to the kernels.
CX, CY, CZ, HX, HY, HZ, COS, SIN = range(8)


def _compiled(fn):
    return njit(cache=True, nogil=True, boundscheck=False)(fn) if AVAILABLE else fn


@_compiled
def _grid(box, area_box):
    """Grid over the boxes and the area: origin, 1 / cell (float32, as _scan computes
    cells), size, CSR lists of the boxes touching each cell, the cells of the area's
    bounds, and a flag per cell that is either.

    A cell is listed for a box when the cell, dilated by ``m``, overlaps the box's
    footprint (separating axes: the box's AABB gives the cell axes, the loop tests the
    box's own two).  ``m`` covers the float32 rounding of _scan's cell lookup, so a
    point in a box always lands in a cell listed for it."""
    nb = len(box)
    has_area = area_box[0] <= area_box[3] and area_box[1] <= area_box[4]
    ext = np.empty((nb, 2))
    lo, hi, reach = np.full(2, np.inf), np.full(2, -np.inf), 0.0
    for b in range(nb):
        ac, as_ = abs(box[b, COS]), abs(box[b, SIN])
        ext[b, 0] = ac * box[b, HX] + as_ * box[b, HY]
        ext[b, 1] = as_ * box[b, HX] + ac * box[b, HY]
        for d in range(2):
            lo[d] = min(lo[d], box[b, d] - ext[b, d])
            hi[d] = max(hi[d], box[b, d] + ext[b, d])
    if has_area:
        for d in range(2):
            lo[d], hi[d] = min(lo[d], area_box[d]), max(hi[d], area_box[d + 3])
    for d in range(2):
        reach = max(reach, abs(lo[d]), abs(hi[d]))
    m_abs = 1e-5 * (reach + 1.0)  # >> float32 rounding of coordinates of this size
    # At most ~250 cells a side, plus a border cell each side for the points off the grid.
    inv = np.float32(1.0 / max(max(hi[0] - lo[0], hi[1] - lo[1]) / 250.0, 8 * m_abs))
    cell = 1.0 / np.float64(inv)
    m = m_abs + 1e-3 * cell
    x0, y0 = np.float32(lo[0] - m - cell), np.float32(lo[1] - m - cell)
    gx, gy = int((hi[0] + m - x0) / cell) + 2, int((hi[1] + m - y0) / cell) + 2

    n_cells = gx * gy
    start = np.zeros(n_cells + 1, np.int32)
    members = np.empty(0, np.int32)
    fill = np.empty(0, np.int32)
    for p in range(2):  # count, then fill
        if p == 1:
            for k in range(n_cells):
                start[k + 1] += start[k]
            members = np.empty(start[n_cells], np.int32)
            fill = start[:n_cells].copy()
        for b in range(nb):
            c, s, cx, cy = box[b, COS], box[b, SIN], box[b, CX], box[b, CY]
            i0 = max(int((cx - ext[b, 0] - m - x0) / cell), 0)
            i1 = min(int((cx + ext[b, 0] + m - x0) / cell), gx - 1)
            j0 = max(int((cy - ext[b, 1] - m - y0) / cell), 0)
            j1 = min(int((cy + ext[b, 1] + m - y0) / cell), gy - 1)
            r = (0.5 * cell + m) * (abs(c) + abs(s))  # the dilated cell's half extent on a box axis
            for j in range(j0, j1 + 1):
                dy = y0 + (j + 0.5) * cell - cy
                for i in range(i0, i1 + 1):
                    dx = x0 + (i + 0.5) * cell - cx
                    if abs(dx * c + dy * s) <= box[b, HX] + r and abs(dy * c - dx * s) <= box[b, HY] + r:
                        k = j * gx + i
                        if p == 0:
                            start[k + 1] += 1
                        else:
                            members[fill[k]] = b
                            fill[k] += 1
    area = np.zeros(n_cells, np.uint8)
    if has_area:
        i0, i1 = max(int((area_box[0] - m - x0) / cell), 0), min(int((area_box[3] + m - x0) / cell), gx - 1)
        j0, j1 = max(int((area_box[1] - m - y0) / cell), 0), min(int((area_box[4] + m - y0) / cell), gy - 1)
        for j in range(j0, j1 + 1):
            area[j * gx + i0:j * gx + i1 + 1] = 1
    flagged = area.copy()
    for k in range(n_cells):
        if start[k + 1] > start[k]:
            flagged[k] = 1
    return x0, y0, inv, gx, gy, start, members, area, flagged


@_compiled
def _scan(x, y, z, x0, y0, inv, gx, gy, flagged, idx, keys, xyz):
    """Index, cell and coordinates of the points in flagged cells, in cloud order;
    returns how many.  Points off the grid (and NaN) are clamped onto its border,
    whose cells are never flagged."""
    n = 0
    xmax, ymax = np.float32(gx - 1), np.float32(gy - 1)
    zero = np.float32(0.0)
    for i in range(len(x)):
        px, py = x[i], y[i]
        fx = (np.float32(px) - x0) * inv
        fy = (np.float32(py) - y0) * inv
        fx = fx if fx > zero else zero
        fy = fy if fy > zero else zero
        fx = fx if fx < xmax else xmax
        fy = fy if fy < ymax else ymax
        k = np.uint32(fy) * np.uint32(gx) + np.uint32(fx)
        # Written for every point, kept for flagged ones: no branch to mispredict.
        idx[n] = i
        keys[n] = k
        xyz[n, 0] = px
        xyz[n, 1] = py
        xyz[n, 2] = z[i]
        n += flagged[k]
    return n


@_compiled
def _in_polygon(px, py, edges, lo, hi):
    """Crossing number over edges lo..hi-1: the rule and float64 expression of points_in_polygon."""
    inside = False
    for e in range(lo, hi):
        if (edges[e, 1] <= py) != (edges[e, 2] <= py) and px < edges[e, 0] + (py - edges[e, 1]) * edges[e, 3]:
            inside = not inside
    return inside


@_compiled
def _judge(xyz, idx, keys, start, members, area_cell, box, z_range, edges, ends, clip_boxes):
    """Per box: the points inside, and the nearest one (first in cloud order on ties).
    And the points of the area (polygon 0 of ``edges``, intersected with any of the
    clip polygons 1.. when there are some) outside every box."""
    nb = len(box)
    counts = np.zeros(nb, np.int64)
    nearest = np.full(nb, -1, np.int64)
    best = np.full(nb, np.inf)
    in_area = np.empty(len(idx), np.int64)
    n_area = 0
    for t in range(len(idx)):
        k = keys[t]
        px, py, pz = xyz[t, 0], xyz[t, 1], xyz[t, 2]
        in_box = False
        for mem in range(start[k], start[k + 1]):
            b = members[mem]
            dx, dy = px - box[b, CX], py - box[b, CY]
            if (abs(dx * box[b, COS] + dy * box[b, SIN]) <= box[b, HX]
                    and abs(dy * box[b, COS] - dx * box[b, SIN]) <= box[b, HY]
                    and abs(pz - box[b, CZ]) <= box[b, HZ]):
                in_box = True
                counts[b] += 1
                d2 = px ** 2 + py ** 2 + pz ** 2
                if d2 < best[b]:
                    best[b] = d2
                    nearest[b] = idx[t]
        if in_box or not area_cell[k] or not (pz >= z_range[0] and pz <= z_range[1]):
            continue
        if not _in_polygon(px, py, edges, 0, ends[0]):
            continue
        on_road = len(clip_boxes) == 0
        for c in range(len(clip_boxes)):
            if (clip_boxes[c, 0] <= px <= clip_boxes[c, 2] and clip_boxes[c, 1] <= py <= clip_boxes[c, 3]
                    and _in_polygon(px, py, edges, ends[c], ends[c + 1])):
                on_road = True
                break
        if on_road:
            in_area[n_area] = t
            n_area += 1
    return counts, nearest, in_area[:n_area]


_scratch = threading.local()  # per thread: the kernels release the GIL


def _buffers(n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Candidates' index, cell and float64 coordinates, reused across frames of the same size."""
    bufs = getattr(_scratch, "bufs", None)
    if bufs is None or len(bufs[0]) != n:
        bufs = _scratch.bufs = (np.empty(n, np.int64), np.empty(n, np.uint32), np.empty((n, 3)))
    return bufs


def evaluate(points: np.ndarray, boxes: BoxSet, area: Area | None) -> CloudCounts:
    """``evaluate_cloud`` for a non-empty cloud; ``area`` is None when it is not checked."""
    x, y, z = xyz_columns(points)
    if not all(c.dtype in (np.float32, np.float64) and c.dtype.isnative for c in (x, y, z)):
        x, y, z = (np.asarray(c, dtype=np.float64) for c in (x, y, z))  # big-endian, integer, half...
    box = np.column_stack([boxes.centers, boxes.half, np.cos(boxes.yaws), np.sin(boxes.yaws)])
    if area is None:  # an empty box (lo > hi) and no edges: no cell is the area's
        area_box, z_range = np.array([1.0, 1.0, 0.0, 0.0, 0.0, 0.0]), np.array([1.0, 0.0])
        edges, ends, clip_boxes = np.zeros((0, 4)), np.zeros(1, np.int64), np.zeros((0, 4))
    else:
        area_box, z_range = area.aabb(), np.array([area.z_min, area.z_max], dtype=np.float64)
        edges, ends, clip_boxes = area.edge_table
    x0, y0, inv, gx, gy, start, members, area_cell, flagged = _grid(box, area_box)
    idx, keys, xyz = _buffers(len(x))
    n = _scan(x, y, z, x0, y0, inv, gx, gy, flagged, idx, keys, xyz)
    counts, first, in_area = _judge(xyz[:n], idx[:n], keys[:n], start, members, area_cell, box, z_range,
                                    edges, ends, clip_boxes)
    nearest = np.full((len(boxes), 3), np.nan)
    has = np.flatnonzero(first >= 0)
    nearest[has] = np.stack([x[first[has]], y[first[has]], z[first[has]]], axis=1)
    return CloudCounts(counts, nearest, xyz[in_area], candidates=n)
