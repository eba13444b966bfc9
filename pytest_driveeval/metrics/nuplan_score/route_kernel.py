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
    """The compiled loops (compiled, or loaded from numba's cache, on first use)."""
    global _compiled
    if _compiled is None:
        _compiled = _compile()
    return _compiled


def _compile():
    from numba import njit

    jit = njit(cache=True, nogil=True, boundscheck=False)

    @jit
    def follow_route(holding, connector, out_starts, out_lanes, k, previous, starts, lanes, same, m):
        """From frame ``k`` on, ``previous`` the lanes of frame k - 1: frame j's lanes written to
        lanes[starts[j]:starts[j + 1]] (from position ``m``), same[j] whether they are frame j - 1's.
        Returns (the first frame it leaves to Python, or the frame count; m)."""
        t, n = holding.shape
        kept = np.empty(n + out_lanes.shape[0], dtype=np.int64)  # a successor may be listed twice
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

    @jit
    def _holds(values, size, x):
        for i in range(size):
            if values[i] == x:
                return True
        return False

    @jit
    def _widened(values, size, starts, table, out):
        """values[:size] and the lanes each leads into (or comes from: ``starts``, ``table``), in out; its size."""
        m = 0
        for i in range(size):
            out[m] = values[i]
            m += 1
        for i in range(size):
            for j in range(starts[values[i]], starts[values[i] + 1]):
                out[m] = table[j]
                m += 1
        return m

    @jit
    def corners_connected(holding, connector, out_starts, out_lanes, in_starts, in_lanes, out):
        """route._corners_connected: out[k] for each frame k of the (4T, N) ``holding`` of its corners
        (rows FL, FR, RR, RL), taken in nuPlan's order FL, RL, RR, FR."""
        t4, n = holding.shape
        found = np.empty((4, n + out_lanes.shape[0]), dtype=np.int64)  # a successor may be listed twice
        sizes = np.zeros(4, dtype=np.int64)
        candidates = np.empty(n, dtype=np.int64)
        here = np.empty(n, dtype=np.int64)
        nc = 0
        wide = 2 * (n + out_lanes.shape[0] + in_lanes.shape[0])
        rr_ahead, rl_ahead = np.empty(wide, dtype=np.int64), np.empty(wide, dtype=np.int64)
        fl_behind, fr_behind = np.empty(wide, dtype=np.int64), np.empty(wide, dtype=np.int64)
        for k in range(t4 // 4):
            nh = 0
            for place in range(4):  # FL, RL, RR, FR
                row = 4 * k + (0, 3, 2, 1)[place]
                size = 0
                # route._with_candidates: the candidates holding the corner, else (one) those it leads into
                for i in range(nc):
                    if holding[row, candidates[i]]:
                        found[place, size] = candidates[i]
                        size += 1
                if size == 0 and nc == 1:
                    for i in range(out_starts[candidates[0]], out_starts[candidates[0] + 1]):
                        if holding[row, out_lanes[i]]:
                            found[place, size] = out_lanes[i]
                            size += 1
                if size == 0:
                    # route._look_up without a heading: the first plain lane, else every connector, ascending
                    for c in range(n):
                        if holding[row, c] and not connector[c]:
                            found[place, 0] = c
                            size = 1
                            break
                    if size == 0:
                        for c in range(n):
                            if holding[row, c]:
                                found[place, size] = c
                                size += 1
                    if k == 1:  # on the second frame what a corner looks up joins the candidates
                        for i in range(size):
                            if not _holds(candidates, nc, found[place, i]):
                                candidates[nc] = found[place, i]
                                nc += 1
                for i in range(size):
                    if not _holds(here, nh, found[place, i]):
                        here[nh] = found[place, i]
                        nh += 1
                sizes[place] = size
            for i in range(nh):
                candidates[i] = here[i]
            nc = nh
            out[k] = _common_or_connected(found, sizes, out_starts, out_lanes, in_starts, in_lanes, rr_ahead,
                                          rl_ahead, fl_behind, fr_behind)

    @jit
    def _common_or_connected(found, sizes, out_starts, out_lanes, in_starts, in_lanes, rr_ahead, rl_ahead,
                             fl_behind, fr_behind):
        """route._common_or_connected of found[p][:sizes[p]], p = FL, RL, RR, FR."""
        for p in range(4):
            if sizes[p] == 0:
                return False
        fl, rl, rr, fr = found[0], found[1], found[2], found[3]
        for i in range(sizes[0]):
            x = fl[i]
            if _holds(rl, sizes[1], x) and _holds(rr, sizes[2], x) and _holds(fr, sizes[3], x):
                return True
        n_rr = _widened(rr, sizes[2], out_starts, out_lanes, rr_ahead)
        n_rl = _widened(rl, sizes[1], out_starts, out_lanes, rl_ahead)
        joined = False
        for i in range(sizes[1]):
            if _holds(rr_ahead, n_rr, rl[i]):
                joined = True
        for i in range(sizes[2]):
            if _holds(rl_ahead, n_rl, rr[i]):
                joined = True
        if not joined:
            return False
        n_fl = _widened(fl, sizes[0], in_starts, in_lanes, fl_behind)
        n_fr = _widened(fr, sizes[3], in_starts, in_lanes, fr_behind)
        for i in range(n_fl):
            x = fl_behind[i]
            if _holds(rr_ahead, n_rr, x) and _holds(fr_behind, n_fr, x) and _holds(rl_ahead, n_rl, x):
                return True
        return False

    return follow_route, corners_connected


def compiled_route(score_map, holding: np.ndarray, step) -> tuple[list[list[int]], np.ndarray, np.ndarray]:
    """route.centre_route's frames before its connectors are cut: per frame its lanes (one list per run of
    frames with the same lanes), (T,) each frame's first lane (-1: none) and (T,) its lane count.
    ``holding`` (T, N): the lanes holding each point; ``step(k, lanes, previous)``: route's own decision for
    frame k, the lanes holding its point and the lanes of the frame before, for the frames handed back."""
    t = len(holding)
    if not t:
        return [], np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    # a frame keeps lanes holding its point, some of the frame before's, or a lane's successors (a map may
    # list one twice): never more than a row holds and a lane's successors
    out_starts, out_lanes = score_map.outgoing_table
    width = max(int(holding.sum(axis=1).max()), 1) + int(np.diff(out_starts).max(initial=0))
    starts = np.zeros(t + 1, dtype=np.int64)
    lanes = np.empty(t * width, dtype=np.int64)
    same = np.zeros(t, dtype=bool)
    kernel = follow()[0]
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


def compiled_corners_connected(score_map, holding: np.ndarray) -> np.ndarray:
    """(T,) route._corners_connected from the (4T, N) ``holding`` of the corners (FL, FR, RR, RL per frame)."""
    out = np.zeros(len(holding) // 4, dtype=bool)
    incoming = score_map.incoming
    in_starts = np.concatenate([[0], np.cumsum([len(c) for c in incoming])]).astype(np.int64)
    in_lanes = np.array([m for c in incoming for m in c], dtype=np.int64)
    out_starts, out_lanes = score_map.outgoing_table
    follow()[1](holding, score_map.connector, out_starts, out_lanes, in_starts, in_lanes, out)
    return out
