"""route.centre_route's per-frame loop compiled (numba), for the frames it can decide alone: a frame
keeping lanes of the frame before (or those the one lane before leads into), or looking again where
one plain lane, or only connectors, hold the point.  The frames it cannot decide it hands back to
route's Python loop, one at a time: two plain lanes holding the point (the heading chooses: numpy's
directions) and nuPlan's 5 m rule after a connector (distances to lane outlines, the intersections).
Those are few; the steady frames are most of a run and cost the Python loop a call each.

Each frame's lanes come out in the Python loop's order; a frame whose lanes are those of the frame
before is marked so, and the caller hands out one list per run of such frames, as the Python loop
hands out the very list of the frame before.
"""
from __future__ import annotations

import numpy as np

_compiled = None


def follow():
    """The compiled loop (compiled, or loaded from numba's cache, on first use)."""
    global _compiled
    if _compiled is None:
        _compiled = _compile()
    return _compiled


def _compile():
    from numba import njit

    @njit(cache=True, nogil=True, boundscheck=False)
    def follow_route(holding, connector, out_starts, out_lanes, k, previous, starts, lanes, same, m):
        """From frame ``k`` on, ``previous`` the lanes of frame k - 1: frame j's lanes written to
        lanes[starts[j]:starts[j + 1]] (from position ``m``), same[j] whether they are frame j - 1's.
        Returns (the first frame it leaves to Python, or the frame count; m)."""
        t, n = holding.shape
        kept = np.empty(n, dtype=np.int64)
        while k < t:
            size = 0
            # route._with_candidates: the frame before's lanes holding the point, in their order, else (one
            # lane before) the lanes it leads into that hold it, in the map's order of its successors
            for i in range(previous.shape[0]):
                if holding[k, previous[i]]:
                    kept[size] = previous[i]
                    size += 1
            if size == 0 and previous.shape[0] == 1:
                p = previous[0]
                for i in range(out_starts[p], out_starts[p + 1]):
                    if holding[k, out_lanes[i]]:
                        kept[size] = out_lanes[i]
                        size += 1
            if size == 0:
                # route._look_up: the one plain lane, else every connector holding the point, ascending
                plain, last_plain = 0, -1
                for c in range(n):
                    if holding[k, c] and not connector[c]:
                        plain += 1
                        last_plain = c
                if plain >= 2:
                    return k, m
                if plain == 1:
                    kept[0] = last_plain
                    size = 1
                else:
                    for c in range(n):
                        if holding[k, c]:
                            kept[size] = c
                            size += 1
                # nuPlan's 5 m rule after a connector, where it may apply: Python's
                if k > 1 and previous.shape[0] > 0 and connector[previous[0]] and (size == 0 or connector[kept[0]]):
                    return k, m
            starts[k] = m
            equal = size == previous.shape[0]
            for i in range(size):
                lanes[m + i] = kept[i]
                if equal and kept[i] != previous[i]:
                    equal = False
            same[k] = equal and k > 0
            m += size
            starts[k + 1] = m
            previous = kept[:size].copy()
            k += 1
        return k, m

    return follow_route


def compiled_route(score_map, holding: np.ndarray, step) -> tuple[list[list[int]], np.ndarray, np.ndarray]:
    """route.centre_route's frames before its connectors are cut: per frame its lanes (one list per run of
    frames with the same lanes), (T,) each frame's first lane (-1: none) and (T,) its lane count.
    ``holding`` (T, N): the lanes holding each point; ``step(k, lanes, previous)``: route's own decision for
    frame k, the lanes holding its point and the lanes of the frame before, for the frames handed back."""
    t = len(holding)
    if not t:
        return [], np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    # a frame keeps lanes holding its point, or some of the frame before's: never more than a row holds
    width = max(int(holding.sum(axis=1).max()), 1)
    starts = np.zeros(t + 1, dtype=np.int64)
    lanes = np.empty(t * width, dtype=np.int64)
    same = np.zeros(t, dtype=bool)
    out_starts, out_lanes = score_map.outgoing_table
    kernel = follow()
    k, m, previous = 0, 0, np.zeros(0, dtype=np.int64)
    while True:
        k, m = kernel(holding, score_map.connector, out_starts, out_lanes, k, previous, starts, lanes, same, m)
        if k >= t:
            break
        before = lanes[starts[k - 1]:starts[k]].tolist() if k else []
        current = step(k, np.flatnonzero(holding[k]).tolist(), before)
        starts[k], starts[k + 1] = m, m + len(current)
        lanes[m:m + len(current)] = current
        m += len(current)
        same[k] = k > 0 and current == before
        previous = np.array(current, dtype=np.int64)
        k += 1
    bounds = np.append(np.flatnonzero(~same), t).tolist()
    route: list[list[int]] = []
    for a, b in zip(bounds[:-1], bounds[1:]):
        route += [lanes[starts[a]:starts[a + 1]].tolist()] * (b - a)
    counts = np.diff(starts)
    first = np.where(counts > 0, lanes[np.minimum(starts[:-1], len(lanes) - 1)], -1)
    return route, first, counts
