"""Which logged agents a policy input shows, and their histories.

A row's input holds the ``max_agents`` agents nearest to the ego: those seen
at the current frame within ``radius`` by distance, then those seen only in
the history window by their closest approach.  The work is gathers over the
log's flat (scene, frame, column) cells, restricted to the columns
:func:`~.logarrays.window_columns` found worth looking at.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from pytest_driveeval.sim.logreplay.logarrays import LogArrays

__all__ = ["AgentHistories", "LogCells", "agent_histories", "select_agents"]


def _gather(array: np.ndarray, cells: np.ndarray) -> np.ndarray:
    return np.take(array.reshape((-1,) + array.shape[3:]), cells, axis=0)


# Never a real track id: marks cells whose agent is not available.
_NO_TRACK = np.iinfo(np.int64).min


class LogCells:
    """Per-cell agent fields of a log, packed per cell for the per-step gathers.

    Built once per log; pass it to :func:`~.inputs.build_batch` (``cells=``)
    when calling that many times on the same, unchanged log.  A step touches
    ~20k cells scattered over the log; gathering one packed row per cell
    instead of one value from each of several arrays is a fraction of the
    memory traffic.
    Rows are int64 words, floats stored as their float64 bit patterns
    (float32 fields widened, exactly):

    * ``sel`` (cells, 4), for the agent choice: track id where relevant
      (``_NO_TRACK`` elsewhere), x, y, and a spare word (numpy's take copies
      32-byte rows several times faster than 24-byte ones);
    * ``feat`` (cells, 7), for the features: track id where available
      (``_NO_TRACK`` elsewhere), x, y, yaw, length, width, label.

    A robustness search unrolls many copies of the same scenes: :meth:`rows_of`
    shares one packing among them (``row_of`` maps an unroll's rows to the
    packed ones) instead of packing every copy again.
    """

    __slots__ = ("shape", "sel", "feat", "row_of")

    def __init__(self, log: LogArrays):
        self.row_of = None
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
        feat_f[:, 4:6] = log.agent_extent.reshape((n, 3))[:, :2]  # (n, 3): a log without agents has n = 0
        self.feat[:, 6] = log.label.reshape(-1)

    def rows_of(self, rows: np.ndarray) -> "LogCells":
        """These cells for ``log.take(rows)`` of the log they were packed from, without packing again."""
        out = LogCells.__new__(LogCells)
        out.shape, out.sel, out.feat = self.shape, self.sel, self.feat
        rows = np.asarray(rows, dtype=np.int64)
        out.row_of = rows if self.row_of is None else self.row_of[rows]
        return out

    def base(self, rows: np.ndarray, frames: np.ndarray) -> np.ndarray:
        """Flat index of the (rows, frames, column 0) cells (rows of the log being unrolled)."""
        return _row_base(self.shape, rows if self.row_of is None else self.row_of[rows], frames)


def _row_base(log_shape: tuple, rows: np.ndarray, frames: np.ndarray) -> np.ndarray:
    """Flat index of the (rows, frames, column 0) cell: one take() at that index plus
    the column is several times faster than numpy's advanced indexing with
    three broadcast index arrays."""
    _, n_frames, n_cols = log_shape
    return (rows * n_frames + frames) * n_cols


def select_agents(log: LogArrays, rows: np.ndarray, hist: np.ndarray, hist_ok: np.ndarray, centre: np.ndarray,
                  max_agents: int, radius: float, candidates: tuple[np.ndarray, np.ndarray]
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The ``max_agents`` agents nearest to ``centre``: columns, slot used, track id (each (B, N)).

    ``hist`` (B, H+1) frame indices (index 0 current), ``hist_ok`` their
    validity, ``candidates`` from :func:`~.logarrays.window_columns`.  A column may hold
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


def _select_agents_cells(cells: LogCells, rows: np.ndarray, hist: np.ndarray, hist_ok: np.ndarray,
                         centre: np.ndarray, max_agents: int, radius: float,
                         candidates: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`select_agents` from the log's :class:`LogCells`, with fewer gathers:
    the same columns and used slots; ``track`` is the same on used slots (on
    unused ones it may differ, and nothing reads it there)."""
    t0 = hist[:, 0]
    cand, cand_ok = candidates[0][rows, t0], candidates[1][rows, t0]  # (B, K)
    idx = cells.base(rows[:, None], hist)[:, :, None] + cand[:, None, :]  # (B, H+1, K)
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


class AgentHistories(NamedTuple):
    """The chosen agents' logged histories, each (B, N, H+1), index 0 the current frame.

    World coordinates and the log's precision; ``ok`` is False on frames
    where the slot's track is not seen, before the log starts, and on unused
    slots.
    """

    ok: np.ndarray
    x: np.ndarray
    y: np.ndarray
    yaw: np.ndarray  # float64
    length: np.ndarray
    width: np.ndarray
    label: np.ndarray


def agent_histories(log: LogArrays, rows: np.ndarray, hist: np.ndarray, hist_ok: np.ndarray, centre: np.ndarray,
                    max_agents: int, radius: float, candidates: tuple[np.ndarray, np.ndarray],
                    cells: LogCells | None = None) -> AgentHistories:
    """The histories of the :func:`select_agents` choice for each row (arguments as there).

    ``cells`` only saves work; the result is the same with or without it.
    """
    if cells is not None:
        cols, used, track = _select_agents_cells(cells, rows, hist, hist_ok, centre, max_agents, radius, candidates)
    else:
        cols, used, track = select_agents(log, rows, hist, hist_ok, centre, max_agents, radius, candidates)
    base = cells.base(rows[:, None], hist) if cells is not None else _row_base(log.available.shape, rows[:, None],
                                                                                 hist)
    idx = base[:, None, :] + cols[:, :, None]  # (B, N, H+1)
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
        a_yaw = _gather(log.agent_yaw, idx).astype(np.float64)  # exact; the ego-frame yaw is float64 anyway
        a_ext = _gather(log.agent_extent, idx)
        a_len, a_wid = a_ext[..., 0], a_ext[..., 1]
        a_label = _gather(log.label, idx)
    a_ok &= hist_ok[:, None, :]
    a_ok &= used[..., None]
    return AgentHistories(a_ok, ax, ay, a_yaw, a_len, a_wid, a_label)
