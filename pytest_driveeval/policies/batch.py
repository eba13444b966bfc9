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

import heapq
from dataclasses import dataclass
from typing import Sequence

import numpy as np
import torch

from pytest_driveeval.geometry import agent_from_world, wrap_angle, world_from_agent
from pytest_driveeval.io.l5kit_zarr import PERCEPTION_LABELS, L5Arrays, L5Scene

__all__ = ["EGO_EXTENT", "LogArrays", "build_batch", "collate_training_samples", "scenes_from_arrays", "select_agents",
           "stack_scenes",
           "window_columns"]

# l5kit's default ego box (length, width, height); the zarr does not store it.
EGO_EXTENT = np.array([4.869, 1.852, 1.476])
STEP_TIME = 0.1

# l5kit's PERCEPTION_LABELS_TO_KEEP: CAR (3) .. ANIMAL (15).
_KEEP_LABEL = np.zeros(len(PERCEPTION_LABELS), dtype=bool)
_KEEP_LABEL[3:16] = True


@dataclass
class LogArrays:
    """Logged scenes stacked and padded: S scenes, T frames, C agent columns.

    A logged scene has thousands of short tracks but only ~100 at a time, so
    tracks share columns: one column holds tracks whose lifetimes do not
    overlap (and are ``track_gap`` frames apart), and ``track_id`` says whose
    state a (scene, frame, column) cell holds.  That keeps the dense arrays
    ~10x smaller than one column per track.  Frames past ``num_frames[s]``
    and empty cells have ``available`` False (and zeros); padded ego frames
    repeat the last logged pose so differences across the padding stay finite.
    """

    scene_ids: np.ndarray  # (S,) int64, how the caller names each scene in messages
    num_frames: np.ndarray  # (S,) int64
    ego_xy: np.ndarray  # (S, T, 2) float64
    ego_yaw: np.ndarray  # (S, T) float64
    agent_xy: np.ndarray  # (S, T, C, 2) float64
    agent_yaw: np.ndarray  # (S, T, C) float32
    agent_extent: np.ndarray  # (S, T, C, 3) float32
    agent_velocity: np.ndarray  # (S, T, C, 2) float32
    available: np.ndarray  # (S, T, C) bool
    track_id: np.ndarray  # (S, T, C) int64, -1 in empty cells
    label: np.ndarray  # (S, T, C) int16 index into PERCEPTION_LABELS (the track's most frequent)
    relevant: np.ndarray  # (S, T, C) bool: available and of a class l5kit feeds to models

    @property
    def shape(self) -> tuple[int, int, int]:
        return self.available.shape

    def take(self, rows: np.ndarray) -> "LogArrays":
        return LogArrays(*(getattr(self, f)[rows] for f in self.__dataclass_fields__))


def scenes_from_arrays(arrays: L5Arrays) -> list[L5Scene]:
    """In-memory l5kit arrays (e.g. from ``generate_scenes``) as scenes, without a zarr round trip."""
    scenes = []
    for i, row in enumerate(arrays.scenes):
        f0, f1 = (int(v) for v in row["frame_index_interval"])
        frames = arrays.frames[f0:f1].copy()
        a0 = int(frames["agent_index_interval"][0, 0]) if f1 > f0 else 0
        a1 = int(frames["agent_index_interval"][-1, 1]) if f1 > f0 else 0
        frames["agent_index_interval"] -= a0
        frames["traffic_light_faces_index_interval"] = 0  # faces are not needed here
        scenes.append(L5Scene(index=i, host=str(row["host"]), start_time=int(row["start_time"]),
                              end_time=int(row["end_time"]), frames=frames, agents=arrays.agents[a0:a1],
                              traffic_light_faces=arrays.traffic_light_faces[:0], frame_offset=f0, agent_offset=a0))
    return scenes


def _assign_columns(available: np.ndarray, gap: int) -> tuple[np.ndarray, int]:
    """Column of each track (greedy interval partitioning, optimal for intervals) and the column count."""
    if available.shape[1] == 0:
        return np.zeros(0, np.int64), 0
    first = available.argmax(axis=0)
    last = available.shape[0] - 1 - available[::-1].argmax(axis=0)
    column = np.empty(first.size, np.int64)
    free: list[tuple[int, int]] = []  # (last busy frame, column), earliest first
    count = 0
    for a in np.argsort(first, kind="stable"):
        if free and free[0][0] < first[a]:
            _, col = heapq.heappop(free)
        else:
            col, count = count, count + 1
        column[a] = col
        heapq.heappush(free, (int(last[a]) + gap, col))
    return column, count


def stack_scenes(scenes: Sequence[L5Scene], scene_ids: Sequence[int] | None = None, *,
                 track_gap: int = 10) -> LogArrays:
    """Dense padded arrays of several scenes (one ``agent_tensor()`` each).

    ``track_gap`` (frames) keeps a column's consecutive tracks apart so an
    agent history window never has to choose between two tracks of a column;
    the default matches the default history length.
    """
    tensors = [s.agent_tensor() for s in scenes]
    columns = [_assign_columns(at.available, track_gap) for at in tensors]
    n_frames = np.array([s.num_frames for s in scenes], dtype=np.int64)
    t_max = int(n_frames.max(initial=1))
    c_max = max((n for _, n in columns), default=0)
    shape = (len(scenes), t_max, c_max)
    log = LogArrays(
        scene_ids=np.asarray([s.index for s in scenes] if scene_ids is None else scene_ids, dtype=np.int64),
        num_frames=n_frames, ego_xy=np.zeros(shape[:2] + (2,)), ego_yaw=np.zeros(shape[:2]),
        agent_xy=np.zeros(shape + (2,)), agent_yaw=np.zeros(shape, np.float32),
        agent_extent=np.zeros(shape + (3,), np.float32), agent_velocity=np.zeros(shape + (2,), np.float32),
        available=np.zeros(shape, bool), track_id=np.full(shape, -1, np.int64), label=np.zeros(shape, np.int16),
        relevant=np.zeros(shape, bool),
    )
    for i, (scene, at, (column, _)) in enumerate(zip(scenes, tensors, columns)):
        t = scene.num_frames
        log.ego_xy[i, :t], log.ego_yaw[i, :t] = scene.ego_positions(), scene.ego_yaws()
        log.ego_xy[i, t:], log.ego_yaw[i, t:] = log.ego_xy[i, t - 1], log.ego_yaw[i, t - 1]
        f, a = np.nonzero(at.available)
        c = column[a]
        log.agent_xy[i, f, c], log.agent_yaw[i, f, c] = at.centroid[f, a], at.yaw[f, a]
        log.agent_extent[i, f, c], log.agent_velocity[i, f, c] = at.extent[f, a], at.velocity[f, a]
        log.available[i, f, c] = True
        log.track_id[i, f, c], log.label[i, f, c] = at.track_id[a].astype(np.int64), at.label[a]
        log.relevant[i, f, c] = _KEEP_LABEL[at.label[a]]
    return log


def window_columns(log: LogArrays, history_frames: int) -> tuple[np.ndarray, np.ndarray]:
    """Per (scene, frame): the agent columns worth looking at for frame t's input.

    Those holding a relevant agent anywhere in ``[t - H, t]``: a few dozen of
    the ~100 columns, so the per-step work shrinks by that factor.  Returns
    cols (S, T, K) int64 and ok (S, T, K) bool (False on padding).
    """
    seen = np.cumsum(log.relevant, axis=1, dtype=np.int32)
    in_window = seen.copy()
    in_window[:, history_frames + 1:] -= seen[:, :-history_frames - 1]
    s, t, a = np.nonzero(in_window)
    n_scenes, n_frames = in_window.shape[:2]
    group = s * n_frames + t
    counts = np.bincount(group, minlength=n_scenes * n_frames)
    k = max(int(counts.max(initial=0)), 1)
    # np.nonzero is row-major, so each (s, t) group is contiguous and ordered by column.
    rank = np.arange(group.size) - (np.cumsum(counts) - counts)[group]
    cols = np.zeros((n_scenes, n_frames, k), np.int64)
    ok = np.zeros((n_scenes, n_frames, k), bool)
    cols[s, t, rank], ok[s, t, rank] = a, True
    return cols, ok


def _cells(log: LogArrays, scene: np.ndarray, frame: np.ndarray, column: np.ndarray) -> np.ndarray:
    """Flat (scene, frame, column) cell index: one take() is several times faster
    than numpy's advanced indexing with three broadcast index arrays."""
    _, n_frames, n_cols = log.available.shape
    return (scene * n_frames + frame) * n_cols + column


def _gather(array: np.ndarray, cells: np.ndarray) -> np.ndarray:
    return np.take(array.reshape((-1,) + array.shape[3:]), cells, axis=0)


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
    idx = _cells(log, rows[:, None, None], hist[:, :, None], cand[:, None, :])  # (B, H+1, K)
    rel = _gather(log.relevant, idx) & (hist_ok[..., None] & cand_ok[:, None, :])
    tid = _gather(log.track_id, idx)
    ref = np.take_along_axis(tid, rel.argmax(axis=1)[:, None, :], 1)  # most recent relevant track
    d = _gather(log.agent_xy, idx) - centre[:, None, None, :]
    dist = np.sqrt(d[..., 0] ** 2 + d[..., 1] ** 2)
    within = rel & (tid == ref) & (dist < radius)
    # Current agents first (by distance), then history-only ones by closest approach.
    score = np.where(within[:, 0], dist[:, 0], radius + np.where(within, dist, np.inf).min(axis=1))
    order = np.argsort(score, axis=1, kind="stable")[:, :max_agents]
    used = np.isfinite(np.take_along_axis(score, order, 1))
    cols, track = np.take_along_axis(cand, order, 1), np.take_along_axis(ref[:, 0], order, 1)
    if cols.shape[1] < max_agents:  # fewer candidates than slots: pad with unused slots
        pad = ((0, 0), (0, max_agents - cols.shape[1]))
        cols, used, track = np.pad(cols, pad), np.pad(used, pad), np.pad(track, pad, constant_values=-1)
    return cols, used, track


def _to_ego_frame(xy: np.ndarray, origin: np.ndarray, cos: np.ndarray, sin: np.ndarray) -> np.ndarray:
    """World points (B, ..., 2) into each row's ego frame; origin/cos/sin are (B,)."""
    shape = (-1,) + (1,) * (xy.ndim - 2)
    dx = xy[..., 0] - origin[:, 0].reshape(shape)
    dy = xy[..., 1] - origin[:, 1].reshape(shape)
    c, s = cos.reshape(shape), sin.reshape(shape)
    return np.stack([c * dx + s * dy, c * dy - s * dx], axis=-1)


def build_batch(log: LogArrays, rows: np.ndarray, frames: np.ndarray, ego_xy: np.ndarray, ego_yaw: np.ndarray, *,
                history_frames: int = 10, future_frames: int = 12, max_agents: int = 30, radius: float = 35.0,
                step_time: float = STEP_TIME, ego_extent: np.ndarray = EGO_EXTENT,
                candidates: tuple[np.ndarray, np.ndarray] | None = None) -> dict[str, torch.Tensor]:
    """Inputs for rows ``(rows[b], frames[b])`` with the ego poses taken from ``ego_xy``/``ego_yaw``.

    ``ego_xy`` (S, T, 2) / ``ego_yaw`` (S, T) are the poses the ego actually
    had: the driven ones in closed loop, the logged ones for training.  The
    targets always come from the log.  ``candidates`` is
    ``window_columns(log, history_frames)``, computed here when not given.
    """
    rows, frames = np.asarray(rows, np.int64), np.asarray(frames, np.int64)
    b = rows.size
    hist = frames[:, None] - np.arange(history_frames + 1)
    hist_ok = hist >= 0
    hist = np.maximum(hist, 0)
    r2 = rows[:, None]
    centre, yaw = ego_xy[rows, frames], ego_yaw[rows, frames]
    cos, sin = np.cos(yaw), np.sin(yaw)

    h_pos = _to_ego_frame(ego_xy[r2, hist], centre, cos, sin) * hist_ok[..., None]
    h_yaw = wrap_angle(ego_yaw[r2, hist] - yaw[:, None]) * hist_ok
    # Frame 0 has no past: fall back to the logged step out of it.
    step = np.where((frames == 0)[:, None], log.ego_xy[rows, min(1, log.ego_xy.shape[1] - 1)] - log.ego_xy[rows, 0],
                    centre - ego_xy[rows, np.maximum(frames - 1, 0)])
    speed = np.sqrt((step ** 2).sum(-1)) / step_time

    fut = frames[:, None] + 1 + np.arange(future_frames)
    fut_ok = fut < log.num_frames[rows][:, None]
    fut = np.minimum(fut, log.ego_xy.shape[1] - 1)
    t_pos = _to_ego_frame(log.ego_xy[r2, fut], centre, cos, sin) * fut_ok[..., None]
    t_yaw = wrap_angle(log.ego_yaw[r2, fut] - yaw[:, None]) * fut_ok

    if candidates is None:
        candidates = window_columns(log, history_frames)
    cols, used, track = select_agents(log, rows, hist, hist_ok, centre, max_agents, radius, candidates)
    idx = _cells(log, rows[:, None, None], hist[:, None, :], cols[:, :, None])  # (B, N, H+1)
    a_ok = _gather(log.available, idx) & (_gather(log.track_id, idx) == track[..., None])
    a_ok &= hist_ok[:, None, :] & used[..., None]
    a_pos = _to_ego_frame(_gather(log.agent_xy, idx), centre, cos, sin) * a_ok[..., None]
    a_yaw = wrap_angle(_gather(log.agent_yaw, idx) - yaw[:, None, None]) * a_ok
    a_ext = _gather(log.agent_extent, idx)[..., :2] * a_ok[..., None]
    a_type = (_gather(log.label, idx) * a_ok).max(axis=-1)  # constant per track; zero for unused slots

    out = {
        "history_positions": h_pos, "history_yaws": h_yaw[..., None], "history_availabilities": hist_ok,
        "target_positions": t_pos, "target_yaws": t_yaw[..., None], "target_availabilities": fut_ok,
        "centroid": centre, "yaw": yaw, "extent": np.broadcast_to(ego_extent, (b, 3)), "speed": speed,
        "world_from_agent": world_from_agent(centre, yaw), "agent_from_world": agent_from_world(centre, yaw),
        "all_other_agents_history_positions": a_pos, "all_other_agents_history_yaws": a_yaw[..., None],
        "all_other_agents_history_extents": a_ext, "all_other_agents_history_availability": a_ok,
        "all_other_agents_types": a_type,
    }
    return {k: torch.from_numpy(np.ascontiguousarray(v, dtype=np.float32)) for k, v in out.items()}


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
