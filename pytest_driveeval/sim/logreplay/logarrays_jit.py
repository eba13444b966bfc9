"""The loops of :mod:`.logarrays` compiled with numba, its path when numba is installed.

The greedy partition of a scene's tracks into columns goes track by track
through a priority queue of the columns' free-from frames; in Python (heapq)
that loop was the largest single cost of loading a scene.  The compiled queue
is a plain binary heap on (free-from frame, column) pairs: their order is
total (columns are distinct), so every queue pops the same pair, and the
columns are those of the heapq loop exactly.
"""
from __future__ import annotations

import numpy as np

from pytest_driveeval.io.l5.l5kit_zarr import DENSE_IDS, TrackTable
from pytest_driveeval.io.l5.l5kit_zarr import track_table as numpy_track_table

try:
    from numba import njit
except ImportError:  # pragma: no cover - exercised where numba is absent
    njit = None

__all__ = ["AVAILABLE", "assign_columns", "scatter_rows", "track_table", "window_columns"]

AVAILABLE = njit is not None


def _compiled(fn):
    return njit(cache=True, nogil=True, boundscheck=False)(fn) if AVAILABLE else fn


@_compiled
def assign_columns(first, last, gap, order):
    """Column of each track (tracks taken in ``order``, by first frame) and the column count:
    a track takes the column free longest before its first frame, or a new one."""
    n = first.shape[0]
    column = np.empty(n, np.int64)
    key = np.empty(n, np.int64)  # heap of (last busy frame + gap, column), compared inline below
    col = np.empty(n, np.int64)
    size = 0
    count = 0
    for a in order:
        if size > 0 and key[0] < first[a]:
            c = col[0]
            # Pop: the last pair to the root, sifted down.
            size -= 1
            key[0] = key[size]
            col[0] = col[size]
            i = 0
            while True:
                m = i
                left = 2 * i + 1
                right = left + 1
                if left < size and (key[left] < key[m] or (key[left] == key[m] and col[left] < col[m])):
                    m = left
                if right < size and (key[right] < key[m] or (key[right] == key[m] and col[right] < col[m])):
                    m = right
                if m == i:
                    break
                key[i], key[m] = key[m], key[i]
                col[i], col[m] = col[m], col[i]
                i = m
        else:
            c = count
            count += 1
        column[a] = c
        # Push, sifted up.
        i = size
        key[i] = last[a] + gap
        col[i] = c
        size += 1
        while i > 0:
            parent = (i - 1) // 2
            if not (key[i] < key[parent] or (key[i] == key[parent] and col[i] < col[parent])):
                break
            key[i], key[parent] = key[parent], key[i]
            col[i], col[parent] = col[parent], col[i]
            i = parent
    return column, count


@_compiled
def scatter_rows(i, cell, centroid, yaw, extent, velocity, track_id, label, keep, rank,
                 agent_xy, agent_yaw, agent_extent, agent_velocity, available, track, labels, relevant, frame_row):
    """Scene i's agent rows into their (frame, column) cells, ``cell`` = frame * C + column,
    all fields in one pass; ``track_id``/``label`` are per row, ``keep`` per label."""
    n_cols = agent_xy.shape[2]
    for r in range(cell.shape[0]):
        f = cell[r] // n_cols
        c = cell[r] - f * n_cols
        agent_xy[i, f, c, 0] = centroid[r, 0]
        agent_xy[i, f, c, 1] = centroid[r, 1]
        agent_yaw[i, f, c] = yaw[r]
        for d in range(3):
            agent_extent[i, f, c, d] = extent[r, d]
        agent_velocity[i, f, c, 0] = velocity[r, 0]
        agent_velocity[i, f, c, 1] = velocity[r, 1]
        available[i, f, c] = True
        track[i, f, c] = track_id[r]
        labels[i, f, c] = label[r]
        relevant[i, f, c] = keep[label[r]]
        frame_row[i, f, c] = rank[r]


def track_table(ids, frame, probabilities, num_frames):
    """:func:`~pytest_driveeval.io.l5.l5kit_zarr.track_table` in one pass over the rows, equal to
    it field for field; ids too sparse for a lookup table take the numpy path."""
    top = int(ids.max()) if ids.size else 0
    if not ids.size or top >= DENSE_IDS * ids.size:
        return numpy_track_table(ids, frame, probabilities, num_frames)
    return TrackTable(*_dense_track_table(ids, frame, probabilities, num_frames, top))


@_compiled
def _dense_track_table(ids, frame, probabilities, num_frames, top):
    n_rows, n_labels = probabilities.shape
    index = np.full(top + 1, -1, np.int64)
    for r in range(n_rows):
        index[ids[r]] = 0
    n_tracks = 0
    for i in range(top + 1):
        if index[i] == 0:
            index[i] = n_tracks
            n_tracks += 1
    track_ids = np.empty(n_tracks, ids.dtype)
    for i in range(top + 1):
        if index[i] >= 0:
            track_ids[index[i]] = i
    track = np.empty(n_rows, np.int64)
    first = np.full(n_tracks, num_frames, np.int64)
    last = np.full(n_tracks, -1, np.int64)
    votes = np.zeros((n_tracks, n_labels), np.int64)
    repeated = -1
    for r in range(n_rows):
        a = index[ids[r]]
        track[r] = a
        f = frame[r]
        if last[a] == f and repeated < 0:  # rows come in frame order: the earliest repeat is the first met
            repeated = f
        first[a] = min(first[a], f)
        last[a] = max(last[a], f)
        # numpy's argmax: the first maximum, or the first NaN.
        best = probabilities[r, 0]
        k = 0
        if best == best:
            for j in range(1, n_labels):
                v = probabilities[r, j]
                if not v <= best:
                    k = j
                    if v != v:
                        break
                    best = v
        votes[a, k] += 1
    label = np.zeros(n_tracks, np.int64)
    for a in range(n_tracks):
        for j in range(1, n_labels):
            if votes[a, j] > votes[a, label[a]]:
                label[a] = j
    return track_ids, track, first, last, label, repeated


@_compiled
def window_columns(relevant, history_frames):
    """:func:`~.logarrays.window_columns` from the log's ``relevant`` (S, T, C): a count per
    column of its relevant cells in [t - H, t], slid frame by frame; one pass sizes the
    table, a second fills it in column order."""
    n_scenes, n_frames, n_cols = relevant.shape
    count = np.zeros(n_cols, np.int32)
    sizes = np.zeros((n_scenes, n_frames), np.int64)
    for s in range(n_scenes):
        count[:] = 0
        for t in range(n_frames):
            old = t - history_frames - 1
            n = 0
            for c in range(n_cols):
                v = count[c] + relevant[s, t, c]
                if old >= 0:
                    v -= relevant[s, old, c]
                count[c] = v
                n += v > 0
            sizes[s, t] = n
    k = max(1, sizes.max()) if sizes.size else 1
    cols = np.zeros((n_scenes, n_frames, k), np.int64)
    ok = np.zeros((n_scenes, n_frames, k), np.bool_)
    for s in range(n_scenes):
        count[:] = 0
        for t in range(n_frames):
            old = t - history_frames - 1
            n = 0
            for c in range(n_cols):
                v = count[c] + relevant[s, t, c]
                if old >= 0:
                    v -= relevant[s, old, c]
                count[c] = v
                if v > 0:
                    cols[s, t, n] = c
                    ok[s, t, n] = True
                    n += 1
    return cols, ok
