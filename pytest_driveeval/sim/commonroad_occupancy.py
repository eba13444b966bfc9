"""Where each CommonRoad obstacle is at each step of an episode, as one box per obstacle for the fast
collision test, and the exact shapes behind the boxes that only bound them.

Every obstacle is one column of the scene's arrays: a box (centre, heading per step; one size) that the
episodes test the ego against first.  Where that box is the obstacle itself (a rectangle at an exact
state) nothing more is kept.  Elsewhere the box only bounds what the obstacle occupies, and the step's
shapes decide a box hit (``ObstacleReplay.exact``):

* a circle or polygon obstacle at an exact state: its shape placed at the state;
* a set-valued state (a shape as position, an interval as orientation): the obstacle may be anywhere in
  the set, so it occupies the axis-aligned rectangle that holds every placement (the position set's
  bounds widened by the shape turned by the state's orientation, or by the shape's radius about its
  reference point when the orientation is an interval); the box is drawn at the set's middle;
* an obstacle given by an occupancy set: at its initial state's step its shape there, as commonroad-io's
  ``occupancy_at_time``; after it present at the steps its occupancies cover, there the union of their
  shapes (commonroad-io takes the first occupancy that covers a step: the same where they do not
  overlap, and never less), its box round them (heading 0, speed 0: an occupancy set has neither).

The box's size is the largest any step needs, so a box miss is a miss of the shapes too.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pytest_driveeval.io.commonroad.commonroad_geometry import shape_outline
from pytest_driveeval.io.commonroad.commonroad_types import Circle, Obstacle, Polygon, Rectangle, Shape, StateSet

__all__ = ["ObstacleReplay", "replay", "placed", "shape_box"]


@dataclass(frozen=True, eq=False)
class ObstacleReplay:
    """One obstacle over the steps ``times``: box centres (T, 2), headings, speeds, presence (T,), the box
    size (2,), and where the box only bounds it, ``exact``: (index (T,) into ``shapes``, -1 where the box is
    exact; ``shapes``: tuples of world-frame shapes).  Static obstacles index one entry throughout."""

    xy: np.ndarray
    yaw: np.ndarray
    speed: np.ndarray
    valid: np.ndarray
    size: np.ndarray
    exact: tuple[np.ndarray, list[tuple[Shape, ...]]] | None = None


def shape_box(shape: Shape) -> tuple[np.ndarray, np.ndarray, float]:
    """(length, width), centre offset and heading offset of a shape's box in the obstacle's frame: a
    rectangle's own, a circle's square, a polygon's axis-aligned bounds."""
    if isinstance(shape, Rectangle):
        return np.array([shape.length, shape.width]), np.asarray(shape.center, float), float(shape.orientation)
    if isinstance(shape, Circle):
        return np.full(2, 2.0 * shape.radius), np.asarray(shape.center, float), 0.0
    if isinstance(shape, Polygon):
        lo, hi = shape.vertices.min(axis=0), shape.vertices.max(axis=0)
        return hi - lo, 0.5 * (lo + hi), 0.0
    raise TypeError(f"not a CommonRoad shape: {type(shape).__name__}")


def placed(shape: Shape, x: float, y: float, heading: float) -> Shape:
    """The obstacle-frame ``shape`` turned by ``heading`` and moved to (x, y): world frame."""
    c, s = math.cos(heading), math.sin(heading)
    turn = np.array([[c, s], [-s, c]])
    if isinstance(shape, Polygon):
        return Polygon(shape.vertices @ turn + (x, y))
    centre = np.asarray(shape.center, float) @ turn + (x, y)
    if isinstance(shape, Circle):
        return Circle(shape.radius, centre)
    return Rectangle(shape.length, shape.width, centre, shape.orientation + heading)


def _bounds(shapes: tuple[Shape, ...]) -> tuple[np.ndarray, np.ndarray]:
    lo, hi = np.full(2, np.inf), np.full(2, -np.inf)
    for shape in shapes:
        if isinstance(shape, Circle):
            c = np.asarray(shape.center, float)
            lo, hi = np.minimum(lo, c - shape.radius), np.maximum(hi, c + shape.radius)
        else:
            outline = shape_outline(shape)
            lo, hi = np.minimum(lo, outline.min(axis=0)), np.maximum(hi, outline.max(axis=0))
    return lo, hi


def _set_region(shape: Shape, sets: StateSet, x: float, y: float, heading: float) -> Rectangle:
    """The axis-aligned rectangle holding every placement of ``shape`` the set-valued state allows."""
    lo, hi = _bounds(sets.position) if sets.position else (np.array([x, y]), np.array([x, y]))
    if sets.interval("orientation") is not None:
        own = _bounds((shape,))
        radius = float(np.max(np.abs(np.concatenate([own[0], own[1]])))) * math.sqrt(2.0)
        lo, hi = lo - radius, hi + radius
    else:
        at_origin = _bounds((placed(shape, 0.0, 0.0, heading),))
        lo, hi = lo + at_origin[0], hi + at_origin[1]
    return Rectangle(float(hi[0] - lo[0]), float(hi[1] - lo[1]), 0.5 * (lo + hi), 0.0)


def _half_extent(shapes: tuple[Shape, ...], centre: np.ndarray, yaw: float) -> np.ndarray:
    """Half length and width a box at ``centre`` turned by ``yaw`` needs to hold ``shapes``."""
    c, s = math.cos(yaw), math.sin(yaw)
    axes = np.array([[c, s], [-s, c]]).T  # columns: along, across
    need = np.zeros(2)
    for shape in shapes:
        if isinstance(shape, Circle):
            need = np.maximum(need, np.abs((np.asarray(shape.center, float) - centre) @ axes) + shape.radius)
        else:
            need = np.maximum(need, np.abs((shape_outline(shape) - centre) @ axes).max(axis=0))
    return need


def _occupancy_replay(obstacle: Obstacle, times: np.ndarray) -> ObstacleReplay:
    n = len(times)
    index = np.full(n, -1, np.int64)
    shapes: list[tuple[Shape, ...]] = []
    per_step: dict[int, list[Shape]] = {}
    init = obstacle.initial
    for occ in obstacle.occupancy:
        for t in range(max(occ.start, int(times[0]), init.time_step + 1), min(occ.end, int(times[-1])) + 1):
            per_step.setdefault(t, []).extend(occ.shapes)
    if times[0] <= init.time_step <= times[-1]:  # as commonroad-io: its initial state's shape at that step
        heading = 0.0 if math.isnan(init.orientation) else init.orientation
        per_step[init.time_step] = [placed(obstacle.shape, init.x, init.y, heading)]
    xy = np.zeros((n, 2))
    half = np.zeros(2)
    for t, found in sorted(per_step.items()):
        k = t - int(times[0])
        group = tuple(found)
        lo, hi = _bounds(group)
        xy[k] = 0.5 * (lo + hi)
        half = np.maximum(half, 0.5 * (hi - lo))
        index[k] = len(shapes)
        shapes.append(group)
    valid = index >= 0
    if valid.any():  # absent steps keep the first present centre, for pictures
        xy[~valid] = xy[int(np.flatnonzero(valid)[0])]
    return ObstacleReplay(xy, np.zeros(n), np.zeros(n), valid, np.maximum(2.0 * half, 1e-3),
                          (index, shapes) if shapes else None)


def replay(obstacle: Obstacle, times: np.ndarray) -> ObstacleReplay:
    """The obstacle at the time steps ``times`` (T,): present from its first recorded step to its last
    (a static obstacle throughout), at its box, with exact shapes where the box only bounds it."""
    if obstacle.set_based:
        return _occupancy_replay(obstacle, times)
    traj = obstacle.trajectory
    if obstacle.role == "static":
        valid = np.ones(len(times), bool)
        i = np.zeros(len(times), np.int64)
    else:
        i = times - int(traj.t[0])
        valid = (i >= 0) & (i < len(traj))
        i = np.clip(i, 0, len(traj) - 1)
    heading = np.nan_to_num(traj.orientation, nan=0.0)
    size, offset, turn = shape_box(obstacle.shape)
    c, s = np.cos(heading), np.sin(heading)
    centres = np.stack([traj.x + c * offset[0] - s * offset[1], traj.y + s * offset[0] + c * offset[1]], axis=-1)
    yaws = heading + turn
    exact = None
    if traj.sets or not isinstance(obstacle.shape, Rectangle):
        # every recorded state's shapes: the box grows to hold the largest, so it is exact at none
        shapes: list[tuple[Shape, ...]] = []
        half = 0.5 * size
        for j in range(len(traj)):
            sets = traj.sets.get(int(traj.t[j]))
            region = ((_set_region(obstacle.shape, sets, traj.x[j], traj.y[j], heading[j]),) if sets is not None
                      else (placed(obstacle.shape, traj.x[j], traj.y[j], heading[j]),))
            half = np.maximum(half, _half_extent(region, centres[j], yaws[j]))
            shapes.append(region)
        size = 2.0 * half
        exact = (i, shapes)
    speed = np.nan_to_num(traj.velocity[i], nan=0.0)
    return ObstacleReplay(centres[i], yaws[i], speed, valid, size, exact)
