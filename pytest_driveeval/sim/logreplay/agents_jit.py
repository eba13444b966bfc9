"""The other agents' policy inputs compiled with numba: ``build_batch``'s path when numba is installed.

One kernel per step does what :mod:`.agents` and the agent half of
:mod:`.inputs` do with a dozen numpy passes: choose each row's agents among
its window's candidate columns and write their histories, in the ego frame,
straight into the float32 arrays the tensors wrap.  It reads the log's own
arrays cell by cell, so it needs no :class:`~.agents.LogCells` packing.

Every value comes from the float64 expressions of the numpy path in the same
order (no fused multiply-adds: numba compiles without fastmath), rounded to
float32 once, so the tensors are the numpy path's bit for bit, the sign of
masked zeros included.
"""
from __future__ import annotations

import math

import numpy as np

try:
    from numba import njit
except ImportError:  # pragma: no cover - exercised where numba is absent
    njit = None

__all__ = ["AVAILABLE", "agent_inputs"]

AVAILABLE = njit is not None
_NO_TRACK = np.iinfo(np.int64).min  # as agents.LogCells marks cells without a relevant agent
_TWO_PI = 2.0 * np.pi


def _compiled(fn):
    return njit(cache=True, nogil=True, boundscheck=False)(fn) if AVAILABLE else fn


@_compiled
def _wrap(angle):
    """``wrap_angle(angle)`` as inputs._wrap_masked computes it, for one value."""
    angle += np.pi
    if angle < -_TWO_PI or angle >= 2.0 * _TWO_PI:
        angle = angle % _TWO_PI  # Python's float modulo, which numpy's remainder is
    elif angle < 0.0:
        angle += _TWO_PI
    elif angle >= _TWO_PI:
        angle -= _TWO_PI
    return angle - np.pi


@_compiled
def _before(a, b):
    """Ascending order with NaN last (numpy's sort order)."""
    return a < b or (b != b and a == a)


@_compiled
def _choose(agent_xy, track_id, relevant, s, t, cand, cand_ok, n_hist, cx, cy, radius, score, ref, order,
            found, best, now):
    """Score each candidate column of row (s, t) as agents._rank_agents does and
    sort them into ``order`` (stable, NaN last); fills ``score`` and ``ref``."""
    k_count = cand.shape[0]
    rel_f, tid_f = relevant[s, t], track_id[s, t]
    for k in range(k_count):
        # With no relevant frame in the window, the current cell's track (never used).
        ref[k] = tid_f[cand[k]] if rel_f[cand[k]] else _NO_TRACK
        found[k] = False
        best[k] = np.inf
        now[k] = np.inf
    # Frame by frame from the current one back: the first relevant frame of a column
    # names its track, and that track's distances in the window score it.
    for h in range(min(n_hist, t + 1)):
        f = t - h
        rel_f, tid_f, xy_f = relevant[s, f], track_id[s, f], agent_xy[s, f]
        for k in range(k_count):
            c = cand[k]
            if not cand_ok[k] or not rel_f[c]:
                continue
            tid = tid_f[c]
            if not found[k]:
                ref[k] = tid
                found[k] = True
            elif tid != ref[k]:
                continue
            dx = xy_f[c, 0] - cx
            dy = xy_f[c, 1] - cy
            d = math.sqrt(dx * dx + dy * dy)
            if d < radius:
                if h == 0:
                    now[k] = d
                if d < best[k]:
                    best[k] = d
    for k in range(k_count):
        # Agents seen now first, by distance; then history-only ones, by closest approach.
        score[k] = now[k] if now[k] != np.inf else best[k] + radius
        # Insertion into the sorted prefix: stable, as the candidates come in column order.
        j = k
        while j > 0 and _before(score[k], score[order[j - 1]]):
            order[j] = order[j - 1]
            j -= 1
        order[j] = k


@_compiled
def agent_inputs(agent_xy, agent_yaw, agent_extent, track_id, relevant, available, label, cand_all, cand_ok_all,
                 rows, frames, centre, yaw, cos, sin, max_agents, radius, pos, yaws, ext, avail, types):
    """Agents of rows ``(rows[b], frames[b])``, written into ``pos`` (B, N, H+1, 2),
    ``yaws`` (B, N, H+1), ``ext`` (B, N, H+1, 2), ``avail`` (B, N, H+1) and
    ``types`` (B, N), all float32; ``cand_all``/``cand_ok_all`` are
    ``window_columns(log, H)``, ``centre``/``yaw``/``cos``/``sin`` each row's ego."""
    n_rows = rows.shape[0]
    n_hist = pos.shape[2]
    k_count = cand_all.shape[2]
    score, best, now = np.empty(k_count), np.empty(k_count), np.empty(k_count)
    ref, order = np.empty(k_count, np.int64), np.empty(k_count, np.int64)
    found = np.empty(k_count, np.bool_)
    slot_col, slot_track = np.empty(max_agents, np.int64), np.empty(max_agents, np.int64)
    slot_used = np.empty(max_agents, np.bool_)
    kind = np.empty(max_agents, label.dtype)
    for b in range(n_rows):
        s = rows[b]
        t = frames[b]
        cx = centre[b, 0]
        cy = centre[b, 1]
        c_b = cos[b]
        s_b = sin[b]
        yaw_b = yaw[b]
        cand = cand_all[s, t]
        _choose(agent_xy, track_id, relevant, s, t, cand, cand_ok_all[s, t], n_hist, cx, cy, radius,
                score, ref, order, found, best, now)
        for j in range(max_agents):
            if j < k_count:
                k = order[j]
                slot_col[j] = cand[k]
                slot_used[j] = math.isfinite(score[k])
                slot_track[j] = ref[k]
            else:  # fewer candidates than slots: column 0, unused
                slot_col[j] = 0
                slot_used[j] = False
                slot_track[j] = -1
        for h in range(n_hist):
            f = t - h
            seen = f >= 0
            if f < 0:
                f = 0
            avail_f, tid_f, xy_f = available[s, f], track_id[s, f], agent_xy[s, f]
            yaw_f, ext_f, label_f = agent_yaw[s, f], agent_extent[s, f], label[s, f]
            for j in range(max_agents):
                c = slot_col[j]
                ok = seen and slot_used[j] and avail_f[c] and tid_f[c] == slot_track[j]
                m = 1.0 if ok else 0.0
                # The ego-frame transform of inputs._planes_to_ego, masked after rounding each step.
                dx = xy_f[c, 0] - cx
                dy = xy_f[c, 1] - cy
                u = c_b * dx + s_b * dy
                v = dy * c_b - dx * s_b
                pos[b, j, h, 0] = u * m
                pos[b, j, h, 1] = v * m
                yaws[b, j, h] = _wrap(np.float64(yaw_f[c]) - yaw_b) * m
                ext[b, j, h, 0] = np.float64(ext_f[c, 0]) * m
                ext[b, j, h, 1] = np.float64(ext_f[c, 1]) * m
                avail[b, j, h] = m
                lab = label_f[c] if ok else 0
                if h == 0 or lab > kind[j]:  # the max over the window of label * availability
                    kind[j] = lab
        for j in range(max_agents):
            types[b, j] = kind[j]
