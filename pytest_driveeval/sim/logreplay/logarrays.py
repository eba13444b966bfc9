"""Logged scenes as dense padded arrays, the replay side of a closed-loop unroll.

Built once per unroll from L5 scenes; the per-step policy inputs
(:mod:`.inputs`) and the engine read from it.
"""
from __future__ import annotations

import heapq
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from pytest_driveeval.io.l5.l5kit_zarr import PERCEPTION_LABELS, L5Arrays, L5Scene
from pytest_driveeval.sim.logreplay import jit

__all__ = ["EGO_EXTENT", "STEP_TIME", "LogArrays", "scenes_from_arrays", "stack_scenes", "window_columns"]

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
    frame_row: np.ndarray  # (S, T, C) int32: the cell's position among its frame's agent rows, -1 in empty cells

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


def _assign_columns(first: np.ndarray, last: np.ndarray, gap: int) -> tuple[np.ndarray, int]:
    """Column of each track, given its first and last frame (greedy interval
    partitioning, optimal for intervals), and the column count."""
    if jit.wanted(first.size * 0.5e-6):  # the heapq loop's cost per track
        from pytest_driveeval.sim.logreplay import logarrays_jit
        column, count = logarrays_jit.assign_columns(np.asarray(first, np.int64), np.asarray(last, np.int64), int(gap),
                                                     np.argsort(first, kind="stable"))
        return column, int(count)
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
    """Dense padded arrays of several scenes.

    ``track_gap`` (frames) keeps a column's consecutive tracks apart so an
    agent history window never has to choose between two tracks of a column;
    the default matches the default history length.
    """
    # Straight from the stored rows into the packed columns: a dense (frames x tracks)
    # table per scene first (thousands of tracks) cost more than unrolling the scene.
    # What the numpy paths cost per stored row more than the compiled ones: the track table
    # (indexing the ids, an argmax over the strided label probabilities) and the scatter below.
    compiled = jit.wanted(sum(len(s.agents) for s in scenes) * 0.12e-6)
    if compiled:
        from pytest_driveeval.sim.logreplay import logarrays_jit
        agent_rows = [s.agent_rows(logarrays_jit.track_table) for s in scenes]
    else:
        agent_rows = [s.agent_rows() for s in scenes]
    columns = [_assign_columns(r.first, r.last, track_gap) for r in agent_rows]
    n_frames = np.array([s.num_frames for s in scenes], dtype=np.int64)
    t_max = int(n_frames.max(initial=1))
    # at least one (empty) column: the engine's agent selection takes from the columns even when no
    # scene has an agent (a scenario whose only track is the ego)
    c_max = max((n for _, n in columns), default=0) or 1
    shape = (len(scenes), t_max, c_max)
    log = LogArrays(
        scene_ids=np.asarray([s.index for s in scenes] if scene_ids is None else scene_ids, dtype=np.int64),
        num_frames=n_frames, ego_xy=np.zeros(shape[:2] + (2,)), ego_yaw=np.zeros(shape[:2]),
        agent_xy=np.zeros(shape + (2,)), agent_yaw=np.zeros(shape, np.float32),
        agent_extent=np.zeros(shape + (3,), np.float32), agent_velocity=np.zeros(shape + (2,), np.float32),
        available=np.zeros(shape, bool), track_id=np.full(shape, -1, np.int64), label=np.zeros(shape, np.int16),
        relevant=np.zeros(shape, bool), frame_row=np.full(shape, -1, np.int32),
    )
    for i, (scene, rows, (column, _)) in enumerate(zip(scenes, agent_rows, columns)):
        t = scene.num_frames
        log.ego_xy[i, :t], log.ego_yaw[i, :t] = scene.ego_positions(), scene.ego_yaws()
        log.ego_xy[i, t:], log.ego_yaw[i, t:] = log.ego_xy[i, t - 1], log.ego_yaw[i, t - 1]
        a = rows.track
        # One flat index per row: scattering through it is several times faster than through (frame, column).
        cell = rows.frame * c_max + column[a]
        label = rows.label[a]
        track = rows.track_ids.astype(np.int64)[a]
        if compiled:
            logarrays_jit.scatter_rows(i, cell, rows.centroid, rows.yaw, rows.extent, rows.velocity, track, label,
                                       _KEEP_LABEL, rows.rank, log.agent_xy, log.agent_yaw, log.agent_extent,
                                       log.agent_velocity, log.available, log.track_id, log.label, log.relevant,
                                       log.frame_row)
            continue

        def put(field: np.ndarray, values) -> None:
            field[i].reshape((-1,) + field.shape[3:])[cell] = values

        put(log.agent_xy, rows.centroid)
        put(log.agent_yaw, rows.yaw)
        put(log.agent_extent, rows.extent)
        put(log.agent_velocity, rows.velocity)
        put(log.available, True)
        put(log.track_id, track)
        put(log.label, label)
        put(log.relevant, _KEEP_LABEL[label])
        put(log.frame_row, rows.rank)
    return log


def rows_by_frame(scene: L5Scene) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every agent row of the scene's frames, frame by frame in stored order:
    (row index into ``scene.agents``, its frame, its position in that frame)."""
    intervals = scene.frames["agent_index_interval"].astype(np.int64)
    counts = intervals[:, 1] - intervals[:, 0]
    frame = np.repeat(np.arange(counts.size), counts)
    rank = np.arange(frame.size) - np.repeat(np.cumsum(counts) - counts, counts)
    return intervals[frame, 0] + rank, frame, rank


def window_columns(log: LogArrays, history_frames: int) -> tuple[np.ndarray, np.ndarray]:
    """Per (scene, frame): the agent columns worth looking at for frame t's input.

    Those holding a relevant agent anywhere in ``[t - H, t]``: a few dozen of
    the ~100 columns, so the per-step work shrinks by that factor.  Returns
    cols (S, T, K) int64 and ok (S, T, K) bool (False on padding).
    """
    if jit.wanted(log.relevant.size * 6e-9):  # numpy's cost per cell
        from pytest_driveeval.sim.logreplay import logarrays_jit
        return logarrays_jit.window_columns(log.relevant, int(history_frames))
    seen = np.cumsum(log.relevant, axis=1, dtype=np.int32)
    in_window = seen.copy()
    in_window[:, history_frames + 1:] -= seen[:, :-history_frames - 1]
    n_scenes, n_frames, n_cols = in_window.shape
    # Flat indices are row-major, so each (s, t) group is contiguous and
    # ordered by column (and much cheaper than a 3-D nonzero).
    group, a = np.divmod(np.flatnonzero(in_window), max(n_cols, 1))
    counts = np.bincount(group, minlength=n_scenes * n_frames)
    k = max(int(counts.max(initial=0)), 1)
    rank = np.arange(group.size) - (np.cumsum(counts) - counts)[group]
    cols = np.zeros((n_scenes, n_frames, k), np.int64)
    ok = np.zeros((n_scenes, n_frames, k), bool)
    cols.reshape(-1, k)[group, rank], ok.reshape(-1, k)[group, rank] = a, True
    return cols, ok
