"""The flat graph observation compiled with numba: ``encode(graph_observation(...))`` in two kernels.

:func:`pytest_driveeval.policies.graph.graph_observation` spends some fifty
torch calls on what is a few hundred numbers per episode.  Here one kernel
orders each episode's agents (the stable sort by distance of ``_nearest``) and
gathers them, a second normalises them, links them and writes the flat
encoding straight into a float32 array.  The four values torch computes with
its own SIMD code, which differ from plain float64 arithmetic in the last bit
(``vector_norm`` fuses a multiply-add, ``atan2`` is SLEEF's in vector lanes and
the C library's in the tail), are still computed by those torch calls, on
tensors of the same shapes and strides, so the observation is torch's bit for
bit; the rest is the same float64 arithmetic in the same order.

A non-finite value in an observed agent goes to the torch path, which names it.
"""
from __future__ import annotations

import numpy as np
import torch

from pytest_driveeval.sim import episodes_jit

__all__ = ["flat_observation", "observer"]

_compiled = False
# What the compiled observation saves over torch's, per call and per episode (2-core machine, one core).
_SAVED_PER_CALL, _SAVED_PER_EPISODE = 6e-4, 1e-5
# Columns of the gathered agents: x, y, yaw, speed, goal x, goal y, goal speed (graph_observation's per_agent).
_COLUMNS = 7


def _gather(xy, yaw, speed, valid, goal_xy, goal_speed, distance, kept, taken, count, to_goal, pair):
    """graph._nearest and the gather: ``taken`` (E, kept, 7) in distance order, ``count`` (E,),
    ``to_goal`` (E, kept, 2) and ``pair`` (E, kept, kept, 2) the differences torch takes norms of.
    Returns False when an observed agent holds a value that is not finite."""
    e_n, a_n = yaw.shape
    key = np.empty(a_n)
    order = np.empty(a_n, np.int64)
    finite = True
    for e in range(e_n):
        others = 0
        for a in range(a_n):
            key[a] = distance[e, a] if valid[e, a] else np.inf
            if a > 0 and valid[e, a]:
                others += 1
            if (a == 0 or valid[e, a]) and not (np.isfinite(xy[e, a, 0]) and np.isfinite(xy[e, a, 1])
                                                and np.isfinite(yaw[e, a]) and np.isfinite(speed[e, a])):
                finite = False
        key[0] = -np.inf
        if not (np.isfinite(goal_xy[e, 0]) and np.isfinite(goal_xy[e, 1]) and np.isfinite(goal_speed[e])):
            finite = False
        # Stable insertion sort: equal keys keep the input order, as torch.sort(stable=True).
        for a in range(a_n):
            k = a
            while k > 0 and key[a] < key[order[k - 1]]:
                order[k] = order[k - 1]
                k -= 1
            order[k] = a
        count[e] = 1 + min(others, kept - 1) if kept > 0 else 1
        for k in range(kept):
            a = order[k]
            taken[e, k, 0], taken[e, k, 1] = xy[e, a, 0], xy[e, a, 1]
            taken[e, k, 2], taken[e, k, 3] = yaw[e, a], speed[e, a]
            taken[e, k, 4], taken[e, k, 5], taken[e, k, 6] = goal_xy[e, 0], goal_xy[e, 1], goal_speed[e]
            to_goal[e, k, 0] = taken[e, k, 4] - taken[e, k, 0]
            to_goal[e, k, 1] = taken[e, k, 5] - taken[e, k, 1]
        for i in range(kept):
            for j in range(kept):
                pair[e, i, j, 0] = taken[e, i, 0] - taken[e, j, 0]
                pair[e, i, j, 1] = taken[e, i, 1] - taken[e, j, 1]
    return finite


def _encode(taken, count, to_goal, theta, goal_d, apart, lo, hi, radius, self_loops, agent_limit, flat):
    """graph_observation's normalisation and links, then encode's layout, into ``flat`` (E, 3 + K*F + K*K)."""
    e_n, kept = taken.shape[0], taken.shape[1]
    f_n = len(lo)
    span = hi - lo
    raw = np.empty(f_n)
    nodes_at = 3
    links_at = 3 + agent_limit * f_n
    for e in range(e_n):
        row = flat[e]
        row[:] = 0.0
        n = count[e]
        row[0], row[1], row[2] = agent_limit, n, f_n
        for k in range(min(kept, n)):
            for f in range(6):
                raw[f] = taken[e, k, f]
            raw[6], raw[7] = to_goal[e, k, 0], to_goal[e, k, 1]
            raw[8], raw[9], raw[10] = theta[e, k, 0], goal_d[e, k, 0], taken[e, k, 6]
            for f in range(f_n):
                row[nodes_at + k * f_n + f] = np.float32((raw[f] - lo[f]) / span[f])
        for i in range(min(kept, n)):
            for j in range(min(kept, n)):
                if (i == j and self_loops) or (i != j and apart[e, i, j] <= radius):
                    row[links_at + i * agent_limit + j] = 1.0


def flat_observation(xy, yaw, speed, valid, goal_xy, goal_speed, lo, hi, *, agent_limit: int, radius: float,
                     self_loops: bool = True):
    """``encode(graph_observation(...))`` (E, 3 + K*F + K*K) float32 for float64 numpy inputs of the
    shapes graph_observation checks and the feature ranges ``lo``, ``hi`` (F,) float64; None when an
    observed agent or a goal is not finite (the torch path raises the error that names it)."""
    global _compiled
    if not _compiled:
        episodes_jit.compile_all(("_gather", "_encode"), globals())
        _compiled = True
    e_n, a_n = yaw.shape
    kept = min(a_n, agent_limit)
    distance = torch.linalg.vector_norm(torch.from_numpy(xy - xy[:, :1]), dim=-1).numpy()
    taken = np.empty((e_n, kept, _COLUMNS))
    count = np.empty(e_n, np.int64)
    to_goal = np.empty((e_n, kept, 2))
    pair = np.empty((e_n, kept, kept, 2))
    if not _gather(xy, yaw, speed, valid, goal_xy, goal_speed, distance, kept, taken, count, to_goal, pair):
        return None
    to_goal_t = torch.from_numpy(to_goal)
    theta = torch.atan2(to_goal_t[..., 1:], to_goal_t[..., :1]).numpy()
    goal_d = torch.linalg.vector_norm(to_goal_t, dim=-1, keepdim=True).numpy()
    apart = torch.linalg.vector_norm(torch.from_numpy(pair), dim=-1).numpy()
    flat = np.empty((e_n, 3 + agent_limit * len(lo) + agent_limit * agent_limit), np.float32)
    _encode(taken, count, to_goal, theta, goal_d, apart, lo, hi, float(radius), bool(self_loops), agent_limit, flat)
    return torch.from_numpy(flat)


def observer(ranges, agent_limit: int, radius: float | None = None, self_loops: bool = True):
    """``observe(xy, yaw, speed, valid, goal_xy, goal_speed)`` -> the flat graph observation (E, D) float32,
    ``encode(graph_observation(...))`` by the kernels when numba is installed and the work pays
    for starting it (:func:`pytest_driveeval.sim.episodes_jit.wanted`), else by torch."""
    from pytest_driveeval.policies.graph import SEED_VISIBILITY_RADIUS, encode, graph_observation

    radius = SEED_VISIBILITY_RADIUS if radius is None else radius
    lo, hi = np.array(ranges.per_feature(), dtype=np.float64).T.copy()

    def observe(xy, yaw, speed, valid, goal_xy, goal_speed):
        if isinstance(xy, np.ndarray) and episodes_jit.wanted(_SAVED_PER_CALL + _SAVED_PER_EPISODE * len(xy)):
            xy, yaw, speed = (np.ascontiguousarray(v, dtype=np.float64) for v in (xy, yaw, speed))
            goal_xy, goal_speed = np.ascontiguousarray(goal_xy, np.float64), np.ascontiguousarray(goal_speed, np.float64)
            valid = np.ascontiguousarray(valid, dtype=np.bool_)
            e_n = len(xy)
            if (xy.ndim == 3 and xy.shape[1] >= 1 and xy.shape[2] == 2 and yaw.shape == speed.shape == valid.shape
                    == xy.shape[:2] and goal_xy.shape == (e_n, 2) and goal_speed.shape == (e_n,)):
                flat = flat_observation(xy, yaw, speed, valid, goal_xy, goal_speed, lo, hi, agent_limit=agent_limit,
                                        radius=radius, self_loops=self_loops)
                if flat is not None:
                    return flat
        return encode(graph_observation(xy, yaw, speed, valid, goal_xy, goal_speed, ranges, agent_limit=agent_limit,
                                        radius=radius, self_loops=self_loops))

    return observe
