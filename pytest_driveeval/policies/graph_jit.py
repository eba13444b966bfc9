"""The flat graph observation compiled with numba: ``encode(graph_observation(...))`` in two kernels.

:func:`pytest_driveeval.policies.graph.graph_observation` spends some fifty
torch calls on what is a few hundred numbers per episode.  Here
:func:`_differences` lays out every difference whose norm the observation
takes (agent to agent, the ego's included, and goal to agent), torch takes
those norms and the bearings to the goal in two calls, and :func:`_encode`
sorts, gathers, normalises and links each episode's agents, writing the flat
encoding straight into a float32 array.  The norms and bearings stay torch's
because its own code differs from plain float64 arithmetic in the last bit
(``vector_norm`` fuses a multiply-add; ``atan2`` is SLEEF's in vector lanes
and the C library's in strided loops, and both calls here are strided as
graph_observation's); a norm of a difference does not depend on where in
the tensor it sits, so the observation is torch's bit for bit; the rest is
the same float64 arithmetic in the same order.

A non-finite value in an observed agent goes to the torch path, which names it.
"""
from __future__ import annotations

import numpy as np
import torch

from pytest_driveeval.sim import episodes_jit

__all__ = ["flat_observation", "observer"]

_compiled = False
# What the compiled observation saves over torch's, per call and per episode (2-core machine, one core).
_SAVED_PER_CALL, _SAVED_PER_EPISODE = 3e-4, 1e-5


def _differences(xy, goal_xy, out):
    """``out`` (E, A + 1, A, 2): agent i minus agent j, then the goal minus agent j: every difference
    graph_observation takes a norm of (from the ego, between agents, to the goal), whatever the order."""
    e_n, a_n = xy.shape[0], xy.shape[1]
    for e in range(e_n):
        for i in range(a_n):
            for j in range(a_n):
                out[e, i, j, 0] = xy[e, i, 0] - xy[e, j, 0]
                out[e, i, j, 1] = xy[e, i, 1] - xy[e, j, 1]
        for j in range(a_n):
            out[e, a_n, j, 0] = goal_xy[e, 0] - xy[e, j, 0]
            out[e, a_n, j, 1] = goal_xy[e, 1] - xy[e, j, 1]


def _encode(xy, yaw, speed, valid, goal_xy, goal_speed, norm, theta, lo, hi, radius, self_loops, agent_limit,
            flat):
    """graph._nearest's order (a stable sort by distance), the gather, the normalisation and the links of
    graph_observation, in encode's layout, into ``flat`` (E, 3 + K*F + K*K).  ``norm`` (E, A + 1, A) and
    ``theta`` (E, A, 1) are torch's norms and bearings of _differences' rows.  Returns False (``flat``
    unfinished) when an observed agent or a goal holds a value that is not finite."""
    e_n, a_n = yaw.shape
    f_n = len(lo)
    kept = min(a_n, agent_limit)
    span = hi - lo
    key = np.empty(a_n)
    order = np.empty(a_n, np.int64)
    raw = np.empty(f_n)
    links_at = 3 + agent_limit * f_n
    for e in range(e_n):
        others = 0
        for a in range(a_n):
            if a == 0 or valid[e, a]:
                others += a > 0
                if not (np.isfinite(xy[e, a, 0]) and np.isfinite(xy[e, a, 1]) and np.isfinite(yaw[e, a])
                        and np.isfinite(speed[e, a])):
                    return False
            key[a] = norm[e, a, 0] if valid[e, a] else np.inf
        if not (np.isfinite(goal_xy[e, 0]) and np.isfinite(goal_xy[e, 1]) and np.isfinite(goal_speed[e])):
            return False
        key[0] = -np.inf
        # Insertion sort, stable: equal keys keep the input order, as torch.sort(stable=True).
        for a in range(a_n):
            k = a
            while k > 0 and key[a] < key[order[k - 1]]:
                order[k] = order[k - 1]
                k -= 1
            order[k] = a
        n = 1 + min(others, agent_limit - 1)
        row = flat[e]
        row[:] = 0.0
        row[0], row[1], row[2] = agent_limit, n, f_n
        for k in range(min(kept, n)):
            a = order[k]
            raw[0], raw[1], raw[2], raw[3] = xy[e, a, 0], xy[e, a, 1], yaw[e, a], speed[e, a]
            raw[4], raw[5] = goal_xy[e, 0], goal_xy[e, 1]
            raw[6], raw[7] = goal_xy[e, 0] - xy[e, a, 0], goal_xy[e, 1] - xy[e, a, 1]
            raw[8], raw[9], raw[10] = theta[e, a, 0], norm[e, a_n, a], goal_speed[e]
            for f in range(f_n):
                row[3 + k * f_n + f] = np.float32((raw[f] - lo[f]) / span[f])
            for m in range(min(kept, n)):
                if (k == m and self_loops) or (k != m and norm[e, a, order[m]] <= radius):
                    row[links_at + k * agent_limit + m] = 1.0
    return True


class _Buffers:
    """The differences and what torch makes of them, for one batch shape: reused from step to step,
    with the tensor views over them, so a step costs torch two calls and no allocation."""

    def __init__(self, e_n: int, a_n: int):
        self.shape = (e_n, a_n)
        self.differences = np.empty((e_n, a_n + 1, a_n, 2))
        d = torch.from_numpy(self.differences)
        # Strided as graph_observation's to_goal[..., 1:] and [..., :1], so torch takes the same (scalar) loop.
        self.goal_dy, self.goal_dx = d[:, a_n, :, 1:], d[:, a_n, :, :1]
        self.d = d
        self.norm_t = torch.empty((e_n, a_n + 1, a_n), dtype=torch.float64)
        self.theta_t = torch.empty((e_n, a_n, 1), dtype=torch.float64)
        self.norm, self.theta = self.norm_t.numpy(), self.theta_t.numpy()


def flat_observation(xy, yaw, speed, valid, goal_xy, goal_speed, lo, hi, *, agent_limit: int, radius: float,
                     self_loops: bool = True, buffers: _Buffers | None = None):
    """``encode(graph_observation(...))`` (E, 3 + K*F + K*K) float32 for C-contiguous float64 (``valid``:
    bool) numpy inputs of the shapes graph_observation checks and the feature ranges ``lo``, ``hi`` (F,)
    float64; None when an observed agent or a goal is not finite (the torch path raises the error that
    names it).  ``buffers``: the last call's, reused when the shape is the same."""
    global _compiled
    if not _compiled:
        episodes_jit.compile_all(("_differences", "_encode"), globals())
        _compiled = True
    e_n, a_n = yaw.shape
    b = buffers if buffers is not None and buffers.shape == (e_n, a_n) else _Buffers(e_n, a_n)
    _differences(xy, goal_xy, b.differences)
    torch.linalg.vector_norm(b.d, dim=-1, out=b.norm_t)
    torch.atan2(b.goal_dy, b.goal_dx, out=b.theta_t)
    flat = np.empty((e_n, 3 + agent_limit * len(lo) + agent_limit * agent_limit), np.float32)
    if not _encode(xy, yaw, speed, valid, goal_xy, goal_speed, b.norm, b.theta, lo, hi, float(radius),
                   bool(self_loops), agent_limit, flat):
        return None
    return torch.from_numpy(flat)


def observer(ranges, agent_limit: int, radius: float | None = None, self_loops: bool = True):
    """``observe(xy, yaw, speed, valid, goal_xy, goal_speed)`` -> the flat graph observation (E, D) float32,
    ``encode(graph_observation(...))`` by the kernels when numba is installed and the work pays
    for starting it (:func:`pytest_driveeval.sim.episodes_jit.wanted`), else by torch."""
    from pytest_driveeval.policies.graph import SEED_VISIBILITY_RADIUS, encode, graph_observation

    radius = SEED_VISIBILITY_RADIUS if radius is None else radius
    lo, hi = np.array(ranges.per_feature(), dtype=np.float64).T.copy()
    kept: list[_Buffers] = []

    def observe(xy, yaw, speed, valid, goal_xy, goal_speed):
        if isinstance(xy, np.ndarray) and episodes_jit.wanted(_SAVED_PER_CALL + _SAVED_PER_EPISODE * len(xy)):
            xy, yaw, speed = (np.ascontiguousarray(v, dtype=np.float64) for v in (xy, yaw, speed))
            goal_xy, goal_speed = (np.ascontiguousarray(v, dtype=np.float64) for v in (goal_xy, goal_speed))
            valid = np.ascontiguousarray(valid, dtype=np.bool_)
            e_n = len(xy)
            if (xy.ndim == 3 and xy.shape[1] >= 1 and xy.shape[2] == 2 and yaw.shape == speed.shape == valid.shape
                    == xy.shape[:2] and goal_xy.shape == (e_n, 2) and goal_speed.shape == (e_n,)):
                buffers = kept[0] if kept and kept[0].shape == yaw.shape else _Buffers(*yaw.shape)
                kept[:] = [buffers]
                flat = flat_observation(xy, yaw, speed, valid, goal_xy, goal_speed, lo, hi, agent_limit=agent_limit,
                                        radius=radius, self_loops=self_loops, buffers=buffers)
                if flat is not None:
                    return flat
        return encode(graph_observation(xy, yaw, speed, valid, goal_xy, goal_speed, ranges, agent_limit=agent_limit,
                                        radius=radius, self_loops=self_loops))

    return observe
