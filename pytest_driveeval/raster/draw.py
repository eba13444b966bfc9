"""Scan conversion with OpenCV's fixed-point rules, the way l5kit calls it.

l5kit draws every shape with ``shift=9`` (vertices are ``trunc(v * 512)``,
nine fractional bits) and ``lineType=LINE_AA``.  What OpenCV (3.x-4.x,
``drawing.cpp``) does with that, and what this module reproduces in integer
arithmetic so the pixels can agree exactly:

* Coordinates move to 16.16 fixed point (``<< 7``).
* ``fillPoly`` with several polygons collects the edges of all of them and
  fills once with the even-odd rule, so overlapping boxes of one call cancel
  where they overlap.  Before filling it outlines every edge with an
  anti-aliased line whose end rows are *rounded to whole pixels*
  (``(y + 256) >> 9``).  The fill walks rows: an edge covers rows
  ``[y_top, y_bottom)``, starts at its top vertex's x and steps by
  ``dx = trunc((x1 - x0) / (y1 - y0))`` a row; between each sorted pair of
  crossings it paints ``ceil(x_left) .. floor(x_right)``.
* ``polylines`` draws each segment as an anti-aliased line with full
  sub-pixel ends; closed ones start with the last-to-first segment.
* The anti-aliased line is a three-pixel-wide Gaussian stroke along the
  major axis (tables below), with end-point weights from the end points'
  fractions, clipped to the image (OpenCV 4.x; 3.x kept it two pixels off
  the border).  Each of its pixels is blended toward the colour *twice*:
  ``c += ((colour - c) * a + 127) >> 8``.

Arrays: an image is (H, W, channels) uint8; a set of polygons is
``verts`` (V, 2) int64 in 1/512 pixel and ``starts`` (P+1,) offsets.
Compiled with numba when installed; the same functions run as plain Python
(much slower) without it.
"""
from __future__ import annotations

import numpy as np

try:
    from numba import njit
except ImportError:  # pragma: no cover - exercised where numba is absent
    njit = None

__all__ = ["AVAILABLE", "SUBPIXEL_SHIFT", "fill_polygons", "line_aa", "polylines", "subpixel"]

AVAILABLE = njit is not None
SUBPIXEL_SHIFT = 9  # l5kit's CV2 shift
XY_SHIFT = 16  # OpenCV's internal fixed point
XY_ONE = 1 << XY_SHIFT
TO_FIXED = XY_SHIFT - SUBPIXEL_SHIFT

# OpenCV's anti-aliasing tables: a slope correction (by the minor/major ratio
# in 32nds) and a Gaussian sampled in 32nds of a pixel.
SLOPE_CORRECTION = np.array([
    181, 181, 181, 182, 182, 183, 184, 185, 187, 188, 190, 192, 194, 196, 198, 201,
    203, 206, 209, 211, 214, 218, 221, 224, 227, 231, 235, 238, 242, 246, 250, 254], np.int64)
GAUSSIAN = np.array([
    168, 177, 185, 194, 202, 210, 218, 224, 231, 236, 241, 246, 249, 252, 254, 254,
    254, 254, 252, 249, 246, 241, 236, 231, 224, 218, 210, 202, 194, 185, 177, 168,
    158, 149, 140, 131, 122, 114, 105, 97, 89, 82, 75, 68, 62, 56, 50, 45,
    40, 36, 32, 28, 25, 22, 19, 16, 14, 12, 11, 9, 8, 7, 5, 5], np.int64)


def compiled(fn):
    return njit(cache=True, nogil=True)(fn) if AVAILABLE else fn


def _inlined(fn):
    # Inlined by numba itself, not left to LLVM: the line's inner loop runs 1.6x as fast.
    return njit(cache=True, nogil=True, inline="always")(fn) if AVAILABLE else fn


def subpixel(points: np.ndarray) -> np.ndarray:
    """Float pixel coordinates as l5kit hands them to cv2: ``int(v * 512)``, truncated toward zero."""
    return (np.asarray(points, np.float64) * (1 << SUBPIXEL_SHIFT)).astype(np.int64)


@compiled
def _cdiv(a, b):
    """C's integer division (toward zero); Python's // floors."""
    q = abs(a) // abs(b)
    return q if (a >= 0) == (b >= 0) else -q


@compiled
def _outcode(x, y, right, bottom):
    code = 0
    if x < 0:
        code |= 1
    if x > right:
        code |= 2
    if y < 0:
        code |= 4
    if y > bottom:
        code |= 8
    return code


@compiled
def _clip_line(width, height, x1, y1, x2, y2):
    """OpenCV's clipLine on [0, width-1] x [0, height-1]: the y sides first, then x,
    each intersection computed in double and truncated."""
    if width <= 0 or height <= 0:
        return False, x1, y1, x2, y2
    right = width - 1
    bottom = height - 1
    c1 = _outcode(x1, y1, right, bottom)
    c2 = _outcode(x2, y2, right, bottom)
    if (c1 & c2) == 0 and (c1 | c2) != 0:
        if c1 & 12:
            a = 0 if c1 < 8 else bottom
            x1 += int(float(a - y1) * (x2 - x1) / (y2 - y1))
            y1 = a
            c1 = _outcode(x1, 0, right, bottom)
        if c2 & 12:
            a = 0 if c2 < 8 else bottom
            x2 += int(float(a - y2) * (x2 - x1) / (y2 - y1))
            y2 = a
            c2 = _outcode(x2, 0, right, bottom)
        if (c1 & c2) == 0 and (c1 | c2) != 0:
            if c1:
                a = 0 if c1 == 1 else right
                y1 += int(float(a - x1) * (y2 - y1) / (x2 - x1))
                x1 = a
                c1 = 0
            if c2:
                a = 0 if c2 == 1 else right
                y2 += int(float(a - x2) * (y2 - y1) / (x2 - x1))
                x2 = a
                c2 = 0
    return (c1 | c2) == 0, x1, y1, x2, y2


@_inlined
def _blend(img, row, col, colour, alpha, height, width, channels):
    """Blend one pixel toward ``colour`` twice, as OpenCV's line does."""
    if 0 <= row < height and 0 <= col < width:
        for k in range(channels):
            c = int(img[row, col, k])
            target = colour[k]
            c += ((target - c) * alpha + 127) >> 8
            c += ((target - c) * alpha + 127) >> 8
            img[row, col, k] = c


@compiled
def _end_index(count):
    # 0 at the end pixel, 1 next to it, 2 inside: which end-point weight applies.
    return 0 if count == 0 else (1 if count == 1 else 2)


@compiled
def _end_weight(index, slope, i, j):
    """OpenCV's end-point correction table, entry ``index`` (3 x start position + end
    position, each 0 at the end pixel, 1 next to it, 2 inside), without building it."""
    if index == 8:
        return slope
    if index == 0:
        return 0
    if index == 1 or index == 3:
        return ((((j - i) & 0x78) | 4) * slope >> 8) & 0x1FF
    if index == 4:
        return ((((j - i) + 0x80) | 4) * slope >> 8) & 0x1FF
    t1 = ((0x78 - i) | 4) * slope
    t2 = (j | 4) * slope
    if index == 2:
        return (t1 >> 8) & 0x1FF
    if index == 5:
        return ((t1 + (slope << 7)) >> 8) & 0x1FF
    if index == 6:
        return (t2 >> 8) & 0x1FF
    return ((t2 + (slope << 7)) >> 8) & 0x1FF


@compiled
def line_aa(img, x1, y1, x2, y2, colour):
    """An anti-aliased line between two 16.16 fixed-point points (OpenCV's LineAA)."""
    height, width, channels = img.shape[0], img.shape[1], img.shape[2]
    ok, x1, y1, x2, y2 = _clip_line(width << XY_SHIFT, height << XY_SHIFT, x1, y1, x2, y2)
    if not ok:
        return
    dx = x2 - x1
    dy = y2 - y1
    x_major = abs(dx) > abs(dy)
    if x_major:
        if dx < 0:
            x1, x2, y1, y2, dy = x2, x1, y2, y1, -dy
        step = _cdiv(dy << XY_SHIFT, abs(dx) | 1)
        major1, major2, minor1 = x1, x2 + XY_ONE, y1
    else:
        if dy < 0:
            x1, x2, y1, y2, dx = x2, x1, y2, y1, -dx
        step = _cdiv(dx << XY_SHIFT, abs(dy) | 1)
        major1, major2, minor1 = y1, y2 + XY_ONE, x1
    count = (major2 >> XY_SHIFT) - (major1 >> XY_SHIFT)
    minor = minor1 + ((step * -(major1 & (XY_ONE - 1))) >> XY_SHIFT) + (XY_ONE >> 1)
    slope = (step >> (XY_SHIFT - 5)) & 0x3F
    if step < 0:
        slope ^= 0x3F
    slope = 0x100 if slope & 0x20 else SLOPE_CORRECTION[slope]
    # End-point weights from the 4-bit fractions of both ends.
    i = (major1 >> (XY_SHIFT - 7)) & 0x78
    j = (major2 >> (XY_SHIFT - 7)) & 0x78
    along = major1 >> XY_SHIFT
    done = 0
    while count >= 0:
        weight = _end_weight(_end_index(done) * 3 + _end_index(count), slope, i, j)
        dist = (minor >> (XY_SHIFT - 5)) & 31
        first = (minor >> XY_SHIFT) - 1  # the first of the three pixels across
        a0 = (weight * GAUSSIAN[dist + 32] >> 8) & 0xFF
        a1 = (weight * GAUSSIAN[dist] >> 8) & 0xFF
        a2 = (weight * GAUSSIAN[63 - dist] >> 8) & 0xFF
        if x_major:
            _blend(img, first, along, colour, a0, height, width, channels)
            _blend(img, first + 1, along, colour, a1, height, width, channels)
            _blend(img, first + 2, along, colour, a2, height, width, channels)
        else:
            _blend(img, along, first, colour, a0, height, width, channels)
            _blend(img, along, first + 1, colour, a1, height, width, channels)
            _blend(img, along, first + 2, colour, a2, height, width, channels)
        minor += step
        along += 1
        done += 1
        count -= 1


@compiled
def polylines(img, verts, starts, closed, colour):
    """cv2.polylines(img, polygons, closed, colour, shift=9, lineType=LINE_AA), thickness 1."""
    for p in range(starts.size - 1):
        a, b = starts[p], starts[p + 1]
        if b <= a:
            continue
        prev = b - 1 if closed else a
        for v in range(a if closed else a + 1, b):
            line_aa(img, verts[prev, 0] << TO_FIXED, verts[prev, 1] << TO_FIXED,
                    verts[v, 0] << TO_FIXED, verts[v, 1] << TO_FIXED, colour)
            prev = v


@compiled
def _insertion_sort(values, n):
    for i in range(1, n):
        v = values[i]
        j = i - 1
        while j >= 0 and values[j] > v:
            values[j + 1] = values[j]
            j -= 1
        values[j + 1] = v


@compiled
def fill_polygons(img, verts, starts, colour):
    """cv2.fillPoly(img, polygons, colour, shift=9, lineType=LINE_AA): every edge
    outlined anti-aliased first, then all polygons filled together, even-odd."""
    height, width = img.shape[0], img.shape[1]
    n_edges = verts.shape[0]
    edges = np.empty((n_edges, 4), np.int64)  # top row, bottom row (exclusive), x at the top, dx per row
    n = 0
    first_row, end_row = height, 0
    half = 1 << (SUBPIXEL_SHIFT - 1)
    for p in range(starts.size - 1):
        a, b = starts[p], starts[p + 1]
        if b <= a:
            continue
        x0 = verts[b - 1, 0] << TO_FIXED
        y0 = (verts[b - 1, 1] + half) >> SUBPIXEL_SHIFT
        for v in range(a, b):
            x1 = verts[v, 0] << TO_FIXED
            y1 = (verts[v, 1] + half) >> SUBPIXEL_SHIFT
            line_aa(img, x0, y0 << XY_SHIFT, x1, y1 << XY_SHIFT, colour)
            if y0 != y1:
                top, bottom = min(y0, y1), max(y0, y1)
                edges[n, 0], edges[n, 1] = top, bottom
                edges[n, 2] = x0 if y0 < y1 else x1
                edges[n, 3] = _cdiv(x1 - x0, y1 - y0)
                first_row, end_row = min(first_row, top), max(end_row, bottom)
                n += 1
            x0, y0 = x1, y1
    first_row, end_row = max(first_row, 0), min(end_row, height)
    if n < 2 or first_row >= end_row:
        return
    # Crossings bucketed by visible row, then each row's few sorted and painted in pairs; rows
    # outside [first_row, end_row) have none.
    rows = end_row - first_row
    counts = np.zeros(2 * rows + 1, np.int64)  # prefix counts, then the fill positions
    for e in range(n):
        for y in range(max(edges[e, 0], first_row), min(edges[e, 1], end_row)):
            counts[y - first_row + 1] += 1
    for y in range(rows):
        counts[y + 1] += counts[y]
        counts[rows + 1 + y] = counts[y]
    xs = np.empty(counts[rows], np.int64)
    for e in range(n):
        for y in range(max(edges[e, 0], first_row), min(edges[e, 1], end_row)):
            k = rows + 1 + y - first_row
            xs[counts[k]] = edges[e, 2] + (y - edges[e, 0]) * edges[e, 3]
            counts[k] += 1
    for y in range(first_row, end_row):
        row = xs[counts[y - first_row]:counts[y - first_row + 1]]
        _insertion_sort(row, row.size)
        for k in range(0, row.size - 1, 2):
            left = (row[k] + XY_ONE - 1) >> XY_SHIFT
            right = row[k + 1] >> XY_SHIFT
            if left < width and right >= 0:
                for x in range(max(left, 0), min(right, width - 1) + 1):
                    for c in range(img.shape[2]):
                        img[y, x, c] = colour[c]
