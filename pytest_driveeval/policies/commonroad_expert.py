"""``idm_expert`` on a CommonRoad scene: route over the lanelets to the planning problem's goal, follow
the route's centre line by IDM behind the obstacles on it, change lanes where the route does, steer
by Stanley's law.  :class:`~pytest_driveeval.policies.idm_expert.IDMExpert` hands CommonRoad
episodes here; like it, this acts on every episode at once and each episode's action is a function of its
state alone (so of its seed).

* **Route** (sim.commonroad_route): lanelets joined by successors form a *corridor*, one centre line;
  a lane change on the route starts the next corridor, beside the lanelet it leaves.  An episode is on
  the last corridor whose lane holds its centre (or the nearest one).
* **Lane change:** on the lanelet the route leaves sideways the ego changes once a MOBIL-like gap
  check passes (the blueprints' expert's: no vehicle on the target corridor makes the ego, or is made
  by it, brake harder than ``max_imposed_braking``, nor is within ``min_gap``); once its box overlaps
  the target lane it finishes the change.  Blocked, it stops ``merge_room`` m before that lanelet's
  end, where a change from standstill still fits.
* **Speed:** IDM (the benchmark's traffic constants) towards a desired speed that brings the ego's
  centre to the middle of the goal's stretch of the route at the middle of the goal's time window,
  within the goal's velocity interval and at most the lanelet's speed limit (else ``cruise_factor``
  times the faster of the initial speed and ``min_cruise``).  Leaders: the nearest obstacle whose
  box overlaps the followed lane ahead, or the lane being left; and two standing walls: the far end
  of the goal's stretch while the time window has not opened (the goal is judged on the centre, so
  the ego waits inside it), and the goal's middle when the goal asks for (almost) standstill.
* **Steering:** Stanley's law from the front axle onto the followed corridor's centre line (see
  :meth:`CommonRoadExpert._steer` for why not the blueprints' pure pursuit).
"""
from __future__ import annotations

import math
import weakref
from dataclasses import dataclass
from typing import Any

import numpy as np

from pytest_driveeval.policies.control_baselines import action_bounds
from pytest_driveeval.sim.agents import TrafficModel, change_blocked, idm_free, idm_interaction
from pytest_driveeval.sim.blueprints.road import Lane, Road
from pytest_driveeval.sim.commonroad_route import Route, plan_route

__all__ = ["CommonRoadExpert", "CorridorPlan", "corridor_plan"]


@dataclass(frozen=True, eq=False)
class CorridorPlan:
    """What the expert works out once per scene: its route as corridors and the goal along it."""

    route: Route
    paths: Road  # one lane per corridor
    offset: np.ndarray  # (C,) route position (m) where each corridor's centre line starts
    change_from: np.ndarray  # (C,) corridor-local start of the lanelet each corridor leaves sideways (inf: none)
    change_end: np.ndarray  # (C,) ... and its end
    limit_from: np.ndarray  # (C, K): arclength where each of a corridor's lanelets starts (inf: padding)
    limit: np.ndarray  # (C, K): that lanelet's speed limit, m/s (inf: none given)
    goal_span: tuple[float, float]  # route positions between which the goal lies
    goal_steps: tuple[float, float]  # the goal's time window, in steps after the initial state
    goal_speed: tuple[float, float]  # its velocity interval
    cruise: float  # m/s where no speed limit is given


def _centre(scenario: Any, ident: int) -> np.ndarray:
    c = scenario.lanelets[ident].center
    keep = np.concatenate([[True], np.linalg.norm(np.diff(c, axis=0), axis=1) > 1e-6])
    return c[keep]


def _length(c: np.ndarray) -> float:
    return float(np.linalg.norm(np.diff(c, axis=0), axis=1).sum())


def corridor_plan(scene: Any, cruise_factor: float = 1.2, min_cruise: float = 8.0) -> CorridorPlan:
    """The corridors of the scene's route (sim.commonroad_route; a RouteError when there is none)."""
    scenario, problem = scene.scenario, scene.problem
    route = plan_route(scenario, problem)
    corridors: list[list[int]] = []
    starts: list[float] = []  # route position of each lanelet's start
    for i, (ident, how) in enumerate(zip(route.lanelets, route.entered)):
        if how == "successor":
            corridors[-1].append(ident)
            prev = _length(_centre(scenario, route.lanelets[i - 1]))
            starts.append(starts[-1] + prev)
        else:  # the start, or a lane change: alongside the lanelet before
            corridors.append([ident])
            starts.append(starts[-1] if starts else 0.0)
    lanes, offset, change_from, change_end, limit_s, limit_v = [], [], [], [], [], []
    at = 0
    for c, ids in enumerate(corridors):
        line = np.concatenate([_centre(scenario, i)[(0 if k == 0 else 1):] for k, i in enumerate(ids)])
        widths = [np.median(np.linalg.norm(scenario.lanelets[i].left - scenario.lanelets[i].right, axis=1))
                  for i in ids]
        lanes.append(Lane(line, float(np.median(widths)), "+".join(map(str, ids))))
        offset.append(starts[at])
        lengths = [_length(_centre(scenario, i)) for i in ids]
        begin = np.concatenate([[0.0], np.cumsum(lengths)[:-1]])
        limit_s.append(begin)
        limit_v.append(np.array([scenario.lanelets[i].speed_limit or np.inf for i in ids]))
        last = c < len(corridors) - 1
        change_from.append(begin[-1] if last else np.inf)
        change_end.append(begin[-1] + lengths[-1] if last else np.inf)
        at += len(ids)
    paths = Road(tuple(lanes), resolution=5.0)  # for projections only: a coarse raster, never read
    span = _goal_span(scene, route, corridors, paths, np.array(offset), starts)
    times = [g.time for g in problem.goals if g.time is not None]
    t0 = problem.initial.time_step
    steps = ((min(t.start for t in times) - t0, max(t.end for t in times) - t0) if len(times) == len(problem.goals)
             else (0.0, math.inf))
    speeds = [g.velocity for g in problem.goals if g.velocity is not None]
    speed = ((min(v.start for v in speeds), max(v.end for v in speeds)) if len(speeds) == len(problem.goals)
             else (0.0, math.inf))
    cruise = cruise_factor * max(problem.initial.velocity, min_cruise)
    k = max(len(v) for v in limit_v)
    limit_from = np.array([np.pad(a, (0, k - len(a)), constant_values=np.inf) for a in limit_s])
    limit = np.array([np.pad(a, (0, k - len(a)), constant_values=np.inf) for a in limit_v])
    return CorridorPlan(route, paths, np.array(offset), np.array(change_from), np.array(change_end),
                        limit_from, limit, span, steps, speed, cruise)


def _goal_span(scene: Any, route: Route, corridors: list[list[int]], paths: Road, offset: np.ndarray,
               starts: list[float]) -> tuple[float, float]:
    """Route positions between which the goal's position lies: the goal lanelet, narrowed to the goal
    shapes' extent along it where the goal is given by shapes."""
    if not route.goal_lanelets:
        return -math.inf, math.inf
    goal = route.lanelets[route.goal_index]
    c = next(k for k, ids in enumerate(corridors) if goal in ids)
    lo = starts[route.goal_index]
    hi = lo + _length(_centre(scene.scenario, goal))
    points = [o for o in scene.goal_outlines if len(o)]
    shapes = [g for g in scene.problem.goals if g.shapes]
    if shapes and points:
        s = paths.project(np.concatenate(points)).s[:, c] + offset[c]
        lo, hi = max(lo, float(s.min())), min(hi, float(s.max()))
        if lo > hi:  # the shape lies beside the lanelet's stretch: keep the shape's own
            lo, hi = float(s.min()), float(s.max())
    return lo, hi


def _pick(values: np.ndarray, column: np.ndarray) -> np.ndarray:
    """(E, A, C) -> (E, A): each episode's column."""
    return np.take_along_axis(values, column[:, None, None], axis=2)[..., 0]


class CommonRoadExpert:
    """The CommonRoad half of ``idm_expert`` (see the module's doc)."""

    def __init__(self, *, steer_gain: float = 2.0, min_steer_speed: float = 1.0, merge_room: float = 8.0,
                 stop_in_goal_below: float = 0.5, goal_margin: float = 1.0, model: TrafficModel | None = None) -> None:
        self.steer_gain = steer_gain
        self.min_steer_speed = min_steer_speed
        self.merge_room = merge_room
        self.stop_in_goal_below = stop_in_goal_below
        self.goal_margin = goal_margin
        self.model = model or TrafficModel(time_headway=1.0)
        self._plans: weakref.WeakKeyDictionary[Any, CorridorPlan] = weakref.WeakKeyDictionary()

    def plan(self, scene: Any) -> CorridorPlan:
        plan = self._plans.get(scene)
        if plan is None:
            plan = self._plans[scene] = corridor_plan(scene)
        return plan

    def act_on_episodes(self, episodes: Any) -> np.ndarray:
        scene = episodes.blueprint
        plan = self.plan(scene)
        m = self.model
        paths = plan.paths
        rows = np.arange(episodes.num_episodes)
        size = episodes.size  # (A, 2)
        proj = paths.project(episodes.xy)  # (E, A, C)
        rel = episodes.yaw[..., None] - proj.heading
        along, across = np.abs(np.cos(rel)), np.abs(np.sin(rel))
        hl, hw = 0.5 * size[None, :, 0, None], 0.5 * size[None, :, 1, None]
        half_long = along * hl + across * hw
        inside = (proj.s > -hl) & (proj.s < paths.lengths + hl)
        overlaps = (np.abs(proj.d) - 0.5 * paths.widths - (across * hl + along * hw) < 0.0) & inside
        speed_along = episodes.speed[..., None] * np.cos(rel)
        others = episodes.valid.copy()
        others[:, 0] = False
        v = episodes.speed[:, 0]

        # Which corridor: the last whose lane holds the ego's centre, else the nearest.
        ego_d = np.abs(proj.d[:, 0])
        holds = (ego_d <= 0.5 * paths.widths) & inside[:, 0] & (np.cos(rel[:, 0]) > 0.0)
        n_c = paths.num_lanes
        last_holding = n_c - 1 - np.argmax(holds[:, ::-1], axis=1)
        current = np.where(holds.any(axis=1), last_holding, np.argmin(np.where(inside[:, 0], ego_d, np.inf), axis=1))
        s_cur = proj.s[rows, 0, current]
        target = np.minimum(current + 1, n_c - 1)
        wants = (current < n_c - 1) & (s_cur >= plan.change_from[current] - hl[0, 0, 0])

        # The gap check on the target corridor, against every obstacle overlapping it.
        v0 = self._desired_speed(episodes, plan, current, s_cur)
        s_t, half_t, v_t = _pick(proj.s, target), _pick(half_long, target), _pick(speed_along, target)
        there = others & _pick(overlaps, target)
        blocks, _, _ = change_blocked(m, s_t, half_t, v_t, v[:, None], v0, np.maximum(v_t, 1.0), there)
        committed = _pick(overlaps, target)[:, 0]
        changing = wants & (~blocks.any(axis=1) | committed)
        path = np.where(changing, target, current)

        interaction = np.zeros(len(rows))
        for p in (path, current):
            s_p, half_p = _pick(proj.s, p), _pick(half_long, p)
            ahead = s_p - s_p[:, :1]
            lead = others & _pick(overlaps, p) & (ahead > 0.0)
            gap_p = np.where(lead, ahead - half_p - half_p[:, :1], np.inf)
            k = np.argmin(gap_p, axis=1)
            found = lead[rows, k]
            lead_v = np.maximum(_pick(speed_along, p)[rows, k], 0.0)
            interaction = np.maximum(interaction,
                                     np.where(found, idm_interaction(m, v, lead_v, gap_p[rows, k]), 0.0))
        interaction += self._walls(episodes, plan, current, s_cur, wants & ~changing, v)
        with np.errstate(divide="ignore", invalid="ignore"):
            free = np.where(v0 > 0.0, idm_free(m, v, np.maximum(v0, 1e-9)), -m.comfort_decel)
        accel = free - m.max_accel * interaction
        steer = self._steer(episodes, paths, path)
        low, high = action_bounds(episodes)
        return np.clip(np.stack([accel, steer], axis=1), low, high)

    def _desired_speed(self, episodes: Any, plan: CorridorPlan, current: np.ndarray, s_cur: np.ndarray) -> np.ndarray:
        """Timed to reach the goal's middle at its window's middle; within the goal's velocity interval
        and the lanelet's speed limit (else the cruise speed)."""
        lanelet = np.maximum(np.count_nonzero(s_cur[:, None] >= plan.limit_from[current], axis=1) - 1, 0)
        cap = plan.limit[current, lanelet]
        cap = np.where(np.isfinite(cap), cap, plan.cruise)
        pos = plan.offset[current] + s_cur
        g_lo, g_hi = plan.goal_span
        t_lo, t_hi = plan.goal_steps
        dt = episodes.blueprint.dt
        if math.isfinite(g_lo) and t_lo > 0.0:
            # As fast as keeps the centre short of the goal's far end until the window opens: a slow ego
            # is run into by the recording's cars behind it, which do not react.
            left_s = (t_lo + 1.0 - episodes.steps) * dt
            timed = np.where(left_s > dt, (g_hi - self.goal_margin - pos) / np.maximum(left_s, dt), cap)
            v0 = np.minimum(np.maximum(timed, 0.0), cap)
        else:
            v0 = cap
        v_lo, v_hi = plan.goal_speed
        standstill = v_hi - v_lo < self.stop_in_goal_below
        if not standstill:
            margin = 0.1 * (v_hi - v_lo) if math.isfinite(v_hi) else 0.0
            v0 = np.clip(v0, v_lo + margin, v_hi - margin)
        if math.isfinite(g_hi):
            # The goal is judged on the box centre: before the window opens (or for a goal of standstill)
            # the centre must be able to stop short of the goal's far end (its middle) braking comfortably.
            stop_at = 0.5 * (g_lo + g_hi) if standstill else g_hi - self.goal_margin
            # ... where keeping its speed would bring it there before the window opens
            early = pos + episodes.speed[:, 0] * np.maximum(t_lo - episodes.steps, 0.0) * dt >= stop_at
            hold = ((episodes.steps < t_lo) & early) | standstill
            room = np.maximum(stop_at - pos, 0.0)
            v0 = np.where(hold & (pos < stop_at), np.minimum(v0, np.sqrt(2.0 * self.model.comfort_decel * room)), v0)
        return np.maximum(v0, 0.5 if not standstill else 0.0)  # 0 only where standing is the goal

    def _walls(self, episodes: Any, plan: CorridorPlan, current: np.ndarray, s_cur: np.ndarray, blocked: np.ndarray,
               v: np.ndarray) -> np.ndarray:
        """IDM's interaction with standing points: the lane-change zone's end while blocked, the route's end."""
        m = self.model
        hl = 0.5 * float(episodes.size[0, 0])
        pos = plan.offset[current] + s_cur
        total = np.zeros(len(v))
        end = plan.change_end[current] - self.merge_room - s_cur - hl
        total += np.where(blocked, idm_interaction(m, v, 0.0, end), 0.0)
        route_end = plan.offset[-1] + plan.paths.lengths[-1]
        total += idm_interaction(m, v, 0.0, route_end - pos - hl)
        return total

    def _steer(self, episodes: Any, paths: Road, path: np.ndarray) -> np.ndarray:
        """Stanley's law from the front axle: the heading error to the path plus ``atan(gain * offset /
        speed)``.  Pure pursuit (the blueprints' expert) corrects a heading error only through its
        lookahead point, too late where a problem starts the ego 0.6 rad off its lane, as
        test_reading_complex_tl's does."""
        wheelbase = episodes.blueprint.params.ego_wheelbase
        yaw, v = episodes.yaw[:, 0], episodes.speed[:, 0]
        front = episodes.xy[:, 0] + 0.5 * wheelbase * np.stack([np.cos(yaw), np.sin(yaw)], axis=-1)
        proj = paths.project(front)
        rows = np.arange(len(path))
        error = np.remainder(proj.heading[rows, path] - yaw + np.pi, 2.0 * np.pi) - np.pi
        return error + np.arctan(self.steer_gain * -proj.d[rows, path] / np.maximum(v, self.min_steer_speed))
