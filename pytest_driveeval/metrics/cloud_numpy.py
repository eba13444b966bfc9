"""The obstacle frame in numpy alone: ``evaluate_cloud``'s path where numba is absent.

Both questions of a frame (which boxes hold each point, is it in the area) are
answered after a single pass over all points: a coarse 255 x 255 grid (the boxes'
footprints rasterised exactly, the area's bounds) flags the few points worth an
exact test.  The pass reads x, y as one complex64 per point, scales, clips and casts
to an int8 pair that is itself the uint16 table key, in L2-sized chunks: five array
operations over N.  Points in cells inside a single box's footprint need only the z
test; all exact tests run in float64 on the survivors.
"""
from __future__ import annotations

import threading

import numpy as np

from ..geometry.polygons import points_in_polygon
from .cloud_types import Area, BoxSet, CloudCounts, xyz_columns


MULTI = -2  # grid label of a cell touched by several boxes
_C64 = np.dtype(np.complex64)
_CHUNK = 1 << 17  # points per step of the full pass (fewer, longer numpy calls measured faster)
_INTP_MAX = int(np.iinfo(np.intp).max)
# Grid cell flags.  BOX: a box footprint may touch the cell; INNER: the cell lies inside
# the footprint of its (single) box, so only z needs testing; AREA: inside the area's bounds.
BOX, AREA, INNER = 1, 2, 4


_scratch = threading.local()  # per thread, so that threads may evaluate frames at once


def _buffers(n: int):
    """Scratch arrays of the full pass, reused across frames of the same size."""
    b = getattr(_scratch, "bufs", None)
    if b is None or len(b[2]) != n:
        b = _scratch.bufs = (np.empty(min(n, _CHUNK), _C64), np.empty(2 * n, np.int8), np.empty(n, np.uint8))
    return b


class _Strided:
    """Wraps raw strided memory so numpy can view it with another dtype (keeps ``base`` alive)."""

    def __init__(self, base, addr: int, typestr: str, n: int, stride: int):
        self.base = base
        self.__array_interface__ = {"shape": (n,), "typestr": typestr, "data": (addr, True),
                                    "strides": (stride,), "version": 3}


def _xy_complex(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """x + i y with no copy when y directly follows x in memory (XYZ clouds, (N, 3) arrays)."""
    if (x.ndim == 1 and x.dtype == y.dtype and x.dtype in (np.float32, np.float64) and x.dtype.isnative
            and x.strides == y.strides and len(x) == len(y)):
        ax, ay = x.__array_interface__["data"][0], y.__array_interface__["data"][0]
        if ay - ax == x.dtype.itemsize:
            ctype = np.dtype(np.complex64 if x.dtype == np.float32 else np.complex128)
            return np.asarray(_Strided(x, ax, ctype.str, len(x), x.strides[0]))
    c = np.empty(len(x), _C64)
    c.real, c.imag = x, y
    return c


def _keys(rows, cols):
    """Table key of cells: the (col, row) int8 pair read as a little-endian uint16."""
    return ((rows & 255) << 8) | (cols & 255)


def _expand(rows, lo, hi):
    """Keys of the cells lo..hi (inclusive) of each row; rows with hi < lo give none."""
    length = np.maximum(hi - lo + 1, 0)
    ends = np.cumsum(length)
    if not len(ends) or ends[-1] == 0:
        return np.zeros(0, np.intp), length
    cols = np.repeat(lo - (ends - length), length) + np.arange(ends[-1])
    return _keys(np.repeat(rows, length), cols), length


class _Grid:
    """A 255 x 255 grid centred on base_link.  A point's cell is (trunc(x / cell),
    trunc(y / cell)) computed in float32 (cell 0 is twice as wide); a cell has flags
    (BOX | INNER | AREA) and a box label (index, MULTI, or -1 for area-only cells).
    Box footprints are rasterised exactly (the oriented rectangle's x extent, and inner
    x extent, within each row of cells) with a ``margin`` that covers the float32
    rounding of the per-point lookup, so no point inside a box or the area is missed."""

    def __init__(self, boxes: BoxSet, area: Area | None):
        nb = len(boxes)
        fp = boxes.footprints()  # (B, 4, 2)
        area_box = None if area is None else area.aabb()
        reach = float(np.max(np.abs(fp))) if nb else 0.0
        if area_box is not None:
            reach = max(reach, float(np.max(np.abs(area_box[[0, 1, 3, 4]]))))
        m_abs = 1e-5 * (reach + 1.0)  # >> float32 rounding of coordinates of this size
        # The per-point lookup runs in float32: rasterise with exactly that float32 scale.
        self.inv = np.float32(1.0 / max((reach + 2 * m_abs) / 125.0, 8 * m_abs))
        cell = 1.0 / float(self.inv)
        m = m_abs + 1e-3 * cell
        flags = np.zeros(1 << 16, dtype=np.uint8)
        labels = np.empty(1 << 16, dtype=np.int16)  # read only where flags != 0

        def index(v):  # trunc cell index of coordinates, as the per-point lookup computes it
            return np.trunc(np.asarray(v) * (1.0 / cell)).astype(np.intp)

        area_keys = None
        if area_box is not None:
            (c0, r0), (c1, r1) = index(area_box[:2] - m), index(area_box[3:5] + m)
            area_keys = (np.arange(r0, r1 + 1)[:, None] & 255) << 8 | (np.arange(c0, c1 + 1) & 255)
            labels[area_keys] = -1
        if nb:
            # Rows of cells each box spans.  Per (box, row): the x extent of the footprint
            # within the row's dilated band [ya, yb], and its chords at the lines ya and yb,
            # whose overlap is the inner extent (the footprint is convex).  An extent is that
            # of the 4 edges, each clipped to the band (a line is a band of height 0).
            j0, j1 = index(fp[:, :, 1].min(axis=1) - m), index(fp[:, :, 1].max(axis=1) + m)
            j = j0[:, None] + np.arange(int(np.max(j1 - j0)) + 1)  # (B, R)
            ya = (j - (j <= 0)) * cell - m  # cell 0 spans [-1, 1]
            yb = (j + (j >= 0)) * cell + m
            # Layout (edge, kind, box * row): broadcasting runs over the long last axis.
            lo_y = np.stack([ya, ya, yb]).reshape(1, 3, -1)  # kinds: band, line ya, line yb
            hi_y = np.stack([yb, ya, yb]).reshape(1, 3, -1)
            edge = np.stack([fp, fp[:, [1, 2, 3, 0]] - fp]).transpose(0, 3, 2, 1)  # (p/e, x/y, edge, box)
            (px, py), (ex, ey) = np.repeat(edge, j.shape[1], axis=3)[:, :, :, None, :]
            with np.errstate(divide="ignore", invalid="ignore"):
                ta, tb = (lo_y - py) / ey, (hi_y - py) / ey
                t0 = np.maximum(np.minimum(ta, tb), 0.0)
                t1 = np.minimum(np.maximum(ta, tb), 1.0)
            flat = ey == 0  # a horizontal edge lies in the band or not
            if flat.any():
                t0 = np.where(flat, np.where((py >= lo_y) & (py <= hi_y), 0.0, 2.0), t0)
                t1 = np.where(flat, 1.0, t1)
            ok = t0 <= t1
            xa, xb = px + t0 * ex, px + t1 * ex
            xlo = np.where(ok, np.minimum(xa, xb), np.inf).min(axis=0).reshape(3, *j.shape)  # (3, B, R)
            xhi = np.where(ok, np.maximum(xa, xb), -np.inf).max(axis=0).reshape(3, *j.shape)
            xlo[0][j > j1[:, None]] = np.inf
            inner_lo, inner_hi = np.maximum(xlo[1], xlo[2]), np.minimum(xhi[1], xhi[2])
            xlo, xhi = xlo[0], xhi[0]
            # Column ranges: every cell touching the dilated extent; inner cells, dilated, inside it.
            out = np.isfinite(xlo)
            lo = index(np.where(out, xlo - m, 0.0))
            hi = np.where(out, index(np.where(out, xhi + m, 0.0)), lo - 1)
            inn = np.isfinite(inner_lo) & np.isfinite(inner_hi)
            with np.errstate(invalid="ignore"):
                a = np.where(inn, np.ceil((inner_lo + m) * (1.0 / cell)), 1.0).astype(np.intp)
                b = np.where(inn, np.floor((inner_hi - m) * (1.0 / cell)), 0.0).astype(np.intp)
            rows = np.concatenate([j.ravel(), j.ravel()])
            keys, length = _expand(rows, np.concatenate([lo.ravel(), (a + (a <= 0)).ravel()]),
                                   np.concatenate([hi.ravel(), (b - (b >= 0)).ravel()]))
            n_out = int(length[:lo.size].sum())
            keys, inner = keys[:n_out], keys[n_out:]
            owner = np.repeat(np.repeat(np.arange(nb, dtype=np.int16), j.shape[1]), length[:lo.size])
            flags[keys] = BOX
            labels[keys] = owner
            if nb > 1:  # a cell of several boxes keeps one owner's label: the others see it
                labels[keys[labels.take(keys) != owner]] = MULTI
            flags[inner] = BOX | INNER  # inner cells are cells of their box
        if area_keys is not None:
            flags[area_keys] |= AREA
        self.flags, self.labels = flags, labels

    def candidates(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Indices of the points whose cell is flagged, and those cells' keys.  The
        only passes over all points: five array operations per chunk of _CHUNK points."""
        xy = _xy_complex(x, y)
        n = len(xy)
        u, k8, hit = _buffers(n)
        f = u.view(np.float32)  # col, row, col, row, ...
        k16 = k8.view(np.uint16)
        lim = np.float32(127)
        flags = self.flags
        with np.errstate(invalid="ignore"):  # NaN coordinates land somewhere; the exact tests reject them
            for s in range(0, n, _CHUNK):
                k = min(n - s, _CHUNK)
                uk, fk = u[:k], f[:2 * k]
                np.multiply(xy[s:s + k], self.inv, out=uk, dtype=_C64)
                np.clip(fk, -lim, lim, out=fk)
                np.copyto(k8[2 * s:2 * (s + k)], fk, casting="unsafe")
                flags.take(k16[s:s + k], out=hit[s:s + k], mode="wrap")
        idx = np.flatnonzero(hit.view(bool))
        key = k16.take(idx)
        if not np.little_endian:  # pragma: no cover - the int8 pair reads the other way round
            key = key.byteswap()
        return idx, key


def _box_pairs(boxes: BoxSet, x, y, z, labels, flags) -> tuple[np.ndarray, np.ndarray]:
    """(point, box) index pairs with the point inside the box.  A point in a
    single-box cell is tested against that box only (z only in an INNER cell);
    MULTI cells against all.  The float64 tests are those of BoxSet.contains."""
    sing = np.flatnonzero(labels >= 0)
    b = labels.take(sing).astype(np.intp)
    cx, cy, cz = boxes.centers.T
    hx, hy, hz = boxes.half.T
    # z first (all single-box points), then x/y for the edge-cell points that passed it.
    dz = z.take(sing)
    dz -= cz.take(b)
    np.abs(dz, out=dz)
    ok = dz <= hz.take(b)
    ok_edge = ok & ~(flags.take(sing) & INNER).astype(bool)
    e = np.flatnonzero(ok_edge)
    if len(e):
        eb, ei = b.take(e), sing.take(e)
        c, s = np.cos(boxes.yaws), np.sin(boxes.yaws)
        ce, se = c.take(eb), s.take(eb)
        dx = x.take(ei)
        dx -= cx.take(eb)
        dy = y.take(ei)
        dy -= cy.take(eb)
        t = dx * ce
        t += dy * se
        np.abs(t, out=t)
        exy = t <= hx.take(eb)
        t = dy * ce
        t -= dx * se
        np.abs(t, out=t)
        exy &= t <= hy.take(eb)
        ok[e] = exy
    k = np.flatnonzero(ok)  # (boolean-mask indexing is several times slower than take)
    pairs, owners = [sing.take(k)], [b.take(k)]
    multi = np.flatnonzero(labels == MULTI)
    if len(multi):
        mp, mb = np.nonzero(boxes.contains(x[multi], y[multi], z[multi]))
        pairs.append(multi[mp])
        owners.append(mb)
    return np.concatenate(pairs), np.concatenate(owners)


def _nearest_per_box(dist2: np.ndarray, box: np.ndarray, point: np.ndarray, nb: int) -> np.ndarray:
    """Per box id, the smallest ``point`` among the pairs of least dist2 (-1 for absent ids)."""
    mins = np.full(nb, np.inf)
    np.minimum.at(mins, box, dist2)
    tie = np.flatnonzero(dist2 == mins.take(box))
    big = _INTP_MAX
    out = np.full(nb, big, dtype=np.intp)
    np.minimum.at(out, box.take(tie), point.take(tie))
    out[out == big] = -1
    return out


def evaluate(points: np.ndarray, boxes: BoxSet, area: Area | None) -> CloudCounts:
    """``evaluate_cloud`` for a non-empty cloud; ``area`` is None when it is not checked."""
    x, y, z = xyz_columns(points)
    nb = len(boxes)
    counts = np.zeros(nb, dtype=np.int64)
    nearest = np.full((nb, 3), np.nan)
    grid = _Grid(boxes, area)
    idx, key = grid.candidates(x, y)
    flags, labels = grid.flags.take(key), grid.labels.take(key)
    # One gather of whole records, then float64 columns of the few candidates.
    cx, cy, cz = (np.asarray(c, dtype=np.float64) for c in xyz_columns(points.take(idx, axis=0)))
    with np.errstate(all="ignore"):
        if np.isnan(cx.sum() + cy.sum()):  # NaN x/y land in an arbitrary cell: drop them
            ok = ~(np.isnan(cx) | np.isnan(cy))
            idx, flags, labels, cx, cy, cz = (a[ok] for a in (idx, flags, labels, cx, cy, cz))

    in_box = None
    if nb:
        pi, bi = _box_pairs(boxes, cx, cy, cz, labels, flags)
        counts = np.bincount(bi, minlength=nb).astype(np.int64)
        if len(pi):
            px, py, pz = cx.take(pi), cy.take(pi), cz.take(pi)
            first = _nearest_per_box(px ** 2 + py ** 2 + pz ** 2, bi, pi, nb)  # first in cloud order on ties
            has = np.flatnonzero(counts)
            take = first[has]
            nearest[has] = np.stack([cx.take(take), cy.take(take), cz.take(take)], axis=1)
            in_box = np.zeros(len(idx), dtype=bool)
            in_box[pi] = True
    area_points = np.zeros((0, 3))
    if area is not None:
        keep = (flags & AREA).astype(bool)
        keep &= cz >= area.z_min
        keep &= cz <= area.z_max
        if in_box is not None:
            keep &= ~in_box
        sel = np.flatnonzero(keep)
        sx, sy = cx.take(sel), cy.take(sel)
        inside = points_in_polygon(sx, sy, area.polygon)
        if area.clips is not None:
            on_road = np.zeros(len(sel), dtype=bool)
            for clip in area.clips:  # loop over lanelets, each test vectorised over points
                on_road |= points_in_polygon(sx, sy, clip)
            inside &= on_road
        sel = sel.take(np.flatnonzero(inside))
        area_points = np.stack([cx.take(sel), cy.take(sel), cz.take(sel)], axis=1)
    return CloudCounts(counts, nearest, area_points, candidates=len(idx))
