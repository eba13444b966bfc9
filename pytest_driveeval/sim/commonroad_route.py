"""A route through a CommonRoad lanelet network to a planning problem's goal: what ``idm_expert``
follows on a CommonRoad scene (policies.commonroad_expert).

* **Where it starts:** the lanelets whose outline holds the initial position, those heading within
  90 degrees of the initial orientation first (a lanelet of the other direction is no start).
* **Where it ends:** a goal state's lanelets (``<lanelet ref>`` in its position), or the lanelets that
  hold a goal shape's centre or one of its outline's points and whose heading there lies within the
  goal's orientation interval (when it has one; 0.3 rad of slack, since a lanelet's heading varies
  across a shape).  A goal state without a position is reached anywhere: the route is then the
  start lanelet and the run-out.
* **Run-out:** beyond the goal lanelet the route goes on over successors for :data:`RUN_OUT` m, at
  each fork the one that ends heading most nearly as the lanelet before (straight on).
* **How:** Dijkstra over the lanelets; a successor costs the length of the lanelet left, a change to
  the adjacent lanelet in the same direction (left or right) :data:`CHANGE_COST` m, so that a route
  changes lanes only where it must.  The cheapest route over every start and goal lanelet wins;
  ties go to the lower lanelet ids, so the route is the same in every process.

A goal that no route reaches is a :class:`RouteError` naming the file, the planning problem and the
goal's lanelets (or shape), and why: no lanelet holds the start, none holds the goal, or the goal's
lanelets are not reached by successors and lane changes from the start.
"""
from __future__ import annotations

import heapq
import math
from dataclasses import dataclass

import numpy as np

from pytest_driveeval.core.errors import display_path
from pytest_driveeval.io.commonroad.commonroad_geometry import lanelets_at, shape_outline
from pytest_driveeval.io.commonroad.commonroad_types import CommonRoadError, CommonRoadScenario, PlanningProblem

__all__ = ["CHANGE_COST", "RUN_OUT", "Route", "RouteError", "plan_route"]

CHANGE_COST = 5.0  # m: what a lane change costs a route against driving on
RUN_OUT = 150.0  # m of successors the route keeps beyond its goal lanelet: room to look ahead and to wait in
_ORIENTATION_SLACK = 0.3  # rad


class RouteError(CommonRoadError):
    """A planning problem whose goal no route over the lanelet network reaches."""


@dataclass(frozen=True)
class Route:
    """The lanelets from start to goal (and on: the run-out), and how each is entered from the one
    before: ``"start"``, ``"successor"``, ``"left"`` or ``"right"`` (a lane change)."""

    lanelets: tuple[int, ...]
    entered: tuple[str, ...]
    goal_index: int  # position in ``lanelets`` of the goal lanelet (the last before the run-out)
    goal_lanelets: tuple[int, ...]  # every lanelet that holds the goal (empty: a goal without position)


def _heading_at(centre: np.ndarray, point: np.ndarray) -> float:
    k = int(np.argmin(np.linalg.norm(centre - point, axis=1)))
    a, b = centre[max(k - 1, 0)], centre[min(k + 1, len(centre) - 1)]
    return math.atan2(b[1] - a[1], b[0] - a[0])


def _angle_in(angle: float, start: float, end: float, slack: float) -> bool:
    return (angle - (start - slack)) % (2.0 * math.pi) <= (end - start) + 2.0 * slack


def _where(scenario: CommonRoadScenario, problem: PlanningProblem) -> str:
    return f"{display_path(scenario.path)}: planning problem {problem.id}"


def _starts(scenario: CommonRoadScenario, problem: PlanningProblem) -> list[int]:
    init = problem.initial
    point = np.array([init.x, init.y])
    found = lanelets_at(scenario, init.x, init.y)[0]
    aligned = [i for i in found if math.cos(_heading_at(scenario.lanelets[i].center, point) - init.orientation) > 0.0]
    if not aligned:
        raise RouteError(f"{_where(scenario, problem)}: no lanelet heading the ego's way holds its initial position "
                         f"({init.x:.2f}, {init.y:.2f}) (lanelets there: {found or 'none'}), so no route starts")
    return aligned


def _goal_lanelets(scenario: CommonRoadScenario, problem: PlanningProblem) -> tuple[int, ...] | None:
    """The lanelets that hold some goal state's position; None when a goal state has no position."""
    found: list[int] = []
    anywhere = False  # some lanelet holds a goal shape, whatever its heading
    for goal in problem.goals:
        if not goal.has_position:
            return None
        found += list(goal.lanelets)
        for shape in goal.shapes:
            outline = shape_outline(shape, circle_vertices=16)
            points = np.concatenate([outline.mean(axis=0, keepdims=True), outline])
            for point, ids in zip(points, lanelets_at(scenario, points[:, 0], points[:, 1])):
                anywhere |= bool(ids)
                for i in ids:
                    o = goal.orientation
                    if o is None or _angle_in(_heading_at(scenario.lanelets[i].center, point), o.start, o.end,
                                              _ORIENTATION_SLACK):
                        found.append(i)
    if not found:
        shapes = "; ".join(f"{type(s).__name__.lower()} at ({c[0]:.2f}, {c[1]:.2f})" for g in problem.goals
                           for s in g.shapes for c in [shape_outline(s, circle_vertices=16).mean(axis=0)])
        why = ("no lanelet heading within the goal's orientation interval holds it" if anywhere else
               "it lies off every lanelet: reaching it means leaving the road")
        raise RouteError(f"{_where(scenario, problem)}: the goal ({shapes}): {why}, so no route ends there")
    return tuple(sorted(set(found)))


def _length(scenario: CommonRoadScenario, ident: int) -> float:
    c = scenario.lanelets[ident].center
    return float(np.linalg.norm(np.diff(c, axis=0), axis=1).sum())


def _moves(scenario: CommonRoadScenario, ident: int):
    ll = scenario.lanelets[ident]
    for nxt in sorted(ll.successors):
        if nxt in scenario.lanelets:
            yield nxt, "successor", _length(scenario, ident)
    for side, nb in (("left", ll.adjacent_left), ("right", ll.adjacent_right)):
        if nb is not None and nb.same_direction and nb.id in scenario.lanelets:
            yield nb.id, side, CHANGE_COST


def _end_heading(scenario: CommonRoadScenario, ident: int) -> float:
    c = scenario.lanelets[ident].center
    return math.atan2(c[-1, 1] - c[-2, 1], c[-1, 0] - c[-2, 0])


def _run_out(scenario: CommonRoadScenario, last: int) -> tuple[list[int], list[str]]:
    ids, how, driven = [], [], 0.0
    while driven < RUN_OUT:
        nxt = [s for s in sorted(scenario.lanelets[last].successors) if s in scenario.lanelets and s not in ids]
        if not nxt:
            break
        here = _end_heading(scenario, last)
        last = min(nxt, key=lambda s: abs(math.remainder(_end_heading(scenario, s) - here, 2.0 * math.pi)))
        ids.append(last)
        how.append("successor")
        driven += _length(scenario, last)
    return ids, how


def plan_route(scenario: CommonRoadScenario, problem: PlanningProblem) -> Route:
    """The cheapest route from the problem's start to its goal (see the module's doc); a RouteError
    saying why when there is none."""
    starts = _starts(scenario, problem)
    goals = _goal_lanelets(scenario, problem)
    if goals is None:
        more, how = _run_out(scenario, starts[0])
        return Route((starts[0], *more), ("start", *how), 0, ())
    best: dict[int, float] = {}
    back: dict[int, tuple[int, str]] = {}
    queue = [(0.0, s, s, "start") for s in starts]
    heapq.heapify(queue)
    reached = None
    while queue:
        cost, node, came, how = heapq.heappop(queue)
        if node in best:
            continue
        best[node] = cost
        back[node] = (came, how)
        if node in goals:
            reached = node
            break
        for nxt, kind, step in _moves(scenario, node):
            if nxt not in best:
                heapq.heappush(queue, (cost + step, nxt, node, kind))
    if reached is None:
        raise RouteError(f"{_where(scenario, problem)}: the goal's lanelets {list(goals)} are not reached from the "
                         f"start lanelet(s) {starts} by successors and lane changes (the route search reached "
                         f"{len(best)} lanelet(s))")
    ids, kinds = [reached], []
    while back[ids[-1]][1] != "start":
        came, how = back[ids[-1]]
        kinds.append(how)
        ids.append(came)
    ids.reverse()
    kinds = ["start", *reversed(kinds)]
    more, how = _run_out(scenario, reached)
    return Route((*ids, *more), (*kinds, *how), len(ids) - 1, goals)
