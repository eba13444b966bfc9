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

try:
    from numba import njit
except ImportError:  # pragma: no cover - exercised where numba is absent
    njit = None

__all__ = ["AVAILABLE", "assign_columns", "scatter_rows", "window_columns"]

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
