"""How far the simulated ego drifts from the logged one, per frame.

Pure array functions.  ``...`` is any batch layout (e.g. scenes); T is the
frame axis, R the reference (logged) trajectory length.  Positions are world
metres, yaws radians, speeds m/s.
"""
from __future__ import annotations

import functools
import math

import numpy as np

from pytest_driveeval.geometry import norm2d, wrap_angle


def displacement_error(driven: np.ndarray, logged: np.ndarray) -> np.ndarray:
    """(..., T, 2), (..., T, 2) -> (..., T) Euclidean distance per frame.

    l5kit's ``displacement_error_l2`` closed-loop metric.
    """
    diff = np.asarray(driven, dtype=np.float64) - np.asarray(logged, dtype=np.float64)
    return norm2d(diff)


def yaw_error(driven_yaw: np.ndarray, logged_yaw: np.ndarray) -> np.ndarray:
    """(..., T), (..., T) -> (..., T) absolute heading difference in [0, pi]."""
    return np.abs(wrap_angle(np.asarray(driven_yaw, dtype=np.float64) - logged_yaw))


def distance_to_reference(
    driven: np.ndarray,
    reference: np.ndarray,
    reference_available: np.ndarray | None = None,
    *,
    waypoints_only: bool = False,
) -> np.ndarray:
    """Distance from each driven position to the reference polyline.

    driven (..., T, 2); reference (..., R, 2); reference_available (..., R)
    bool -> (..., T).  The polyline is the logged ego path; the distance is to
    its nearest *segment*, so a sparse log does not inflate the error between
    waypoints.  ``waypoints_only=True`` gives l5kit's
    ``distance_to_reference_trajectory`` (nearest logged centroid) instead.
    Unavailable waypoints drop out together with their segments; with no
    usable waypoint the result is inf.

    Exact, but avoids the point-to-segment work on all T x (R-1) pairs: the
    waypoints around the same index (the driven ego follows its log) bound
    the answer, the polyline is cut into chunks of :data:`_CHUNK` segments
    with a bounding box each, and only the chunks whose box is within that
    bound (typically the one or two around the frame index) get the exact
    projection.  A far-off driven position simply qualifies more chunks, so
    the search stays exact whatever the drift.
    """
    p = np.asarray(driven, dtype=np.float64)
    ref = np.asarray(reference, dtype=np.float64)
    if not waypoints_only and ref.shape[-2] >= 2 * _CHUNK and p.shape[-2] >= 1:
        out = _distance_to_polyline_chunked(p, ref, reference_available)
        if out is not None:
            return out
    return _distance_to_reference_full(p, ref, reference_available, waypoints_only)


def distance_to_reference_l5kit(driven: np.ndarray, logged: np.ndarray, unrolled: np.ndarray,
                                scene_fraction: float = 0.8) -> np.ndarray:
    """l5kit's ``DistanceToRefTrajectoryMetric`` per frame: (..., T, 2), (..., T, 2),
    (..., T) bool -> (..., T).

    ``unrolled`` marks the simulated frames (one run per row, as l5kit
    simulates them).  Of those n frames, the first ``int(n * scene_fraction)``
    get the distance from the driven centroid to the nearest logged centroid
    of the unrolled frames (waypoints, not the path between them); the rest,
    which l5kit does not measure, and the frames outside are NaN.  The
    fraction cuts the *driven* frames, not the reference.
    """
    measured = np.asarray(unrolled, dtype=bool)
    n = measured.sum(axis=-1, keepdims=True)
    measured = measured & (np.cumsum(measured, axis=-1) <= np.floor(n * scene_fraction))
    dist = distance_to_reference(driven, logged, unrolled, waypoints_only=True)
    return np.where(measured, dist, np.nan)


# Segments per chunk of the reference polyline, and waypoints each side of the
# frame index for the first bound (see distance_to_reference).
_CHUNK = 16
_WINDOW = 4


@functools.lru_cache(maxsize=32)
def _chunk_layout(t_len: int, r_len: int) -> tuple[np.ndarray, np.ndarray]:
    """Waypoint indices of each frame's window (2W+1, T) and of each chunk
    (CHUNK+1, C: its segments' ends), clipped to the polyline (a clipped index
    repeats the last waypoint, which is harmless: it is a waypoint).  Long
    axis last: numpy reduces much faster across rows than along short ones."""
    window = np.arange(-_WINDOW, _WINDOW + 1)[:, None] + np.minimum(np.arange(t_len), r_len - 1)
    np.clip(window, 0, r_len - 1, out=window)
    n_chunk = max(1, -(-(r_len - 1) // _CHUNK))
    chunk = np.minimum(np.arange(_CHUNK + 1)[:, None] + np.arange(n_chunk) * _CHUNK, r_len - 1)
    window.setflags(write=False)
    chunk.setflags(write=False)
    return window, chunk


def _distance_to_polyline_chunked(p: np.ndarray, ref: np.ndarray, reference_available) -> np.ndarray | None:
    """distance_to_reference (segments) by chunks; None when a position or an
    available waypoint is not finite (the full search has its own way with those).

    Coordinates are held as (2, ...) planes so that every step is one call
    for x and y together; ``sum(0)`` over such a plane pair is exactly x + y.
    """
    t_len, r_len = p.shape[-2], ref.shape[-2]
    same = p.shape[:-2] == ref.shape[:-2]
    lead = p.shape[:-2] if same else np.broadcast_shapes(p.shape[:-2], ref.shape[:-2])
    origin = ref[..., :1, :]
    p = p - origin
    ref = ref - origin
    if not same:
        p = np.broadcast_to(p, lead + (t_len, 2))
        ref = np.broadcast_to(ref, lead + (r_len, 2))
    n_b = math.prod(lead)
    pts = np.ascontiguousarray(np.moveaxis(p.reshape(n_b, t_len, 2), -1, 0))  # (2, B, T)
    way = np.ascontiguousarray(np.moveaxis(ref.reshape(n_b, r_len, 2), -1, 0))  # (2, B, R)
    avail = None
    if reference_available is not None:
        avail = np.broadcast_to(np.asarray(reference_available, dtype=bool), lead + (r_len,)).reshape(n_b, r_len)
        if not np.isfinite(way[:, avail]).all():
            return None
    elif not np.isfinite(way).all():
        return None
    if not np.isfinite(pts).all():
        return None
    window, chunk = _chunk_layout(t_len, r_len)
    # A few scenes at a time: the (scenes, chunks, frames) temporaries then
    # stay in cache instead of costing page faults.
    step = max(1, _BLOCK // (t_len * chunk.shape[1]))
    if step >= n_b:
        best = _chunked_block(pts, way, avail, window)
    else:
        best = np.empty((n_b, t_len))
        for b0 in range(0, n_b, step):
            blk = slice(b0, b0 + step)
            best[blk] = _chunked_block(pts[:, blk], way[:, blk], None if avail is None else avail[blk], window)
    return np.sqrt(best).reshape(lead + (t_len,))


# Elements of the (scenes, chunks, frames) table handled per block.
_BLOCK = 4096


def _chunked_block(pts: np.ndarray, way: np.ndarray, avail: np.ndarray | None, window: np.ndarray) -> np.ndarray:
    """Squared distances (B, T) for pts (2, B, T), way (2, B, R), avail (B, R) or None."""
    t_len = pts.shape[-1]

    # 1. Upper bound: exact distance to the available waypoints around the frame index.
    d = np.take(way, window, axis=2)  # (2, B, W, T)
    d -= pts[:, :, None, :]  # (way - p)^2 == (p - way)^2: rounding is symmetric
    d *= d
    d2 = d.sum(0)
    if avail is not None:
        d2[~np.take(avail, window, axis=1)] = np.inf
    bound = d2.min(axis=1)  # (B, T); inf when no waypoint of the window is available

    # A stop repeats the same waypoint for many frames: drop the repeats (an
    # available waypoint equal to the available one before it).  Nothing is
    # lost: a repeat's segments are a point (its waypoint's distance) and the
    # segment out of the run, which now starts at the identical first waypoint.
    # Without this, every chunk of a long stop would be a candidate.
    same = way[:, :, 1:] == way[:, :, :-1]
    dup = same[0] & same[1]
    if avail is not None:
        dup &= avail[:, 1:]
        dup &= avail[:, :-1]
    if dup.any():
        keep = np.ones(dup.shape[:1] + (dup.shape[1] + 1,), dtype=bool)
        np.logical_not(dup, out=keep[:, 1:])
        count = keep.sum(axis=1)
        b_idx, j_idx = np.nonzero(keep)
        pos = np.arange(b_idx.size) - np.repeat(np.cumsum(count) - count, count)
        kept = np.repeat(j_idx[np.cumsum(count) - 1][:, None], int(count.max()), axis=1)  # pad: last kept
        kept[b_idx, pos] = j_idx
        way = np.take_along_axis(way, kept[None], axis=2)
        if avail is not None:
            avail = np.take_along_axis(avail, kept, axis=1)
    r_len = way.shape[-1]
    chunk = _chunk_layout(t_len, r_len)[1]
    n_chunk = chunk.shape[1]

    # 2. Bounding box of each chunk's (available) waypoints.
    box = np.take(way, chunk, axis=2)  # (2, B, CHUNK+1, C)
    if avail is not None:
        c_ok = np.take(avail, chunk, axis=1)[None]
        lo, hi = np.where(c_ok, box, np.inf).min(axis=2), np.where(c_ok, box, -np.inf).max(axis=2)
    else:
        lo, hi = box.min(axis=2), box.max(axis=2)  # (2, B, C)

    # 3. Chunks whose box may hold something within the bound (slack for rounding).
    q = pts[:, :, None, :]  # (2, B, 1, T)
    gap = np.maximum(lo[..., None] - q, q - hi[..., None])  # (2, B, C, T)
    np.maximum(gap, 0.0, out=gap)
    gap *= gap
    bound_ = bound * (1.0 + 1e-8)
    bound_ += 1e-6
    flat = np.flatnonzero(gap.sum(0) <= bound_[:, None, :])
    b_c, ti = np.divmod(flat, t_len)
    bi, ci = np.divmod(b_c, n_chunk)
    bt = bi * t_len
    bt += ti

    # 4. Exact distances to every waypoint and segment of those chunks, with
    # the arithmetic of the full search.
    best = bound.reshape(-1)  # a view: updated in place
    if flat.size:
        bi *= r_len
        cell = chunk[:, ci]
        cell += bi  # (CHUNK+1, P)
        w = np.take(way.reshape(2, -1), cell, axis=1)  # (2, CHUNK+1, P)
        d = np.take(pts.reshape(2, -1), bt, axis=1)[:, None, :] - w  # point minus waypoint
        e = w[:, 1:] - w[:, :-1]  # segment vectors
        wd2 = np.multiply(d, d, out=w).sum(0)  # (CHUNK+1, P)
        ds = d[:, :-1]  # point minus segment start
        len2 = (e * e).sum(0)
        proj = (ds * e).sum(0)
        # Zero-length segment: proj is 0 too, so any divisor gives u = 0.
        u = proj / np.where(len2 > 0, len2, 1.0)
        np.maximum(u, 0.0, out=u)
        np.minimum(u, 1.0, out=u)
        e *= u
        np.subtract(ds, e, out=e)
        e *= e
        sd2 = e.sum(0)  # (CHUNK, P)
        if avail is not None:
            w_ok = np.take(avail, cell)
            sd2[~(w_ok[1:] & w_ok[:-1])] = np.inf
            wd2[~w_ok] = np.inf
        vals = sd2.min(axis=0)
        np.minimum(vals, wd2.min(axis=0), out=vals)
        np.minimum.at(best, bt, vals)
    return bound


def _distance_to_reference_full(p: np.ndarray, ref: np.ndarray, reference_available,
                                waypoints_only: bool) -> np.ndarray:
    """distance_to_reference over all T x R pairs: the nearest waypoint (one
    small matrix product) bounds the answer, and only segments whose midpoint
    lies within that bound plus half their length can beat it; those few get
    the exact projection."""
    lead = np.broadcast_shapes(p.shape[:-2], ref.shape[:-2])
    t_len, r_len = p.shape[-2], ref.shape[-2]
    # Relative to the first waypoint: world coordinates are km-sized and the
    # expanded squares below would otherwise lose precision.
    origin = ref[..., :1, :]
    p = np.broadcast_to(p - origin, lead + (t_len, 2)).reshape(-1, t_len, 2)
    ref = np.broadcast_to(ref - origin, lead + (r_len, 2)).reshape(-1, r_len, 2)
    avail = None
    if reference_available is not None:
        avail = np.broadcast_to(np.asarray(reference_available, dtype=bool), lead + (r_len,)).reshape(-1, r_len)

    # Nearest available waypoint, then its exact distance (the expanded form
    # is only trusted for the argmin).
    d2 = _pairwise_sq_dist(p, ref)
    if avail is not None:
        d2 = np.where(avail[:, None, :], d2, np.inf)
    k = d2.argmin(axis=-1)
    diff = p - np.take_along_axis(ref, k[..., None], axis=1)
    best = np.einsum("btd,btd->bt", diff, diff)
    if avail is not None:
        best[~avail.any(axis=-1)] = np.inf
    if waypoints_only or r_len < 2:
        return np.sqrt(best).reshape(lead + (t_len,))

    a = ref[:, :-1]
    e = ref[:, 1:] - a
    half = 0.5 * norm2d(e)  # (B, R-1)
    mid = a + 0.5 * e
    # |p - mid|^2 - (sqrt(best) + half)^2 <= 0 marks the candidates; expanded,
    # every term is a row term, a column term or a rank-1 product, so the
    # whole (B, T, R-1) table is a single matrix product.
    s = np.sqrt(best)
    lhs = np.stack([p[..., 0], p[..., 1], np.einsum("btd,btd->bt", p, p) - s * s, np.ones_like(s), s], axis=-1)
    rhs = np.stack(
        [-2.0 * mid[..., 0], -2.0 * mid[..., 1], np.ones_like(half), np.einsum("brd,brd->br", mid, mid) - half * half,
         -2.0 * half], axis=-1)
    excess = lhs @ np.swapaxes(rhs, -1, -2)
    # Slack covers the rounding of the expanded squares; extra candidates only cost time.
    cand = excess <= 1e-6
    if avail is not None:
        cand &= (avail[:, :-1] & avail[:, 1:])[:, None, :]
    flat = np.flatnonzero(cand)  # much faster than a 3-D nonzero when sparse
    bt, si = np.divmod(flat, r_len - 1)
    bi, ti = np.divmod(bt, t_len)

    d = p[bi, ti] - a[bi, si]
    es = e[bi, si]
    len2 = np.einsum("kd,kd->k", es, es)
    proj = np.einsum("kd,kd->k", d, es)
    # Repeated waypoints give zero-length segments: distance to the point.
    u = np.clip(np.divide(proj, len2, out=np.zeros_like(proj), where=len2 > 0), 0.0, 1.0)
    r = d - u[:, None] * es
    np.minimum.at(best.reshape(-1), bi * t_len + ti, np.einsum("kd,kd->k", r, r))
    return np.sqrt(best).reshape(lead + (t_len,))


def _pairwise_sq_dist(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """(B, N, 2), (B, M, 2) -> (B, N, M) squared distances in one BLAS call.

    |x - y|^2 = [x, |x|^2, 1] . [-2y, 1, |y|^2]; cancellation errors are
    ~1e-16 of |x|^2, hence the callers' origin shift.
    """
    xa = np.empty(x.shape[:-1] + (4,))
    xa[..., :2] = x
    xa[..., 2] = np.einsum("bnd,bnd->bn", x, x)
    xa[..., 3] = 1.0
    ya = np.empty(y.shape[:-1] + (4,))
    ya[..., :2] = -2.0 * y
    ya[..., 2] = 1.0
    ya[..., 3] = np.einsum("bnd,bnd->bn", y, y)
    return xa @ np.swapaxes(ya, -1, -2)


def driven_distance(positions: np.ndarray, available: np.ndarray | None = None) -> np.ndarray:
    """(..., T, 2) -> (..., T) cumulative path length, 0 at the first frame.

    A step counts only when both of its frames are available (``available``
    (..., T) bool), so gaps add nothing rather than a jump.
    """
    pos = np.asarray(positions, dtype=np.float64)
    step = np.diff(pos, axis=-2)
    step_len = norm2d(step)
    if available is not None:
        ok = np.asarray(available, dtype=bool)
        step_len = np.where(ok[..., 1:] & ok[..., :-1], step_len, 0.0)
    out = np.zeros(pos.shape[:-1])
    np.cumsum(step_len, axis=-1, out=out[..., 1:])
    return out


def speed_from_positions(positions: np.ndarray, dt: float) -> np.ndarray:
    """(..., T, 2) positions sampled every ``dt`` s -> (..., T) speed.

    Central differences inside, one-sided at the ends (``np.gradient``), for
    logs that carry no speed field.
    """
    pos = np.asarray(positions, dtype=np.float64)
    if pos.shape[-2] < 2:
        return np.zeros(pos.shape[:-1])
    vel = np.gradient(pos, dt, axis=-2)
    return norm2d(vel)


def speed_difference(driven_speed: np.ndarray, logged_speed: np.ndarray) -> np.ndarray:
    """(..., T), (..., T) -> (..., T) driven minus logged speed (signed).

    Positive: the policy drives faster than the human did.
    """
    return np.asarray(driven_speed, dtype=np.float64) - np.asarray(logged_speed, dtype=np.float64)
