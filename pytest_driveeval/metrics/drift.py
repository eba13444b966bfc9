"""How far the simulated ego drifts from the logged one, per frame.

Pure array functions.  ``...`` is any batch layout (e.g. scenes); T is the
frame axis, R the reference (logged) trajectory length.  Positions are world
metres, yaws radians, speeds m/s.
"""
from __future__ import annotations

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

    Exact, but avoids the full point-to-segment work on all T x (R-1) pairs:
    the nearest waypoint (one small matrix product) bounds the answer, and
    only segments whose midpoint lies within that bound plus half their
    length can beat it; those few get the exact projection.
    """
    p = np.asarray(driven, dtype=np.float64)
    ref = np.asarray(reference, dtype=np.float64)
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
