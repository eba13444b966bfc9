"""The obstacle frame compiled with numba: ``evaluate_cloud``'s path when numba is installed.

One pass over the cloud, in chunks of CHUNK points whose records stay in L1.  Per
16 records, ``cloud_simd.scan16`` computes their cells (one wide load, shuffles,
float32), gathers the cells' entries and appends the points of listed cells
(a compress).  Then the chunk's candidates, eight at a time in float64 vectors
(``cloud_simd.boxes8``): most lie in a cell of one box, tested against it alone,
or inside the area polygon, where the z range decides (``cloud_jit_grid``); the
rest go through each box of their cell and the polygons, one at a time.  Every
verdict is the float64 expression the numpy path evaluates, so the two agree
point for point.  The records are read in place: x, y, z are viewed as one record
type (stride and offsets known to the compiler) whatever else the cloud holds.
"""
from __future__ import annotations

import threading
from functools import lru_cache

import numpy as np

from .cloud_jit_grid import AVAILABLE, CX, CY, CZ, HX, HY, HZ, COS, SIN, LOW
from .cloud_jit_grid import FIRST, MAX_CELLS, build, cell_of, clear, compiled, in_polygon
from .cloud_types import Area, BoxSet, CloudCounts, xyz_columns

if AVAILABLE:
    from .cloud_simd import bit, boxes8, compact16, scan16
else:  # pragma: no cover - exercised where numba is absent
    bit = boxes8 = compact16 = scan16 = None

CHUNK = 2048  # points per step (32 KB of XYZIRC records, in L1); 1024 was 5 % slower (per-step costs)


@compiled
def _on_road(px, py, edges, ends, clip_boxes):
    """In the area polygon and, when there are lanelet clips, in one of them."""
    if not in_polygon(px, py, edges, FIRST, ends[0]):
        return False
    if len(clip_boxes) == 0:
        return True
    for c in range(len(clip_boxes)):
        if (clip_boxes[c, 0] <= px <= clip_boxes[c, 2] and clip_boxes[c, 1] <= py <= clip_boxes[c, 3]
                and in_polygon(px, py, edges, ends[c], ends[c + 1])):
            return True
    return False


@compiled
def _frame(rec, x0, y0, inv, xmax, ymax, gx, table, next_node, node_box, box, z_range, edges, ends, clip_boxes):
    """Per box (``box`` has at least one row): points inside, and the nearest one (first in
    cloud order on ties), as x y z (NaN: none).  And the area points, in cloud order."""
    n, nb = len(rec), len(box)
    counts, nearest, best = np.zeros(nb, np.int64), np.full(nb, -1, np.int64), np.full(nb, np.inf)
    keys = np.zeros(16, np.int32)
    cand, val, generic = np.empty(CHUNK + 16, np.int32), np.empty(CHUNK + 16, np.int32), np.empty(CHUNK + 8, np.int32)
    hits, dist = np.empty(CHUNK + 8, np.int32), np.empty(CHUNK + 16)
    late = np.empty(CHUNK, np.int32)
    area = np.empty(4 * CHUNK, np.int32)
    n_area = n_cands = 0
    zlo, zhi = z_range[0], z_range[1]
    gx32 = np.int32(gx)
    for s in range(0, n, CHUNK):
        m = min(n - s, CHUNK)
        if n_area + m + 8 > len(area):  # room for every point of this chunk, and a vector's spare lanes
            more = np.empty(2 * len(area), np.int32)
            more[:n_area] = area[:n_area]
            area = more
        n_cand = 0
        full = m - m % 16
        for b in range(0, full, 16):
            n_cand = scan16(rec, s + b, x0, y0, inv, xmax, ymax, gx, table, cand, val, n_cand)
        if full < m:  # the last few points of the cloud
            for j in range(16):
                keys[j] = 0  # cell 0 is a border cell: never a candidate
            for j in range(m - full):
                i, jj = cell_of(rec[s + full + j].x, rec[s + full + j].y, x0, y0, inv, xmax, ymax)
                keys[j] = jj * gx32 + i
            n_cand = compact16(table, keys, 0, s + full, cand, val, n_cand)
        n_cands += n_cand
        # Eight at a time in vectors: cells of one box (or none) and decided area, the rest
        # queued; then the counts and nearest points of the hits, in cloud order.
        for k in range(8):  # the last vector's spare lanes read a valid point of cell 0
            cand[n_cand + k], val[n_cand + k] = s, 0
        n_hit, n_gen, first_area = 0, 0, n_area
        for t in range(0, n_cand, 8):
            n_hit, n_area, n_gen = boxes8(rec, cand, val, t, n_cand - t, box, zlo, zhi, hits, n_hit, dist, area,
                                          n_area, generic, n_gen)
        for h in range(n_hit):
            t = hits[h]
            b = val[t] & LOW
            counts[b] += 1
            if dist[t] < best[b]:  # rarely: cloud order is no distance order
                best[b], nearest[b] = dist[t], cand[t]
        # The exact tests of BoxSet.contains and points_in_polygon.  Ties of the nearest point
        # go to the first in cloud order, though this loop runs after the one above.
        n_late = 0
        for u in range(n_gen):
            t = generic[u]
            v, i = val[t], np.int64(cand[t])
            px, py, pz = np.float64(rec[i].x), np.float64(rec[i].y), np.float64(rec[i].z)
            in_box = 0
            node = (v & LOW) - 1
            while node >= 0:
                b = node_box[node]
                dx, dy = px - box[b, CX], py - box[b, CY]
                inside = (bit(abs(dx * box[b, COS] + dy * box[b, SIN]) <= box[b, HX])
                          & bit(abs(dy * box[b, COS] - dx * box[b, SIN]) <= box[b, HY])
                          & bit(abs(pz - box[b, CZ]) <= box[b, HZ]))
                counts[b] += inside
                in_box |= inside
                d2 = px * px + py * py + pz * pz
                d2 = d2 if inside else np.inf
                if d2 < best[b] or (d2 == best[b] and inside and i < nearest[b]):
                    best[b], nearest[b] = d2, i
                node = next_node[node]
            if (in_box ^ 1) & ((v >> 28) & 1) & (pz >= zlo) & (pz <= zhi):  # rarely: an area point?
                if _on_road(px, py, edges, ends, clip_boxes):
                    late[n_late] = i
                    n_late += 1
        # Both lists of this chunk's area points are in cloud order: merged from the back.
        a, w = n_area - 1, n_area + n_late - 1
        for l in range(n_late - 1, -1, -1):
            while a >= first_area and area[a] > late[l]:
                area[w] = area[a]
                a -= 1
                w -= 1
            area[w] = late[l]
            w -= 1
        n_area += n_late
    area_xyz = np.empty((n_area, 3))
    for a in range(n_area):
        i = area[a]
        area_xyz[a, 0], area_xyz[a, 1], area_xyz[a, 2] = rec[i].x, rec[i].y, rec[i].z
    near = np.full((nb, 3), np.nan)
    for b in range(nb):
        if nearest[b] >= 0:
            i = nearest[b]
            near[b, 0], near[b, 1], near[b, 2] = rec[i].x, rec[i].y, rec[i].z
    return counts, near, area_xyz, n_cands


_scratch = threading.local()  # per thread (the kernels release the GIL): the grid's table, all zeros
_NO_AREA_BOX, _NO_POLYGON = np.array([1.0, 1.0, 0.0, 0.0, 0.0, 0.0]), np.zeros((0, 2))
# Read-only as Area.aabb() is: numba types an array by its flags too, and a writable one here
# compiled the frame kernels (tens of seconds on a cold start) a second time for frames without an area.
_NO_AREA_BOX.setflags(write=False)
_NO_EDGES = np.zeros((0, 4)), np.zeros(1, np.int64), np.zeros((0, 4))


@compiled
def _evaluate(rec, centers, half, yaws, area_box, z_min, z_max, poly, edges, ends, clip_boxes, clipped, table):
    """The box table, the grid, the frame, the grid's table zeroed again: one call from Python."""
    nb = len(yaws)
    box = np.zeros((max(nb, 1), 8))  # a row at least: the frame indexes row 0 for cells of no box
    for b in range(nb):
        box[b, CX], box[b, CY], box[b, CZ] = centers[b, 0], centers[b, 1], centers[b, 2]
        box[b, HX], box[b, HY], box[b, HZ] = half[b, 0], half[b, 1], half[b, 2]
        box[b, COS], box[b, SIN] = np.cos(yaws[b]), np.sin(yaws[b])
    x0, y0, inv, xmax, ymax, gx, table, next_node, node_box, touched = build(box[:nb], area_box, poly, edges,
                                                                             clipped, table)
    z_range = np.array([z_min, z_max])
    counts, nearest, area_points, n_cands = _frame(rec, x0, y0, inv, xmax, ymax, gx, table, next_node, node_box, box,
                                                   z_range, edges, ends, clip_boxes)
    clear(table, touched)
    return counts[:nb], nearest[:nb], area_points, n_cands


class _Records:
    """x, y, z of a cloud as one record type over its own memory (keeps ``base`` alive)."""

    def __init__(self, base, addr: int, itemsize: int, n: int):
        self.base = base
        self.__array_interface__ = {"shape": (n,), "typestr": f"|V{itemsize}", "data": (addr, True),
                                    "strides": None, "version": 3}


@lru_cache(maxsize=64)
def _record_type(field: str, offsets: tuple, stride: int) -> np.dtype:
    return np.dtype({"names": ["x", "y", "z"], "formats": [field] * 3, "offsets": list(offsets), "itemsize": stride})


@lru_cache(maxsize=64)
def _view_type(dtype: np.dtype) -> np.dtype | None:
    """The x, y, z record type a contiguous structured cloud of ``dtype`` can be viewed as."""
    fields = [dtype.fields.get(k) for k in "xyz"] if dtype.names else [None]
    if None in fields:
        return None
    (tx, ox), (ty, oy), (tz, oz) = (f[:2] for f in fields)
    size = tx.itemsize
    if (tx not in (np.float32, np.float64) or not tx.isnative or not tx == ty == tz
            or not (ox + size <= oy and oy + size <= oz and oz + size <= dtype.itemsize)):
        return None
    return _record_type(tx.str, (ox, oy, oz), dtype.itemsize)


def records(points: np.ndarray) -> np.ndarray:
    """A (N,) C-contiguous record array of fields x, y, z viewing the points' memory where
    their layout allows (one native float type, one stride), else a float64 copy."""
    if points.ndim == 1 and points.flags.c_contiguous and points.dtype.names:
        view = _view_type(points.dtype)
        if view is not None:  # the common case, in microseconds
            return points.view(view)
    x, y, z = xyz_columns(points)
    cols = (x, y, z)
    if (x.dtype in (np.float32, np.float64) and x.dtype.isnative and all(c.dtype == x.dtype for c in cols)
            and len({c.strides for c in cols}) == 1 and x.strides[0] > 0):
        stride, size = x.strides[0], x.dtype.itemsize
        addr = [c.__array_interface__["data"][0] for c in cols]
        offsets = [a - addr[0] for a in addr]
        if 0 < offsets[1] - offsets[0] and 0 < offsets[2] - offsets[1] and offsets[2] + size <= stride \
                and offsets[1] >= size and offsets[2] - offsets[1] >= size:
            dtype = _record_type(x.dtype.str, tuple(offsets), stride)
            return np.asarray(_Records(points, addr[0], stride, len(x))).view(dtype)
    out = np.empty(len(x), [("x", "<f8"), ("y", "<f8"), ("z", "<f8")])
    out["x"], out["y"], out["z"] = x, y, z
    return out


def evaluate(points: np.ndarray, boxes: BoxSet, area: Area | None) -> CloudCounts:
    """``evaluate_cloud`` for a non-empty cloud; ``area`` is None when it is not checked."""
    if area is None:  # an empty box (lo > hi) and no edges: no cell is the area's
        area_box, z_min, z_max, poly = _NO_AREA_BOX, 1.0, 0.0, _NO_POLYGON
        (edges, ends, clip_boxes), clipped = _NO_EDGES, False
    else:
        area_box, z_min, z_max, poly = area.aabb(), float(area.z_min), float(area.z_max), area.polygon
        (edges, ends, clip_boxes), clipped = area.edge_table, area.clips is not None
        if poly.dtype != np.float64:
            poly = poly.astype(np.float64)
    table = getattr(_scratch, "table", None)
    if table is None:
        table = _scratch.table = np.zeros(MAX_CELLS, np.int32)
    f64 = np.float64
    centers, half = np.asarray(boxes.centers, f64).reshape(-1, 3), np.asarray(boxes.half, f64).reshape(-1, 3)
    counts, nearest, area_points, n_cands = _evaluate(records(points), centers, half, np.asarray(boxes.yaws, f64).ravel(),
                                                      area_box, z_min, z_max, poly, edges, ends, clip_boxes, clipped,
                                                      table)
    return CloudCounts(counts, nearest, area_points, candidates=n_cands)
