"""The policy benchmark's step compiled with numba: ``Episodes.step``'s path when numba is installed.

Two kernels per step, each one pass over the episodes, instead of some two
hundred small numpy calls, whose dispatch was what a step of 16 episodes cost:
:func:`~.traffic_jit.traffic_kernel` is :func:`~pytest_driveeval.sim.agents.step_traffic`
up to the heading of a lane change, :func:`_finish` moves the ego (the
kinematic bicycle), places the traffic on its lanes and judges the outcome as
``Episodes.step`` does.  Between them numpy computes the lane change's
``arctan2``, and before them the steering's ``tan``: numpy's float64 ``tan``
and ``arctan2`` are SIMD code on some machines (SVML) that differs from the C
library's in the last bit, so those two stay numpy's.  ``cos`` and ``sin`` are
the C library's in both paths.  Everything else is the numpy path's float64
expressions in the same order (numba compiles without fastmath, so no fused
multiply-adds), and the episodes come out bit for bit (tests/sim/test_episodes_jit.py).

Only straight roads (one segment per lane, all the blueprints'), IDM's default
exponent 4 and a forward-only ego are compiled; :func:`supported` says when.

When: importing numba and starting its compiler costs a process about half a
second, more than a few short episodes save.  :func:`wanted` takes the compiled
paths once numba is loaded anyway, or once the numpy paths have cost the
process that much more than the compiled ones would have (the rent-or-buy rule
of sim.logreplay.jit and metrics.nuplan_score.kernels; a separate account, as
sim may not import sim.logreplay).  The graph observation's kernels
(policies.graph_jit) share this account.
"""
from __future__ import annotations

import importlib.util
import sys
from typing import NamedTuple

import numpy as np

from pytest_driveeval.sim import traffic_jit
from pytest_driveeval.sim.traffic_jit import HALF_LENGTH, HALF_WIDTH, clip

__all__ = ["AVAILABLE", "START_SECONDS", "Constants", "constants", "start", "step", "supported", "wanted"]


def _installed() -> bool:
    if "numba" in sys.modules:  # None there means imports of it are blocked
        return sys.modules["numba"] is not None
    return importlib.util.find_spec("numba") is not None


AVAILABLE = _installed()
START_SECONDS = 0.5  # importing numba and starting its compiler (as sim.logreplay.jit measured it)
_forgone = 0.0  # what the numpy paths cost more so far in this process
_compiled = False
_EPS = float(np.finfo(np.float64).eps)  # what np.sinc puts in place of 0
_RUNNING, _GOAL, _COLLISION, _OFF_ROAD, _STEP_LIMIT = 0, 1, 2, 3, 4


def wanted(seconds_saved: float) -> bool:
    """Whether to take the compiled paths for work the numpy (or torch) path would do ``seconds_saved``
    slower: once numba is loaded anyway, or once the savings forgone in this process reach the cost
    of loading it (rent until the rent paid equals the price, then buy, as sim.logreplay.jit does)."""
    global _forgone
    if not AVAILABLE:
        return False
    if sys.modules.get("numba") is not None:
        return True
    _forgone += seconds_saved
    return _forgone >= START_SECONDS


def start() -> bool:
    """Take the compiled paths from now on in this process (False: numba is not installed)."""
    if AVAILABLE:
        import numba  # noqa: F401  loaded: wanted() says yes from now on
    return AVAILABLE


def compile_all(names: tuple[str, ...], namespace: dict) -> None:
    """Replace the functions ``names`` of a module's ``namespace`` by their numba versions, helpers
    first: a kernel resolves the helpers it calls in the module's globals when it compiles."""
    from numba import njit

    for name in names:
        namespace[name] = njit(cache=True, nogil=True, boundscheck=False)(namespace[name])


def supported(road, model, bicycle) -> bool:
    """Whether the compiled step computes what the numpy one does for this road, traffic model and ego."""
    return AVAILABLE and road.straight_lanes is not None and model.delta == 4.0 and not bicycle.allow_reverse


def _finish(c, g, a0, u0, heading0, mask, origin, goal_centre, goal_heading, goal_size, goal_tol, goal_speed,
            ego_xy, ego_yaw, ego_speed, accel, steer, tan_steer, n_lane, n_s, n_d, n_valid, atan,
            old_xy, old_yaw, old_speed, n_speed, steps, outcome, returns,
            e_xy, e_yaw, e_speed, xy, yaw, speed, reward, flags):
    """The rest of Episodes.step: the ego's bicycle, the traffic's poses (Road.pose), the outcome
    and the reward; ended episodes keep everything.  ``atan``: np.arctan2 of traffic_kernel's pair."""
    e_n, a_n = n_lane.shape
    nx, ny = mask.shape
    hl, hw = c[HALF_LENGTH], c[HALF_WIDTH]
    dt, wheelbase = g[0], g[1]
    corners = ((1.0, 1.0), (1.0, -1.0), (-1.0, -1.0), (-1.0, 1.0))  # geometry.boxes' order
    for e in range(e_n):
        if outcome[e] != _RUNNING:  # ended before this step (outcome is written below, once per episode)
            e_xy[e, 0], e_xy[e, 1], e_yaw[e], e_speed[e] = ego_xy[e, 0], ego_xy[e, 1], ego_yaw[e], ego_speed[e]
            for i in range(a_n):
                xy[e, i, 0], xy[e, i, 1] = old_xy[e, i, 0], old_xy[e, i, 1]
                yaw[e, i], speed[e, i] = old_yaw[e, i], old_speed[e, i]
            reward[e] = 0.0
            flags[0, e] = True
            for k in range(1, 5):
                flags[k, e] = False
            continue
        # KinematicBicycle.step (max_decel, max_accel, max_speed in g[2:5]).
        acc = clip(accel[e], -g[2], g[3])
        v0 = ego_speed[e]
        v = clip(v0 + acc * dt, 0.0, g[4])
        arc = 0.5 * (v0 + v) * dt
        dyaw = arc * tan_steer[e] / wheelbase
        x = np.pi * (dyaw / (2.0 * np.pi))
        if x == 0.0:
            x = _EPS
        chord = arc * (np.sin(x) / x)
        mid = ego_yaw[e] + 0.5 * dyaw
        e_xy[e, 0] = ego_xy[e, 0] + chord * np.cos(mid)
        e_xy[e, 1] = ego_xy[e, 1] + chord * np.sin(mid)
        ey = (ego_yaw[e] + dyaw + np.pi) % (2.0 * np.pi) - np.pi
        e_yaw[e], e_speed[e] = ey, v
        # The traffic on its lanes; the ego's box is centred half a wheelbase ahead of its rear axle.
        for i in range(a_n):
            l = n_lane[e, i]
            xy[e, i, 0] = a0[l, 0] + n_s[e, i] * u0[l, 0] - n_d[e, i] * u0[l, 1]
            xy[e, i, 1] = a0[l, 1] + n_s[e, i] * u0[l, 1] + n_d[e, i] * u0[l, 0]
            yaw[e, i] = heading0[l] + atan[e, i]
            speed[e, i] = n_speed[e, i]
        half = 0.5 * wheelbase
        xy[e, 0, 0] = e_xy[e, 0] + half * np.cos(ey)
        xy[e, 0, 1] = e_xy[e, 1] + half * np.sin(ey)
        yaw[e, 0], speed[e, 0] = ey, v
        # episode_outcomes.ego_collides (geometry.oriented_boxes_overlap with tol 0).
        cx, cy = xy[e, 0, 0], xy[e, 0, 1]
        ca, sa = np.cos(ey), np.sin(ey)
        collision = False
        for j in range(1, a_n):
            if not n_valid[e, j]:
                continue
            cb, sb = np.cos(yaw[e, j]), np.sin(yaw[e, j])
            dx, dy = xy[e, j, 0] - cx, xy[e, j, 1] - cy
            cos_rel = abs(ca * cb + sa * sb)
            sin_rel = abs(ca * sb - sa * cb)
            if (abs(dx * ca + dy * sa) <= hl + cos_rel * hl + sin_rel * hw + 0.0
                    and abs(dy * ca - dx * sa) <= hw + sin_rel * hl + cos_rel * hw + 0.0
                    and abs(dx * cb + dy * sb) <= hl + cos_rel * hl + sin_rel * hw + 0.0
                    and abs(dy * cb - dx * sb) <= hw + sin_rel * hl + cos_rel * hw + 0.0):
                collision = True
        # episode_outcomes.off_road on geometry.box_corners.
        left = False
        for k in range(4):
            lx, ly = hl * corners[k][0], hw * corners[k][1]
            px = cx + ca * lx - sa * ly
            py = cy + sa * lx + ca * ly
            ix = int(np.floor((px - origin[0]) / g[6]))
            iy = int(np.floor((py - origin[1]) / g[6]))
            if not (ix >= 0 and ix < nx and iy >= 0 and iy < ny and mask[ix, iy]):
                left = True
        # episode_outcomes.in_goal.
        gdx, gdy = cx - goal_centre[e, 0], cy - goal_centre[e, 1]
        gc, gs = np.cos(goal_heading[e]), np.sin(goal_heading[e])
        off = (ey - goal_heading[e] + np.pi) % (2.0 * np.pi) - np.pi
        goal = (abs(gdx * gc + gdy * gs) <= 0.5 * goal_size[e, 0] and abs(gdy * gc - gdx * gs) <= 0.5 * goal_size[e, 1]
                and abs(off) <= goal_tol[e] and v >= goal_speed[e, 0] and v <= goal_speed[e, 1])
        steps[e] += 1
        if collision:
            out = _COLLISION
        elif left:
            out = _OFF_ROAD
        elif goal:
            out = _GOAL
        elif steps[e] >= g[7]:
            out = _STEP_LIMIT
        else:
            out = _RUNNING
        r = 1.0 if out == _GOAL else (-1.0 if out == _COLLISION or out == _OFF_ROAD else 0.01)
        reward[e], outcome[e] = r, out
        flags[0, e] = out != _RUNNING
        for k in range(1, 5):
            flags[k, e] = out == k
        returns[e] = returns[e] + r


class Constants(NamedTuple):
    """What a batch of episodes steps with, worked out once (see :func:`constants`)."""

    traffic: np.ndarray  # traffic_jit.CONSTANTS
    ego: np.ndarray  # dt, wheelbase, max_decel, max_accel, max_speed, max_steer, grid resolution, max_steps
    lanes: tuple[np.ndarray, ...]  # each lane's start (L, 2), direction (L, 2), heading (L,), first lane of its heading


def constants(blueprint, traffic_model, bicycle, size: np.ndarray) -> Constants:
    """The :class:`Constants` of episodes of ``blueprint`` (a road :func:`supported` takes)."""
    start, direction, heading = blueprint.road.straight_lanes
    same = np.array([int(np.flatnonzero(heading == h)[0]) for h in heading], dtype=np.int64)
    ego = np.array([bicycle.dt, bicycle.wheelbase, bicycle.max_decel, bicycle.max_accel, bicycle.max_speed,
                    bicycle.max_steer, blueprint.road.drivable.resolution, blueprint.max_steps], dtype=np.float64)
    return Constants(traffic_jit.constants(traffic_model, size, blueprint.dt), ego, (start, direction, heading, same))


def step(episodes, ego, consts: Constants, actions: np.ndarray):
    """``Episodes.step``'s work on ``episodes`` (the ego's state ``ego``), whose arrays are read, never
    written: the new traffic fields, ego state, poses (xy, yaw, speed), (steps, outcome, returns), the
    reward (E,) and flags (5, E) bool: done, then ended on this step by goal, collision, off-road, step limit."""
    global _compiled
    if not _compiled:
        compile_all(("_max", "_min", "clip", "_free", "_interaction", "traffic_kernel"), vars(traffic_jit))
        compile_all(("clip", "_finish"), globals())
        _compiled = True
    road, traffic = episodes.blueprint.road, episodes.traffic
    e_n, a_n = traffic.lane.shape
    c, g, (a0, u0, heading0, same_heading) = consts

    shape = (e_n, a_n)
    n_lane, n_yield = np.empty(shape, np.int64), np.empty(shape, np.int64)
    n_s, n_d, n_speed, n_offset, n_time = (np.empty(shape) for _ in range(5))
    n_valid = np.empty(shape, np.bool_)
    atan_y, atan_x = np.empty(shape), np.empty(shape)
    traffic_jit.traffic_kernel(
        c, a0, u0, heading0, same_heading, road.widths, road.lengths, road.end_s, road.left_of, road.right_of,
        traffic.lane, traffic.s, traffic.d, traffic.speed, traffic.desired_speed, traffic.change_offset,
        traffic.change_time, traffic.yield_to, traffic.valid, episodes.xy, episodes.yaw, episodes.speed,
        episodes.outcome, n_lane, n_s, n_d, n_speed, n_offset, n_time, n_yield, n_valid, atan_y, atan_x)
    atan = np.arctan2(atan_y, atan_x)
    steer = np.minimum(np.maximum(actions[:, 1], -g[5]), g[5])  # np.clip, for finite values
    tan_steer = np.tan(steer)

    # At the start the ego's yaw and speed are strided views: one layout, one compilation.
    ego_xy, ego_yaw, ego_speed = (np.ascontiguousarray(v) for v in (ego.xy, ego.yaw, ego.speed))
    e_xy, e_yaw, e_speed = np.empty((e_n, 2)), np.empty(e_n), np.empty(e_n)
    xy, yaw, speed = np.empty((e_n, a_n, 2)), np.empty(shape), np.empty(shape)
    steps, outcome, returns = episodes.steps.copy(), episodes.outcome.copy(), episodes.returns.copy()
    reward, flags = np.empty(e_n), np.empty((5, e_n), np.bool_)
    grid = road.drivable
    _finish(c, g, a0, u0, heading0, grid.mask, grid.origin, episodes.goal_centre, episodes.goal_heading,
            episodes.goal_size, episodes.goal_heading_tol, episodes.goal_speed_bounds, ego_xy, ego_yaw,
            ego_speed, np.ascontiguousarray(actions[:, 0]), steer, tan_steer, n_lane, n_s, n_d, n_valid, atan,
            episodes.xy, episodes.yaw, episodes.speed, n_speed, steps, outcome, returns,
            e_xy, e_yaw, e_speed, xy, yaw, speed, reward, flags)
    new = dict(lane=n_lane, s=n_s, d=n_d, speed=n_speed, desired_speed=traffic.desired_speed, change_offset=n_offset,
               change_time=n_time, yield_to=n_yield, valid=n_valid)
    return new, (e_xy, e_yaw, e_speed), (xy, yaw, speed), (steps, outcome, returns), reward, flags
