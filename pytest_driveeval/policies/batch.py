"""Policy inputs in the layout of l5kit's planning datasets, built for many rows at once.

A row is one (scene, frame) pair.  Keys, shapes and frames follow l5kit's
``generate_agent_sample`` / ``generate_agent_sample_vectorized`` (ego as the
agent of interest), all expressed in the ego frame of the current step::

    history_positions (H+1, 2)  history_yaws (H+1, 1)  history_availabilities (H+1,)
        index 0 is the current frame, index k is k frames back (l5kit order)
    target_positions (F, 2)  target_yaws (F, 1)  target_availabilities (F,)
        the LOGGED future, frames t+1 .. t+F
    centroid (2,)  yaw ()  extent (3,)  speed ()  world_from_agent (3, 3)  agent_from_world (3, 3)
    all_other_agents_history_positions (N, H+1, 2)  ..._yaws (N, H+1, 1)
    all_other_agents_history_extents (N, H+1, 2)  ..._availability (N, H+1)  all_other_agents_types (N,)

Every value is a float32 tensor with a leading batch axis B.  Unavailable
slots are zero, as l5kit leaves them.

Where we differ from l5kit, on purpose:

* ``speed`` is the backward difference ``|p_t - p_(t-1)| / dt`` of the ego
  history.  l5kit's vectorised sample uses the *next logged* position, which
  in closed loop leaks the human's future into the input.
* The other agents are chosen deterministically: agents seen at frame t within
  ``radius`` by distance, then agents seen only in the history window by their
  closest approach (l5kit takes the same two groups but orders them through a
  Python set).  The label filter keeps l5kit's agent classes, judged on each
  track's most frequent label rather than per-row probabilities.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np
import torch

from pytest_driveeval.io.l5kit_zarr import L5Scene
from pytest_driveeval.sim.logarrays import (EGO_EXTENT, STEP_TIME, LogArrays, scenes_from_arrays, stack_scenes,
                                            window_columns)

__all__ = ["EGO_EXTENT", "LogArrays", "build_batch", "collate_training_samples", "scenes_from_arrays", "select_agents",
           "stack_scenes",
           "window_columns"]


def _cells(log: LogArrays, scene: np.ndarray, frame: np.ndarray, column: np.ndarray) -> np.ndarray:
    """Flat (scene, frame, column) cell index: one take() is several times faster
    than numpy's advanced indexing with three broadcast index arrays."""
    _, n_frames, n_cols = log.available.shape
    return (scene * n_frames + frame) * n_cols + column


def _gather(array: np.ndarray, cells: np.ndarray) -> np.ndarray:
    return np.take(array.reshape((-1,) + array.shape[3:]), cells, axis=0)


# Never a real track id: marks cells whose agent is not available.
_NO_TRACK = np.iinfo(np.int64).min


class _Cells:
    """Per-cell agent fields of a log, packed per cell for the per-step gathers.

    Built once per log (see :func:`_log_cells`).  A step touches ~20k cells
    scattered over the log; gathering one packed row per cell instead of one
    value from each of several arrays is a fraction of the memory traffic.
    Rows are int64 words, floats stored as their float64 bit patterns
    (float32 fields widened, exactly):

    * ``sel`` (cells, 4), for the agent choice: track id where relevant
      (``_NO_TRACK`` elsewhere), x, y, and a spare word (numpy's take copies
      32-byte rows several times faster than 24-byte ones);
    * ``feat`` (cells, 7), for the features: track id where available
      (``_NO_TRACK`` elsewhere), x, y, yaw, length, width, label.
    """

    __slots__ = ("shape", "sel", "feat")

    def __init__(self, log: LogArrays):
        self.shape = log.available.shape
        n = log.available.size
        track = log.track_id.reshape(-1)
        self.sel = np.empty((n, 4), np.int64)
        self.feat = np.empty((n, 7), np.int64)
        self.sel[:, 3] = 0  # spare
        self.sel[:, 0] = self.feat[:, 0] = track
        np.copyto(self.sel[:, 0], _NO_TRACK, where=~log.relevant.reshape(-1))
        np.copyto(self.feat[:, 0], _NO_TRACK, where=~log.available.reshape(-1))
        sel_f, feat_f = self.sel.view(np.float64), self.feat.view(np.float64)
        sel_f[:, 1:3] = feat_f[:, 1:3] = log.agent_xy.reshape(-1, 2)
        feat_f[:, 3] = log.agent_yaw.reshape(-1)
        feat_f[:, 4:6] = log.agent_extent.reshape((n, -1))[:, :2]
        self.feat[:, 6] = log.label.reshape(-1)


def _log_cells(log: LogArrays) -> _Cells:
    """The :class:`_Cells` of ``log``; pass it to :func:`build_batch` (``cells=``)
    when calling it many times on the same, unchanged log."""
    return _Cells(log)


def _row_base(log_shape: tuple, rows: np.ndarray, frames: np.ndarray) -> np.ndarray:
    """Cell index of column 0 for each (rows, frames) pair (same formula as :func:`_cells`)."""
    _, n_frames, n_cols = log_shape
    return (rows * n_frames + frames) * n_cols


def select_agents(log: LogArrays, rows: np.ndarray, hist: np.ndarray, hist_ok: np.ndarray, centre: np.ndarray,
                  max_agents: int, radius: float, candidates: tuple[np.ndarray, np.ndarray]
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The ``max_agents`` agents nearest to ``centre``: columns, slot used, track id (each (B, N)).

    ``hist`` (B, H+1) frame indices (index 0 current), ``hist_ok`` their
    validity, ``candidates`` from :func:`window_columns`.  A column may hold
    two tracks within one window (only if ``track_gap`` < H); the most recent
    one is taken.
    """
    cand, cand_ok = candidates[0][rows, hist[:, 0]], candidates[1][rows, hist[:, 0]]  # (B, K)
    idx = _row_base(log.available.shape, rows[:, None], hist)[:, :, None] + cand[:, None, :]  # (B, H+1, K)
    rel = _gather(log.relevant, idx)
    rel &= hist_ok[..., None]
    rel &= cand_ok[:, None, :]
    tid = _gather(log.track_id, idx)
    ref = np.take_along_axis(tid, rel.argmax(axis=1)[:, None, :], 1)  # most recent relevant track
    d = _gather(log.agent_xy, idx)
    within = tid == ref
    within &= rel
    cols, used, track = _rank_agents(d[..., 0], d[..., 1], centre, within, radius, cand, ref[:, 0], max_agents)
    return cols, used, track


def _select_agents_cells(cells: _Cells, rows: np.ndarray, hist: np.ndarray, hist_ok: np.ndarray,
                         centre: np.ndarray, max_agents: int, radius: float,
                         candidates: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`select_agents` from the log's :class:`_Cells`, with fewer gathers:
    the same columns and used slots; ``track`` is the same on used slots (on
    unused ones it may differ, and nothing reads it there)."""
    t0 = hist[:, 0]
    cand, cand_ok = candidates[0][rows, t0], candidates[1][rows, t0]  # (B, K)
    idx = _row_base(cells.shape, rows[:, None], hist)[:, :, None] + cand[:, None, :]  # (B, H+1, K)
    # Track id where relevant: on relevant cells it is the track id, so the
    # most recent relevant one and the same-track test come from this one gather.
    rec = np.take(cells.sel, idx, axis=0)  # (B, H+1, K, 4)
    rt = rec[..., 0]
    rel = rt != _NO_TRACK
    rel &= hist_ok[..., None]
    rel &= cand_ok[:, None, :]
    b, h, k = rt.shape
    at = rel.argmax(axis=1)  # most recent relevant frame of each column
    at *= k
    at += np.arange(0, b * h * k, h * k)[:, None] + np.arange(k)
    ref = np.take(rt, at)  # (B, K) its track
    within = rt == ref[:, None, :]
    within &= rel
    rec = rec.view(np.float64)
    return _rank_agents(rec[..., 1], rec[..., 2], centre, within, radius, cand, ref, max_agents)


def _rank_agents(x: np.ndarray, y: np.ndarray, centre: np.ndarray, within: np.ndarray, radius: float,
                 cand: np.ndarray, ref: np.ndarray, max_agents: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Order the candidates (x, y, within: (B, H+1, K)) and keep ``max_agents`` of them."""
    dx = x - centre[:, 0, None, None]
    dy = y - centre[:, 1, None, None]
    dx *= dx
    dy *= dy
    dx += dy
    dist = np.sqrt(dx, out=dx)
    within &= dist < radius
    # Current agents first (by distance), then history-only ones by closest approach.
    np.copyto(dist, np.inf, where=~within)
    score = dist.min(axis=1)
    score += radius
    now = within[:, 0]
    score[now] = dist[:, 0][now]
    order = _first_sorted(score, max_agents)
    order += np.arange(0, score.size, score.shape[1])[:, None]  # flat (row, candidate)
    used = np.isfinite(np.take(score, order))
    cols, track = np.take(cand, order), np.take(ref, order)
    if cols.shape[1] < max_agents:  # fewer candidates than slots: pad with unused slots
        b, k = cols.shape
        pc, pu, pt = np.zeros((b, max_agents), cols.dtype), np.zeros((b, max_agents), bool), \
            np.full((b, max_agents), -1, track.dtype)
        pc[:, :k], pu[:, :k], pt[:, :k] = cols, used, track
        cols, used, track = pc, pu, pt
    return cols, used, track


def _first_sorted(score: np.ndarray, n: int) -> np.ndarray:
    """``np.argsort(score, axis=1, kind="stable")[:, :n]``, without sorting everything
    when there are many more than ``n`` columns: a partition finds the n-th
    value, every score below it is in, ties at it go to the lowest indices
    (as the stable sort has them), and only those n get sorted."""
    b, k = score.shape
    if k <= 2 * n or n <= 0 or np.isnan(score).any():
        return np.argsort(score, axis=1, kind="stable")[:, :n]
    kth = np.partition(score, n - 1, axis=1)[:, n - 1:n]
    below = score < kth
    tie = score == kth
    room = n - below.sum(axis=1, keepdims=True)
    take = below | (tie & (np.cumsum(tie, axis=1) <= room))
    sel = np.nonzero(take)[1].reshape(b, n)  # row-major: ascending column index per row
    return np.take_along_axis(sel, np.argsort(np.take_along_axis(score, sel, 1), axis=1, kind="stable"), 1)


def _to_ego_frame(xy: np.ndarray, origin: np.ndarray, cos: np.ndarray, sin: np.ndarray) -> np.ndarray:
    """World points (B, ..., 2) into each row's ego frame; origin/cos/sin are (B,)."""
    shape = (-1,) + (1,) * (xy.ndim - 2)
    dx = xy[..., 0] - origin[:, 0].reshape(shape)
    dy = xy[..., 1] - origin[:, 1].reshape(shape)
    c, s = cos.reshape(shape), sin.reshape(shape)
    return np.stack([c * dx + s * dy, c * dy - s * dx], axis=-1)


_TWO_PI = 2.0 * np.pi


def _wrap_masked(angle: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """``float32(wrap_angle(angle) * mask)`` bit for bit; ``angle`` (float64) is overwritten.

    ``wrap_angle`` is ``(a + pi) % 2pi - pi``.  With y = a + pi in [-2pi, 4pi)
    numpy's float modulo is a single exact step: fmod is exact, so it gives y
    for y in [0, 2pi), the rounded y + 2pi below (Python's sign rule), and
    y - 2pi above, which is exact there (Sterbenz).  Those two adds replace
    the slow modulo; any value farther out takes the modulo itself.
    """
    angle += np.pi
    low = angle < 0.0
    high = angle >= _TWO_PI
    if low.any() or high.any():
        far = (angle < -_TWO_PI) | (angle >= 2.0 * _TWO_PI)
        if far.any():
            low &= ~far
            high &= ~far
            angle[far] %= _TWO_PI
        np.add(angle, _TWO_PI, out=angle, where=low)
        np.subtract(angle, _TWO_PI, out=angle, where=high)
    angle -= np.pi
    return np.multiply(angle, mask, out=np.empty(angle.shape, np.float32), casting="unsafe")


def _planes_to_ego(x: np.ndarray, y: np.ndarray, origin: np.ndarray, cos: np.ndarray, sin: np.ndarray,
                   mask: np.ndarray) -> np.ndarray:
    """``(_to_ego_frame(stack([x, y], -1), ...) * mask[..., None])`` as float32, bit for bit,
    from x/y planes (B, ...)."""
    shape = (-1,) + (1,) * (x.ndim - 1)
    dx = x - origin[:, 0].reshape(shape)
    dy = y - origin[:, 1].reshape(shape)
    c, s = cos.reshape(shape), sin.reshape(shape)
    out = np.empty(x.shape + (2,), np.float32)
    u = c * dx
    u += s * dy
    u *= mask
    out[..., 0] = u
    dy *= c
    dx *= s
    dy -= dx
    dy *= mask
    out[..., 1] = dy
    return out


def build_batch(log: LogArrays, rows: np.ndarray, frames: np.ndarray, ego_xy: np.ndarray, ego_yaw: np.ndarray, *,
                history_frames: int = 10, future_frames: int = 12, max_agents: int = 30, radius: float = 35.0,
                step_time: float = STEP_TIME, ego_extent: np.ndarray = EGO_EXTENT,
                candidates: tuple[np.ndarray, np.ndarray] | None = None,
                cells: _Cells | None = None) -> dict[str, torch.Tensor]:
    """Inputs for rows ``(rows[b], frames[b])`` with the ego poses taken from ``ego_xy``/``ego_yaw``.

    ``ego_xy`` (S, T, 2) / ``ego_yaw`` (S, T) are the poses the ego actually
    had: the driven ones in closed loop, the logged ones for training.  The
    targets always come from the log.  ``candidates`` is
    ``window_columns(log, history_frames)``, computed here when not given.
    ``cells`` (``_log_cells(log)``) only saves work on repeated calls.

    Every value is computed with the same float64 operations and rounded to
    float32 once, so the tensors do not depend on the path taken.
    """
    rows, frames = np.asarray(rows, np.int64), np.asarray(frames, np.int64)
    b = rows.size
    hist = frames[:, None] - np.arange(history_frames + 1)
    hist_ok = hist >= 0
    np.maximum(hist, 0, out=hist)
    r2 = rows[:, None]
    centre, yaw = ego_xy[rows, frames], ego_yaw[rows, frames]
    cos, sin = np.cos(yaw), np.sin(yaw)
    f32 = np.float32

    # Frame 0 has no past: fall back to the logged step out of it.
    step = np.where((frames == 0)[:, None], log.ego_xy[rows, min(1, log.ego_xy.shape[1] - 1)] - log.ego_xy[rows, 0],
                    centre - ego_xy[rows, np.maximum(frames - 1, 0)])
    speed = np.sqrt((step ** 2).sum(-1)) / step_time

    fut = frames[:, None] + 1 + np.arange(future_frames)
    fut_ok = fut < log.num_frames[rows][:, None]
    np.minimum(fut, log.ego_xy.shape[1] - 1, out=fut)
    # Driven history and logged future together: (B, H+1+F) poses, one transform.
    n_hist = history_frames + 1
    e_xy = np.concatenate([ego_xy[r2, hist], log.ego_xy[r2, fut]], axis=1)
    e_yaw = np.concatenate([ego_yaw[r2, hist], log.ego_yaw[r2, fut]], axis=1)
    e_ok = np.concatenate([hist_ok, fut_ok], axis=1)
    e_pos = _planes_to_ego(e_xy[..., 0], e_xy[..., 1], centre, cos, sin, e_ok)
    e_yaw -= yaw[:, None]
    e_yaw = _wrap_masked(e_yaw, e_ok)
    h_pos, t_pos = e_pos[:, :n_hist], e_pos[:, n_hist:]
    h_yaw, t_yaw = e_yaw[:, :n_hist], e_yaw[:, n_hist:]

    if candidates is None:
        candidates = window_columns(log, history_frames)
    if cells is not None:
        cols, used, track = _select_agents_cells(cells, rows, hist, hist_ok, centre, max_agents, radius, candidates)
    else:
        cols, used, track = select_agents(log, rows, hist, hist_ok, centre, max_agents, radius, candidates)
    idx = _row_base(log.available.shape, r2, hist)[:, None, :] + cols[:, :, None]  # (B, N, H+1)
    if cells is not None:
        rec = np.take(cells.feat, idx, axis=0)  # (B, N, H+1, 7)
        a_ok = rec[..., 0] == track[..., None]
        a_label = rec[..., 6]
        rec = rec.view(np.float64)
        ax, ay, a_yaw, a_len, a_wid = rec[..., 1], rec[..., 2], rec[..., 3], rec[..., 4], rec[..., 5]
    else:
        a_ok = _gather(log.available, idx) & (_gather(log.track_id, idx) == track[..., None])
        a_xy = _gather(log.agent_xy, idx)
        ax, ay = a_xy[..., 0], a_xy[..., 1]
        a_yaw = _gather(log.agent_yaw, idx).astype(np.float64)  # exact; the difference below is float64 anyway
        a_ext = _gather(log.agent_extent, idx)
        a_len, a_wid = a_ext[..., 0], a_ext[..., 1]
        a_label = _gather(log.label, idx)
    a_ok &= hist_ok[:, None, :]
    a_ok &= used[..., None]
    a_pos = _planes_to_ego(ax, ay, centre, cos, sin, a_ok)
    a_yaw = _wrap_masked(a_yaw - yaw[:, None, None], a_ok)
    a_ext = np.empty(a_ok.shape + (2,), f32)  # extent * availability, in the log's precision (float32)
    np.multiply(a_len, a_ok, out=a_ext[..., 0], dtype=a_len.dtype, casting="unsafe")
    np.multiply(a_wid, a_ok, out=a_ext[..., 1], dtype=a_wid.dtype, casting="unsafe")
    a_type = (a_label * a_ok).max(axis=-1)  # constant per track; zero for unused slots

    out = {
        "history_positions": h_pos, "history_yaws": h_yaw[..., None], "history_availabilities": hist_ok,
        "target_positions": t_pos, "target_yaws": t_yaw[..., None], "target_availabilities": fut_ok,
        "centroid": centre, "yaw": yaw, "extent": np.broadcast_to(ego_extent, (b, 3)), "speed": speed,
        "world_from_agent": _world_from_agent32(centre, cos, sin),
        "agent_from_world": _agent_from_world32(centre, cos, sin),
        "all_other_agents_history_positions": a_pos, "all_other_agents_history_yaws": a_yaw[..., None],
        "all_other_agents_history_extents": a_ext, "all_other_agents_history_availability": a_ok,
        "all_other_agents_types": a_type,
    }
    return {k: torch.from_numpy(np.ascontiguousarray(v, dtype=f32)) for k, v in out.items()}


def _world_from_agent32(centre: np.ndarray, cos: np.ndarray, sin: np.ndarray) -> np.ndarray:
    """``world_from_agent(centre, yaw)`` as float32, from the yaw's cos/sin."""
    out = np.zeros((centre.shape[0], 3, 3), np.float32)
    out[:, 0, 0] = cos
    out[:, 0, 1] = -sin
    out[:, 1, 0] = sin
    out[:, 1, 1] = cos
    out[:, :2, 2] = centre
    out[:, 2, 2] = 1.0
    return out


def _agent_from_world32(centre: np.ndarray, cos: np.ndarray, sin: np.ndarray) -> np.ndarray:
    """``agent_from_world(centre, yaw)`` as float32: R^T and -R^T t, with the
    same einsum as the geometry function on the same float64 R^T."""
    rt = np.empty((centre.shape[0], 2, 2))
    rt[:, 0, 0] = cos
    rt[:, 0, 1] = sin
    rt[:, 1, 0] = -sin
    rt[:, 1, 1] = cos
    out = np.zeros((centre.shape[0], 3, 3), np.float32)
    out[:, :2, :2] = rt
    out[:, :2, 2] = -np.einsum("...ij,...j->...i", rt, centre)
    out[:, 2, 2] = 1.0
    return out


def collate_training_samples(scene: L5Scene | LogArrays, frames: Sequence[int] | np.ndarray, *, row: int = 0,
                             **options) -> dict[str, torch.Tensor]:
    """Open-loop samples of one scene at ``frames``: history and future both from the log.

    Same keys and conventions as the closed-loop input (``options`` as in
    :func:`build_batch`), so a model trained on these sees identical features
    at evaluation time.
    """
    log = scene if isinstance(scene, LogArrays) else stack_scenes([scene])
    frames = np.asarray(frames, dtype=np.int64).reshape(-1)
    n = int(log.num_frames[row])
    bad = frames[(frames < 0) | (frames >= n)]
    if bad.size:
        raise IndexError(f"scene {int(log.scene_ids[row])}: frame {int(bad[0])} outside [0, {n})")
    return build_batch(log, np.full(frames.size, row), frames, log.ego_xy, log.ego_yaw, **options)
