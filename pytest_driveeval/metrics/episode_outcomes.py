"""How a policy-benchmark episode ends, and its reward: pure functions of arrays.

Arrays are batched over episodes (E, ...); agent 0 of an (E, A) array is the
ego.  Each step the engine asks, in this order of precedence: a collision
(the ego's box overlaps another valid agent's, touching counts), leaving the
drivable area (a corner of the ego's box outside it), reaching the goal
(position in the goal rectangle, heading and speed within bounds), the step
limit.  The first that holds ends the episode.

The reward is the seed's (BARK-ML's ``GoalReached`` evaluator plus its
per-step bonus): +1 at the goal, -1 for a collision or leaving the road, and
+0.01 for every other step, the step limit's included.  Mind that with a
200-step limit an episode that idles to the end earns 2, more than one that
reaches its goal early: judge policies on the outcomes, not on the return.
"""
from __future__ import annotations

import numpy as np

from pytest_driveeval.geometry import oriented_boxes_overlap, wrap_angle

__all__ = ["COLLISION", "GOAL", "OFF_ROAD", "OUTCOME_NAMES", "RUNNING", "STEP_LIMIT", "cells_contain", "classify",
           "ego_collides", "in_goal", "off_road", "step_reward", "traffic_overlaps"]

RUNNING, GOAL, COLLISION, OFF_ROAD, STEP_LIMIT = 0, 1, 2, 3, 4
OUTCOME_NAMES = ("running", "goal", "collision", "off_road", "step_limit")


def in_goal(xy: np.ndarray, yaw: np.ndarray, speed: np.ndarray, centre: np.ndarray, heading: np.ndarray,
            size: np.ndarray, heading_tol: np.ndarray, speed_bounds: np.ndarray) -> np.ndarray:
    """Ego pose (E, 2), (E,), speed (E,) against goal rectangles: centre (E, 2),
    heading (E,), size (E, 2) or (2,) as (length along heading, width), heading
    tolerance, speed bounds (E, 2) or (2,) as (low, high); all inclusive."""
    d = np.asarray(xy, np.float64) - centre
    c, s = np.cos(heading), np.sin(heading)
    size = np.asarray(size, np.float64)
    speed_bounds = np.asarray(speed_bounds, np.float64)
    inside = (np.abs(d[..., 0] * c + d[..., 1] * s) <= 0.5 * size[..., 0]) & (
        np.abs(d[..., 1] * c - d[..., 0] * s) <= 0.5 * size[..., 1])
    aligned = np.abs(wrap_angle(np.asarray(yaw) - heading)) <= heading_tol
    return inside & aligned & (speed >= speed_bounds[..., 0]) & (speed <= speed_bounds[..., 1])


def ego_collides(xy: np.ndarray, yaw: np.ndarray, size: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """(E, A, 2), (E, A), box (length, width), (E, A) -> (E,) the ego overlaps a valid other agent."""
    size = np.asarray(size, np.float64)
    hit = oriented_boxes_overlap(xy[:, :1], yaw[:, :1], size, xy[:, 1:], yaw[:, 1:], size)
    return np.any(hit & valid[:, 1:], axis=-1)


def traffic_overlaps(xy: np.ndarray, yaw: np.ndarray, size: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """(E,) number of overlapping pairs among the valid agents other than the ego: traffic crashing into
    itself, which a sound traffic model never does."""
    size = np.asarray(size, np.float64)
    t_xy, t_yaw, t_valid = xy[:, 1:], yaw[:, 1:], valid[:, 1:]
    hit = oriented_boxes_overlap(t_xy[:, :, None], t_yaw[:, :, None], size, t_xy[:, None], t_yaw[:, None], size)
    hit &= t_valid[:, :, None] & t_valid[:, None, :]
    return np.count_nonzero(np.triu(hit, k=1), axis=(1, 2))


def cells_contain(points: np.ndarray, mask: np.ndarray, origin: np.ndarray, resolution: float) -> np.ndarray:
    """(..., 2) points -> (...) True where the point's cell of a boolean raster is set.

    ``mask[i, j]`` covers the cell with lower-left corner ``origin + (i, j) *
    resolution``; points outside the raster are not contained.
    """
    idx = np.floor((np.asarray(points, np.float64) - origin) / resolution).astype(np.int64)
    nx, ny = mask.shape
    inside = (idx[..., 0] >= 0) & (idx[..., 0] < nx) & (idx[..., 1] >= 0) & (idx[..., 1] < ny)
    return inside & mask[np.clip(idx[..., 0], 0, nx - 1), np.clip(idx[..., 1], 0, ny - 1)]


def off_road(corners: np.ndarray, mask: np.ndarray, origin: np.ndarray, resolution: float) -> np.ndarray:
    """(E, 4, 2) box corners -> (E,) some corner lies outside the drivable raster."""
    return ~np.all(cells_contain(corners, mask, origin, resolution), axis=-1)


def classify(goal: np.ndarray, collision: np.ndarray, off_road: np.ndarray, step_limit: np.ndarray) -> np.ndarray:
    """(E,) int8 outcome of this step by precedence: collision, off-road, goal, step limit, else running."""
    # Nested where rather than np.select: a quarter of the time on per-step batch sizes.
    out = np.where(goal, np.int8(GOAL), np.where(step_limit, np.int8(STEP_LIMIT), np.int8(RUNNING)))
    return np.where(collision, np.int8(COLLISION), np.where(off_road, np.int8(OFF_ROAD), out)).astype(np.int8)


def step_reward(outcome: np.ndarray, active: np.ndarray, *, goal: float = 1.0, crash: float = -1.0,
                step: float = 0.01) -> np.ndarray:
    """(E,) reward of this step from its outcome; 0 for episodes that had already ended (``active`` False)."""
    r = np.where(outcome == GOAL, goal, np.where((outcome == COLLISION) | (outcome == OFF_ROAD), crash, step))
    return np.where(active, r, 0.0)
