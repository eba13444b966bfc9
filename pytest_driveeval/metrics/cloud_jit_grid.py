"""The grid of cloud_jit's frame kernel: per cell, what a point landing there needs to be judged.

A point's cell is computed in float32 (``cell_of``); cells are judged on their
footprint dilated by ``m``, which covers that rounding many times over, so a
cell's class holds for every point the lookup puts in it.  Table entry of a cell:

* 0: no box footprint and no area touches it: its points are in nothing;
* ``ONE | b``: box b's footprint touches it, no other box's: a point there is in
  box b or in none;
* ``AREA_IN``: inside the area polygon (no lanelet clips): a point in no box is
  an area point exactly when z is in the area's range;
* both, or either with no box / no area around;
* otherwise (GENERIC) the low bits are 1 + the head of the cell's list of
  boxes (0: none) and ``AREA_BIT`` says the area's bounds touch it: the exact
  float64 tests run.
"""
from __future__ import annotations

import numpy as np

try:
    from numba import njit
except ImportError:  # pragma: no cover - exercised where numba is absent
    njit = None

AVAILABLE = njit is not None
ONE, AREA_IN, AREA_BIT = 1 << 30, 1 << 29, 1 << 28
LOW = AREA_BIT - 1
CX, CY, CZ, HX, HY, HZ, COS, SIN = range(8)  # columns of the box table
SIDE = 250  # cells along the grid's longer side
MAX_CELLS = (SIDE + 4) ** 2  # a table this long serves every grid
# in_polygon's first edge as an int64 value: a literal 0 would compile it a second time
FIRST = np.int64(0)


def compiled(fn):
    return njit(cache=True, nogil=True, boundscheck=False)(fn) if AVAILABLE else fn


@compiled
def in_polygon(px, py, edges, lo, hi):
    """Crossing number over edges lo..hi-1: the rule and float64 expression of points_in_polygon."""
    inside = False
    for e in range(lo, hi):
        if (edges[e, 1] <= py) != (edges[e, 2] <= py) and px < edges[e, 0] + (py - edges[e, 1]) * edges[e, 3]:
            inside = not inside
    return inside


@compiled
def cell_of(px, py, x0, y0, inv, xmax, ymax):
    """Cell column and row of a point, in float32; off-grid and NaN points land on the border."""
    zero = np.float32(0.0)
    fx = (np.float32(px) - x0) * inv
    fy = (np.float32(py) - y0) * inv
    fx = fx if fx > zero else zero
    fy = fy if fy > zero else zero
    fx = fx if fx < xmax else xmax
    fy = fy if fy < ymax else ymax
    return np.int32(fx), np.int32(fy)


@compiled
def _clear_of_edges(poly, xa, ya, xb, yb):
    """Whether no edge of the closed polygon ``poly`` meets the rectangle (conservative)."""
    nv = len(poly)
    for e in range(nv):
        ax, ay = poly[e, 0], poly[e, 1]
        bx, by = poly[(e + 1) % nv, 0], poly[(e + 1) % nv, 1]
        if max(ax, bx) < xa or min(ax, bx) > xb or max(ay, by) < ya or min(ay, by) > yb:
            continue
        above = below = 0
        for cx in (xa, xb):
            for cy in (ya, yb):
                side = (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)
                above += side > 0.0
                below += side < 0.0
        if above < 4 and below < 4:
            return False
    return True


@compiled
def build(box, area_box, poly, edges, clipped, table):
    """The grid: origin, 1 / cell and border limits (float32, as cell_of computes), width,
    the table of cell entries (in ``table`` when it is long enough), the box lists (next
    node, box) of GENERIC cells, and the cells written (``clear`` zeroes them again).

    A cell is listed for a box when the cell, dilated by ``m``, overlaps the box's
    footprint (separating axes: the box's AABB gives the cell axes, the loop tests the
    box's own two)."""
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
    inv = np.float32(1.0 / max(max(hi[0] - lo[0], hi[1] - lo[1]) / SIDE, 8 * m_abs))
    cell = 1.0 / np.float64(inv)
    m = m_abs + 1e-3 * cell
    # A border cell each side, never listed: cell_of clamps the points off the grid onto it.
    x0, y0 = np.float32(lo[0] - m - cell), np.float32(lo[1] - m - cell)
    gx, gy = int((hi[0] + m - x0) / cell) + 2, int((hi[1] + m - y0) / cell) + 2

    if len(table) < gx * gy:  # the caller's buffer is all zeros and at least MAX_CELLS long
        table = np.zeros(gx * gy, np.int32)
    spans = np.empty((nb, 4), np.int64)
    n_nodes = 0
    for b in range(nb):
        spans[b, 0] = max(int((box[b, CX] - ext[b, 0] - m - x0) / cell), 1)
        spans[b, 1] = min(int((box[b, CX] + ext[b, 0] + m - x0) / cell), gx - 2)
        spans[b, 2] = max(int((box[b, CY] - ext[b, 1] - m - y0) / cell), 1)
        spans[b, 3] = min(int((box[b, CY] + ext[b, 1] + m - y0) / cell), gy - 2)
        n_nodes += max(spans[b, 1] - spans[b, 0] + 1, 0) * max(spans[b, 3] - spans[b, 2] + 1, 0)
    ai0 = max(int((area_box[0] - m - x0) / cell), 1) if has_area else 1
    ai1 = min(int((area_box[3] + m - x0) / cell), gx - 2) if has_area else 0
    aj0 = max(int((area_box[1] - m - y0) / cell), 1) if has_area else 1
    aj1 = min(int((area_box[4] + m - y0) / cell), gy - 2) if has_area else 0
    next_node, node_box = np.empty(n_nodes, np.int32), np.empty(n_nodes, np.int32)
    touched = np.empty(n_nodes + max(ai1 - ai0 + 1, 0) * max(aj1 - aj0 + 1, 0), np.int64)
    n_touched = n_nodes = 0
    for b in range(nb):
        c, s, cx, cy, hx, hy = box[b, COS], box[b, SIN], box[b, CX], box[b, CY], box[b, HX], box[b, HY]
        r = (0.5 * cell + m) * (abs(c) + abs(s))  # the dilated cell's half extent on a box axis
        for j in range(spans[b, 2], spans[b, 3] + 1):
            dy = y0 + (j + 0.5) * cell - cy
            for i in range(spans[b, 0], spans[b, 1] + 1):
                dx = x0 + (i + 0.5) * cell - cx
                u, v = abs(dx * c + dy * s), abs(dy * c - dx * s)
                if u <= hx + r and v <= hy + r:
                    k = j * gx + i
                    if table[k] == 0:
                        touched[n_touched] = k
                        n_touched += 1
                    next_node[n_nodes], node_box[n_nodes] = table[k] - 1, b
                    table[k] = n_nodes + 1
                    n_nodes += 1
    for j in range(aj0, aj1 + 1):
        for i in range(ai0, ai1 + 1):
            if table[j * gx + i] == 0:
                touched[n_touched] = j * gx + i
                n_touched += 1
    for t in range(n_touched):  # the final entries
        k = touched[t]
        head = table[k] - 1
        i, j = k % gx, k // gx
        decided = head < 0 or next_node[head] < 0
        entry = ONE | node_box[head] if decided and head >= 0 else 0
        in_area = ai0 <= i <= ai1 and aj0 <= j <= aj1
        if decided and in_area:
            xa, ya = x0 + i * cell - m, y0 + j * cell - m
            xb, yb = xa + cell + 2 * m, ya + cell + 2 * m
            decided = not clipped and _clear_of_edges(poly, xa, ya, xb, yb)
            if decided and in_polygon(0.5 * (xa + xb), 0.5 * (ya + yb), edges, FIRST, len(poly)):
                entry |= AREA_IN
        table[k] = entry if decided else (head + 1) | (AREA_BIT if in_area else 0)
    xmax, ymax = np.float32(gx - 1), np.float32(gy - 1)
    return x0, y0, inv, xmax, ymax, gx, table, next_node, node_box, touched[:n_touched]


@compiled
def clear(table, touched):
    """Zero the cells ``build`` wrote, so that the table serves the next frame."""
    for t in range(len(touched)):
        table[touched[t]] = 0
