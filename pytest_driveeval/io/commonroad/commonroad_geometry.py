"""CommonRoad's goal test, road test and obstacle outlines on what ``pytest_driveeval.io.commonroad.commonroad`` reads.

The semantics follow commonroad-io's ``GoalRegion.is_reached`` (checked against it by
tests/io/test_commonroad_oracle.py): a planning problem's goal is reached when any of its goal states
is; a goal state when every constraint it gives holds.  Intervals include both ends (time steps,
velocity); the orientation interval is read on the circle, from its start counter-clockwise to its
end, so [-3.0, 3.5] holds pi and -2.9 wraps to 3.38; the position holds when the point lies in or on
any of the shapes (rectangle, circle, polygon) or any referenced lanelet's outline.  commonroad-io
asserts an orientation interval narrower than pi; here any width below 2 pi works the same way.
"""
from __future__ import annotations

import math

import numpy as np

from ...geometry import points_in_polygon
from ...geometry.polygons import outline_distance
from .commonroad_types import (Circle, CommonRoadScenario, GoalState, Obstacle, PlanningProblem, Polygon, Rectangle,
                               Shape)

__all__ = ["goal_reached", "in_shape", "in_outline", "on_road", "lanelets_at", "obstacle_outline", "shape_outline",
           "outlines_meet", "outline_meets_shape", "ROAD_TOLERANCE"]

# Points this close to an outline count as on it: commonroad-io's shapely test includes the boundary,
# which a crossing-number test only half does.
ON_EDGE = 1e-9
#: How far outside every lanelet a point may lie and still be on the road, m.  Lanelets that share a
#: bound in the file often differ in its last digits, leaving hairline gaps of a few mm² between them;
#: the drivability checker closes them with a 1 mm buffer (create_road_polygons(buffer=..., buf_width=1e-3)),
#: and a corner that falls in one must not be off the road for us while it is on it for a reference.
ROAD_TOLERANCE = 1e-3


def in_outline(x: np.ndarray, y: np.ndarray, outline: np.ndarray, tolerance: float = ON_EDGE) -> np.ndarray:
    """Whether each point lies inside the closed outline (K, 2) or within ``tolerance`` of it."""
    x, y = np.atleast_1d(np.asarray(x, dtype=np.float64)), np.atleast_1d(np.asarray(y, dtype=np.float64))
    inside = points_in_polygon(x, y, outline)
    if not inside.all():
        rest = ~inside
        inside[rest] = outline_distance(np.stack([x[rest], y[rest]], axis=1), outline) <= tolerance
    return inside


def _segments_cross(a0: np.ndarray, a1: np.ndarray, b0: np.ndarray, b1: np.ndarray) -> bool:
    """Whether any segment a0[i]-a1[i] (I, 2) meets any b0[j]-b1[j] (J, 2), touching included."""
    def side(p, q, r):  # sign of the turn p -> q -> r, for every pair
        return np.sign((q[..., 0] - p[..., 0]) * (r[..., 1] - p[..., 1])
                       - (q[..., 1] - p[..., 1]) * (r[..., 0] - p[..., 0]))
    p, q = a0[:, None], a1[:, None]
    r, t = b0[None], b1[None]
    return bool(np.any((side(p, q, r) * side(p, q, t) <= 0) & (side(r, t, p) * side(r, t, q) <= 0)
                       & (np.minimum(p[..., 0], q[..., 0]) <= np.maximum(r[..., 0], t[..., 0]))
                       & (np.minimum(r[..., 0], t[..., 0]) <= np.maximum(p[..., 0], q[..., 0]))
                       & (np.minimum(p[..., 1], q[..., 1]) <= np.maximum(r[..., 1], t[..., 1]))
                       & (np.minimum(r[..., 1], t[..., 1]) <= np.maximum(p[..., 1], q[..., 1]))))


def outlines_meet(a: np.ndarray, b: np.ndarray) -> bool:
    """Whether two closed outlines (K, 2), convex or not, share a point (touching counts, as shapely's
    ``intersects`` and the drivability checker's collision test)."""
    if in_outline(a[:, 0], a[:, 1], b).any() or in_outline(b[:, 0], b[:, 1], a).any():
        return True
    return _segments_cross(a, np.roll(a, -1, axis=0), b, np.roll(b, -1, axis=0))


def outline_meets_shape(outline: np.ndarray, shape: Shape) -> bool:
    """Whether the closed outline (K, 2) shares a point with a world-frame shape (touching counts)."""
    if isinstance(shape, Circle):
        centre = np.asarray(shape.center, dtype=np.float64)
        return bool(in_outline(centre[:1], centre[1:], outline)[0]
                    or outline_distance(centre[None], outline)[0] <= shape.radius + ON_EDGE)
    return outlines_meet(outline, shape_outline(shape))


def in_shape(x: np.ndarray, y: np.ndarray, shape: Shape) -> np.ndarray:
    """Whether each point lies inside or on the shape (its center and orientation as given)."""
    x, y = np.atleast_1d(np.asarray(x, dtype=np.float64)), np.atleast_1d(np.asarray(y, dtype=np.float64))
    if isinstance(shape, Rectangle):
        dx, dy = x - shape.center[0], y - shape.center[1]
        c, s = math.cos(shape.orientation), math.sin(shape.orientation)
        along, across = c * dx + s * dy, -s * dx + c * dy
        return (np.abs(along) <= 0.5 * shape.length + ON_EDGE) & (np.abs(across) <= 0.5 * shape.width + ON_EDGE)
    if isinstance(shape, Circle):
        return np.hypot(x - shape.center[0], y - shape.center[1]) <= shape.radius + ON_EDGE
    if isinstance(shape, Polygon):
        return in_outline(x, y, shape.vertices)
    raise TypeError(f"not a CommonRoad shape: {type(shape).__name__}")


def _in_angle_interval(angle: np.ndarray, start: float, end: float) -> np.ndarray:
    return np.mod(angle - start, 2.0 * math.pi) <= end - start


def _goal_state_reached(goal: GoalState, x, y, orientation, velocity, time_step) -> np.ndarray:
    reached = np.ones(np.broadcast(x, y, orientation, velocity, time_step).shape or (1,), dtype=bool)
    if goal.time is not None:
        reached &= goal.time.contains(np.asarray(time_step))
    if goal.velocity is not None:
        reached &= goal.velocity.contains(np.asarray(velocity, dtype=np.float64))
    if goal.orientation is not None:
        reached &= _in_angle_interval(np.asarray(orientation, dtype=np.float64),
                                      goal.orientation.start, goal.orientation.end)
    if goal.has_position and reached.any():
        xs, ys = np.broadcast_to(x, reached.shape).ravel(), np.broadcast_to(y, reached.shape).ravel()
        inside = np.zeros(reached.size, dtype=bool)
        for shape in goal.shapes:
            inside |= in_shape(xs, ys, shape)
        for outline in goal.lanelet_polygons:
            inside |= in_outline(xs, ys, outline)
        reached &= inside.reshape(reached.shape)
    return reached


def goal_reached(goal: GoalState | PlanningProblem, x, y, orientation, velocity, time_step):
    """Whether states (scalars or numpy arrays that broadcast) reach ``goal``: a goal state, or a planning
    problem (any of its goal states).  A bool for scalars, else a bool array of the broadcast shape.
    A constraint the goal gives needs its value: nan fails it."""
    goals = goal.goals if isinstance(goal, PlanningProblem) else (goal,)
    shape = np.broadcast(x, y, orientation, velocity, time_step).shape
    reached = np.zeros(shape or (1,), dtype=bool)
    for g in goals:
        reached |= _goal_state_reached(g, x, y, orientation, velocity, time_step)
    return bool(reached[0]) if not shape else reached


def on_road(scenario: CommonRoadScenario, x, y, tolerance: float = ON_EDGE) -> np.ndarray:
    """Whether each point lies in some lanelet's outline or within ``tolerance`` of one (off-road:
    outside every lanelet; the episodes' corner rule gives :data:`ROAD_TOLERANCE`)."""
    x, y = np.atleast_1d(np.asarray(x, dtype=np.float64)), np.atleast_1d(np.asarray(y, dtype=np.float64))
    out = np.zeros(np.broadcast(x, y).shape, dtype=bool)
    xs, ys = np.broadcast_to(x, out.shape).ravel(), np.broadcast_to(y, out.shape).ravel()
    flat = out.ravel()
    for lanelet in scenario.lanelets.values():
        outline = lanelet.polygon
        lo, hi = outline.min(axis=0) - tolerance, outline.max(axis=0) + tolerance
        near = ~flat & (xs >= lo[0]) & (xs <= hi[0]) & (ys >= lo[1]) & (ys <= hi[1])
        if near.any():
            flat[near] = in_outline(xs[near], ys[near], outline, tolerance)
    return flat.reshape(out.shape)


def lanelets_at(scenario: CommonRoadScenario, x, y) -> list[list[int]]:
    """For each point, the ids of the lanelets whose outline holds it (in or on), in the file's order;
    commonroad-io's ``LaneletNetwork.find_lanelet_by_position``."""
    xs, ys = np.atleast_1d(np.asarray(x, dtype=np.float64)), np.atleast_1d(np.asarray(y, dtype=np.float64))
    xs, ys = np.broadcast_arrays(xs, ys)
    xs, ys = xs.ravel(), ys.ravel()
    found: list[list[int]] = [[] for _ in range(len(xs))]
    for lanelet in scenario.lanelets.values():
        outline = lanelet.polygon
        lo, hi = outline.min(axis=0) - ON_EDGE, outline.max(axis=0) + ON_EDGE
        near = np.flatnonzero((xs >= lo[0]) & (xs <= hi[0]) & (ys >= lo[1]) & (ys <= hi[1]))
        if len(near):
            for i in near[in_outline(xs[near], ys[near], outline)]:
                found[i].append(lanelet.id)
    return found


def shape_outline(shape: Shape, circle_vertices: int = 32) -> np.ndarray:
    """(K, 2) outline of a shape in its own frame (placed by its center and orientation): a rectangle's
    4 corners counter-clockwise from rear right, a circle's ``circle_vertices``-gon through its rim, a
    polygon's vertices."""
    if isinstance(shape, Rectangle):
        hl, hw = 0.5 * shape.length, 0.5 * shape.width
        local = np.array([[-hl, -hw], [hl, -hw], [hl, hw], [-hl, hw]])
        c, s = math.cos(shape.orientation), math.sin(shape.orientation)
        return local @ np.array([[c, s], [-s, c]]) + shape.center
    if isinstance(shape, Circle):
        a = np.linspace(0.0, 2.0 * math.pi, circle_vertices, endpoint=False)
        return shape.center + shape.radius * np.stack([np.cos(a), np.sin(a)], axis=1)
    return shape.vertices


def obstacle_outline(obstacle: Obstacle, time_step: int, circle_vertices: int = 32) -> np.ndarray:
    """(K, 2) outline of the obstacle's shape at its state of ``time_step``: the shape (placed by its own
    center and orientation, zero for the files seen) turned by the state's orientation and moved to its
    position.  A rectangle gives its 4 corners counter-clockwise from rear right; a circle a
    ``circle_vertices``-gon through its rim."""
    state = obstacle.trajectory.at(time_step)
    local = shape_outline(obstacle.shape, circle_vertices)
    heading = 0.0 if math.isnan(state.orientation) else state.orientation
    c, s = math.cos(heading), math.sin(heading)
    return local @ np.array([[c, s], [-s, c]]) + np.array([state.x, state.y])
