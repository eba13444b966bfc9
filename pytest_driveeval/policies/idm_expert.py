"""The ``idm_expert`` baseline of the policy benchmark: a lane-following IDM
expert that reads the simulator's lanes and traffic (no learning), for every
episode at once.

It changes towards the goal's lane when a MOBIL-like gap check passes (and
drops back or waits where a change from standstill still fits), follows a
left-turn route through the intersection yielding at a stop line while
crossing traffic is within a time gap, takes its speed from the simulator's
own IDM and steers by pure pursuit.  Like the other baselines it acts on the
episodes (``act_on_episodes``), and its action depends on each episode's
state alone.
"""
from __future__ import annotations

import weakref
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from pytest_driveeval.policies.control_baselines import action_bounds
from pytest_driveeval.sim.agents import TrafficModel, change_blocked, idm_free, idm_interaction
from pytest_driveeval.sim.blueprints.road import Lane, Road

__all__ = ["IDMExpert"]


# --------------------------------------------------------------------------- the expert's road knowledge

@dataclass(frozen=True, eq=False)
class _Plan:
    """What the expert works out once per blueprint: the paths it can follow and where they cross traffic.

    ``paths`` holds the road's lanes (same indices, ``L`` of them) and then one
    turn route per pair of crossing lanes, ``P`` paths in all.
    """

    paths: Road
    toward: np.ndarray  # (L, L): the lane beside a on the way to b by lane changes; a at b; -1: unreachable
    route: np.ndarray  # (L, L): the path turning from lane a into lane b, -1: none
    zone_in: np.ndarray  # (P, L): start of the stretch of lane k the ego's box covers on path p (nan: none)
    zone_out: np.ndarray  # (P, L): ... and its end
    leave: np.ndarray  # (P, L): arclength on p where the ego's centre is clear of lane k
    stop: np.ndarray  # (P,): arclength on p where the ego's centre waits for crossing traffic (inf: no line)
    turn_end: np.ndarray  # (P,): arclength on p where its turn ends (-inf for lanes)
    merge_room: float  # m before a lane end where the ego waits: room to change lanes from standstill


def _lane_steps(road: Road) -> np.ndarray:
    n = road.num_lanes
    toward = np.full((n, n), -1, np.int64)
    for a in range(n):
        toward[a, a] = a
        for side in (road.left, road.right):
            b = side[a]
            while b >= 0 and toward[a, b] < 0:
                toward[a, b] = side[a]
                b = side[b]
    return toward


def _cross(a: np.ndarray, b: np.ndarray) -> float:
    return float(a[0] * b[1] - a[1] * b[0])


def _turn_route(a: Lane, b: Lane, radius: float) -> tuple[np.ndarray, float, float] | None:
    """The centre line from lane ``a`` into lane ``b`` where their centre lines cross: ``a``,
    then a circular arc of ``radius`` tangent to both, then ``b``; with the arc's (start,
    end) arclength along it.  None when they do not cross far enough inside both lanes."""
    p0, p1 = a.centre[-2], a.centre[-1]
    q0, q1 = b.centre[0], b.centre[1]
    len_a, len_b = float(np.linalg.norm(p1 - p0)), float(np.linalg.norm(q1 - q0))
    u1, u2 = (p1 - p0) / len_a, (q1 - q0) / len_b
    c = _cross(u1, u2)
    if abs(c) < 0.5:  # (anti)parallel lanes are joined by lane changes, not turns
        return None
    # p0 + t u1 = q0 + w u2
    t, w = _cross(q0 - p0, u2) / c, _cross(q0 - p0, u1) / c
    angle = float(np.arctan2(c, u1 @ u2))
    tangent = radius * np.tan(0.5 * abs(angle))
    if not (tangent < t < len_a and 0.0 < w < len_b - tangent):
        return None
    start, end = p0 + (t - tangent) * u1, q0 + (w + tangent) * u2
    normal = np.sign(angle) * np.array([-u1[1], u1[0]])
    centre = start + radius * normal
    phi0 = np.arctan2(*(start - centre)[::-1])
    phi = phi0 + np.linspace(0.0, angle, max(4, int(np.ceil(abs(angle) * radius / 0.5))) + 1)
    arc = centre + radius * np.stack([np.cos(phi), np.sin(phi)], axis=1)
    arc[0], arc[-1] = start, end
    line = np.concatenate([a.centre[:-1], arc, b.centre[1:]])
    arc_start = a.length - (len_a - t + tangent)
    return line, arc_start, arc_start + abs(angle) * radius


def _conflicts(road: Road, route: Road, p: int, a: int, b: int, turn_end: float, size: np.ndarray,
               margin: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """Where the ego's box, driven along path ``p`` from lane ``a`` into ``b``, overlaps each other lane:
    the stretch of that lane it covers (widened by half a car length, whatever the angle), the path's
    arclength where the ego's centre has left it, and the stop line (``margin`` before the first overlap)."""
    hl, hw = 0.5 * size
    s = np.arange(0.0, route.lengths[p], 0.25)
    xy, heading = route.pose(np.full(len(s), p), s, 0.0)
    proj = road.project(xy)  # (S, L)
    rel = heading[:, None] - proj.heading
    extent = np.abs(np.sin(rel)) * hl + np.abs(np.cos(rel)) * hw
    touch = (np.abs(proj.d) - 0.5 * road.widths < extent) & (proj.s > -hl) & (proj.s < road.lengths + hl)
    touch[:, a] = False
    # On the lane it turns into, the conflict is the joining; after the turn its traffic is ahead or behind.
    touch[s > turn_end, b] = False
    n = road.num_lanes
    zone_in, zone_out, leave = np.full(n, np.nan), np.full(n, np.nan), np.full(n, np.nan)
    first = np.inf
    for k in np.flatnonzero(touch.any(axis=0)):
        on = touch[:, k]
        zone_in[k], zone_out[k] = proj.s[on, k].min() - hl, proj.s[on, k].max() + hl
        leave[k] = s[on].max()
        first = min(first, float(s[on].min()))
    return zone_in, zone_out, leave, first - margin


def _plan(blueprint: Any, turn_radius: float, stop_margin: float) -> _Plan:
    road, params = blueprint.road, blueprint.params
    size = np.array([params.vehicle_length, params.vehicle_width])
    n = road.num_lanes
    lanes, route, turn_end = list(road.lanes), np.full((n, n), -1, np.int64), [-np.inf] * n
    toward = _lane_steps(road)
    pairs = []
    for a in range(n):
        for b in range(n):
            made = None if toward[a, b] >= 0 else _turn_route(road.lanes[a], road.lanes[b], turn_radius)
            if made is not None:
                route[a, b] = len(lanes)
                lanes.append(Lane(made[0], road.lanes[a].width, f"{road.lanes[a].name}->{road.lanes[b].name}"))
                turn_end.append(made[2])
                pairs.append((a, b))
    # Only its projection is used: a coarse raster keeps the drivable grid, never read, cheap.
    paths = Road(tuple(lanes), resolution=5.0)
    zone_in, zone_out, leave = (np.full((paths.num_lanes, n), np.nan) for _ in range(3))
    stop = np.full(paths.num_lanes, np.inf)
    for p, (a, b) in enumerate(pairs, start=n):
        zone_in[p], zone_out[p], leave[p], stop[p] = _conflicts(road, paths, p, a, b, turn_end[p], size,
                                                                stop_margin)
    # Changing one lane from standstill: two arcs at full lock, plus the car's length to clear the end.
    spacing = float(np.median(road.widths))
    lock = params.ego_wheelbase / np.tan(params.ego_max_steer)
    room = 2.0 * np.sqrt(max(lock * spacing - 0.25 * spacing ** 2, 0.0)) + params.vehicle_length
    return _Plan(paths, toward, route, zone_in, zone_out, leave, stop, np.array(turn_end), float(room))


def _on(values: np.ndarray, path: np.ndarray) -> np.ndarray:
    """(E, A, P) -> (E, A): each episode's values on its own path (E,)."""
    return np.take_along_axis(values, path[:, None, None], axis=2)[..., 0]


def _first(mask: np.ndarray, key: np.ndarray, *fields: np.ndarray) -> tuple[np.ndarray, ...]:
    """(E, A) -> (E,): per episode, the fields of the agent with the smallest ``key`` where ``mask``;
    ``found`` first, then the fields (whatever agent 0 has where nothing qualifies)."""
    k = np.argmin(np.where(mask, key, np.inf), axis=1)[:, None]
    found = np.take_along_axis(mask, k, axis=1)[:, 0]
    return (found, *(np.take_along_axis(f, k, axis=1)[:, 0] for f in fields))


class _View(NamedTuple):
    """Every agent on every path, (E, A, P), as the expert sees it."""

    s: np.ndarray  # arclength along the path
    d: np.ndarray  # lateral offset
    half_long: np.ndarray  # the box's half extent along the path
    overlaps: np.ndarray  # the box overlaps the path's ribbon (within its length)
    along: np.ndarray  # speed along the path
    aligned: np.ndarray  # heading within 90 degrees of the path's, within its length


class _Choice(NamedTuple):
    """Which path each episode's ego follows and why, (E,) each."""

    path: np.ndarray  # the path steered along
    current: np.ndarray  # the lane the ego is on
    on_route: np.ndarray  # following a turn route (the path) rather than lanes
    wants: np.ndarray  # the goal lane is another lane, reachable by changing to the next one
    goal_s: np.ndarray  # the goal's centre along the current lane
    changing: np.ndarray  # changing to it now
    drop_back: np.ndarray  # acceleration cap while a change is blocked (inf: not blocked)


class IDMExpert:
    """A lane-following IDM expert: the rule-based driver a learnt policy should come close to.

    It reads the simulator's state (the road's lanes, every vehicle's pose,
    speed and lane) and acts on all episodes at once, without a loop over
    episodes or agents; the action is a function of each episode's state alone.

    * Which path: when the goal lies on a lane reachable by lane changes, the
      ego changes one lane towards it once a MOBIL-like gap check passes: no
      vehicle on that lane would make the ego, or be made by it, brake harder
      than the traffic's ``max_imposed_braking`` (MOBIL's safety criterion,
      and the traffic's own gap acceptance).  Once its box overlaps the new
      lane it finishes the change whatever the check says.  While blocked it
      drops back behind the rearmost vehicle in the way (following it when it
      is ahead, letting it pass at ``pass_margin`` m/s less when it is not):
      the traffic is finite, so falling back finds a gap or its end.  The
      lane must be left before its end and, with the goal on another lane,
      early enough to reach the goal's speed inside its region; the ego waits
      at a standing obstacle where a lane change from standstill still fits
      before that point.  When the goal lane crosses the lane the ego started
      on (the intersection) the ego follows a route from one into the other
      on an arc of ``turn_radius`` m.
    * Yielding on a route: while a vehicle on a lane the route crosses or
      joins is in the conflict zone, or would reach it before the ego could
      clear it (accelerating from its speed) plus ``time_gap`` s, a stop line
      ``stop_margin`` m before the first conflict is a standing obstacle; past
      the line the ego goes on.
    * Longitudinal: the traffic's own IDM (:func:`idm_free`,
      :func:`idm_interaction`, with the episodes' traffic model) towards the
      middle of the goal's speed bounds, with the nearest vehicle ahead whose
      box overlaps the path (and, during a lane change, the lane being left)
      as leader, plus the standing obstacles above.  Through a turn the
      desired speed is capped so the lateral acceleration stays below
      ``turn_accel``.
    * Lateral: pure pursuit of the path's centre line from the rear axle,
      ``lookahead_time`` s ahead (at least ``min_lookahead`` m), as a bicycle
      steering angle clipped to the bounds.
    """

    def __init__(self, *, lookahead_time: float = 0.8, min_lookahead: float = 5.0, turn_radius: float = 9.0,
                 turn_accel: float = 2.5, time_gap: float = 2.0, stop_margin: float = 1.0,
                 pass_margin: float = 4.0) -> None:
        self.lookahead_time = lookahead_time
        self.min_lookahead = min_lookahead
        self.turn_radius = turn_radius
        self.turn_accel = turn_accel
        self.time_gap = time_gap
        self.stop_margin = stop_margin
        self.pass_margin = pass_margin
        self._plans: weakref.WeakKeyDictionary[Any, _Plan] = weakref.WeakKeyDictionary()
        self._on_commonroad: Any = None

    def _commonroad(self) -> Any:
        if self._on_commonroad is None:
            from pytest_driveeval.policies.commonroad_expert import CommonRoadExpert

            self._on_commonroad = CommonRoadExpert()
        return self._on_commonroad

    def plan(self, blueprint: Any) -> _Plan:
        """The paths and conflict zones of ``blueprint``, worked out on first use."""
        plan = self._plans.get(blueprint)
        if plan is None:
            plan = self._plans[blueprint] = _plan(blueprint, self.turn_radius, self.stop_margin)
        return plan

    def act_on_episodes(self, episodes: Any) -> np.ndarray:
        if getattr(episodes.blueprint, "scenario", None) is not None:  # a CommonRoad scene: its own expert
            return self._commonroad().act_on_episodes(episodes)
        plan = self.plan(episodes.blueprint)
        model: TrafficModel = episodes.traffic_model
        view = self._view(episodes, plan)
        choice = self._choose_path(episodes, plan, model, view)
        accel = self._accelerate(episodes, plan, model, view, choice)
        steer = self._steer(episodes, plan, choice.path)
        low, high = action_bounds(episodes)
        return np.clip(np.stack([accel, steer], axis=1), low, high)

    @staticmethod
    def _view(episodes: Any, plan: _Plan) -> _View:
        paths = plan.paths
        length, width = np.asarray(episodes.size, np.float64)
        proj, cos_rel, half_long, clearance = paths.footprint(episodes.xy, episodes.yaw, length, width)
        inside = (proj.s > -0.5 * length) & (proj.s < paths.lengths + 0.5 * length)
        return _View(proj.s, proj.d, half_long, (clearance < 0.0) & inside,
                     episodes.speed[..., None] * cos_rel, (cos_rel > 0.0) & inside)

    @staticmethod
    def _desired_speed(episodes: Any) -> np.ndarray:
        low, high = episodes.blueprint.params.desired_speed
        return np.where(episodes.goal_speed > 0.0, episodes.goal_speed, 0.5 * (low + high))

    def _choose_path(self, episodes: Any, plan: _Plan, model: TrafficModel, view: _View) -> _Choice:
        road, params = episodes.blueprint.road, episodes.blueprint.params
        n_lanes = road.num_lanes
        others = episodes.valid.copy()
        others[:, 0] = False
        v = episodes.speed[:, 0]

        current = np.argmin(np.where(view.aligned[:, 0, :n_lanes], np.abs(view.d[:, 0, :n_lanes]), np.inf), axis=1)
        goal = plan.paths.project(episodes.goal_centre)
        goal_cost = np.where((np.cos(episodes.goal_heading[:, None] - goal.heading[:, :n_lanes]) > 0.5)
                             & (goal.s[:, :n_lanes] >= 0.0) & (goal.s[:, :n_lanes] <= road.lengths),
                             np.abs(goal.d[:, :n_lanes]), np.inf)
        goal_lane = np.where(np.isfinite(goal_cost.min(axis=1)), np.argmin(goal_cost, axis=1), current)
        # Routes start on the lane the blueprint spawned the ego on, which the engine keeps in column 0.
        route = plan.route[episodes.traffic.lane[:, 0], goal_lane]
        on_route = route >= 0
        step_to = plan.toward[current, goal_lane]
        wants = ~on_route & (step_to >= 0) & (step_to != current)
        beside = np.where(wants, step_to, current)

        # The gap check, against every vehicle on the lane beside or heading into it.
        v0 = self._desired_speed(episodes)
        s_b, half_b, v_b = _on(view.s, beside), _on(view.half_long, beside), _on(view.along, beside)
        there = others & (_on(view.overlaps, beside) | (episodes.traffic.lane == beside[:, None]))
        # Others' desired speeds are unknown to the ego: take the fastest of the blueprint's.
        blocks, gap, ahead = change_blocked(model, s_b, half_b, v_b, v_b[:, :1], v0, params.desired_speed[1], there)
        b_safe = model.max_imposed_braking
        # Half across, turning back would be worse than going on: traffic there already brakes for the ego.
        committed = _on(view.overlaps, beside)[:, 0]
        changing = wants & (~blocks.any(axis=1) | committed)
        path = np.where(on_route, route, np.where(changing, beside, current))

        # The vehicle in the way is on another lane: dropping back behind it needs no hard braking.
        found, r_gap, r_v, r_ahead = _first(blocks, s_b, gap, v_b, ahead)
        r_ahead &= found & (r_gap >= model.min_gap)
        slower = np.where(r_ahead, v0, np.minimum(v0, np.maximum(r_v - self.pass_margin, 1.0)))
        follow = np.where(r_ahead, idm_interaction(model, v, r_v, r_gap), 0.0)
        drop_back = np.where(wants & ~changing,
                             np.maximum(idm_free(model, v, slower) - model.max_accel * follow, -b_safe), np.inf)
        return _Choice(path, current, on_route, wants, goal.s[np.arange(len(current)), current], changing, drop_back)

    def _accelerate(self, episodes: Any, plan: _Plan, model: TrafficModel, view: _View, choice: _Choice) -> np.ndarray:
        road = episodes.blueprint.road
        rows = np.arange(episodes.num_episodes)
        hl = 0.5 * float(episodes.size[0])
        others = episodes.valid.copy()
        others[:, 0] = False
        v = episodes.speed[:, 0]
        path, current, on_route = choice.path, choice.current, choice.on_route

        # Leaders: the nearest overlapping vehicle ahead on the path, and on the lane being left.
        interaction = np.zeros(episodes.num_episodes)
        for p in (path, np.where(on_route, path, current)):
            s_p, half_p = _on(view.s, p), _on(view.half_long, p)
            ahead_by = s_p - s_p[:, :1]
            found, lead_gap, lead_v = _first(others & _on(view.overlaps, p) & (ahead_by > 0.0), ahead_by,
                                             ahead_by - half_p - half_p[:, :1], _on(view.along, p))
            interaction = np.maximum(interaction, np.where(found, idm_interaction(model, v, lead_v, lead_gap), 0.0))

        # Leaving the lane: by its end, and, for a goal on another lane, early enough to speed up from
        # standstill into the goal's speed bounds inside its region; unless changing already, wait
        # where a change from standstill still fits.
        speed_up = episodes.goal_speed_bounds[:, 0] ** 2 / (2.0 * model.max_accel)
        leave_by = np.where(choice.wants, choice.goal_s + 0.5 * episodes.goal_size[:, 0] - speed_up, np.inf)
        lane_end = road.end_s[current]
        end = np.where(choice.changing, lane_end, np.minimum(lane_end, leave_by) - plan.merge_room)
        end_gap = end - view.s[rows, 0, current] - view.half_long[rows, 0, current]
        interaction += np.where(on_route, 0.0, idm_interaction(model, v, 0.0, end_gap))

        # Crossing traffic on a route: a vehicle in the conflict, or reaching it before the ego clears it.
        s_route = view.s[rows, 0, path]
        lane = episodes.traffic.lane
        s_lane = np.take_along_axis(view.s, lane[..., None], axis=2)[..., 0]
        zone_in, zone_out, leave = (z[path[:, None], lane] for z in (plan.zone_in, plan.zone_out, plan.leave))
        a = model.max_accel
        to_clear = np.maximum(leave - s_route[:, None], 0.0)
        t_clear = (np.sqrt(v[:, None] ** 2 + 2.0 * a * to_clear) - v[:, None]) / a
        within = (s_lane + hl >= zone_in) & (s_lane - hl <= zone_out)
        coming = (s_lane + hl < zone_in) & (zone_in - s_lane - hl < episodes.speed * (t_clear + self.time_gap))
        threat = others & np.isfinite(zone_in) & (within | coming)
        stop = plan.stop[path]
        waits = on_route & threat.any(axis=1) & (s_route <= stop)
        interaction += np.where(waits, idm_interaction(model, v, 0.0, stop - s_route), 0.0)

        v0 = self._desired_speed(episodes)
        turning = on_route & (s_route < plan.turn_end[path])
        v0 = np.where(turning, np.minimum(v0, np.sqrt(self.turn_accel * self.turn_radius)), v0)
        return np.minimum(idm_free(model, v, v0) - model.max_accel * interaction, choice.drop_back)

    def _steer(self, episodes: Any, plan: _Plan, path: np.ndarray) -> np.ndarray:
        """Pure pursuit: the arc from the rear axle through the path's point a lookahead ahead."""
        wheelbase = episodes.blueprint.params.ego_wheelbase
        yaw, v = episodes.yaw[:, 0], episodes.speed[:, 0]
        rear = episodes.xy[:, 0] - 0.5 * wheelbase * np.stack([np.cos(yaw), np.sin(yaw)], axis=-1)
        s_rear = plan.paths.project(rear).s[np.arange(len(path)), path]
        target, _ = plan.paths.pose(path, s_rear + np.maximum(self.lookahead_time * v, self.min_lookahead), 0.0)
        to = target - rear
        alpha = np.arctan2(to[:, 1], to[:, 0]) - yaw
        return np.arctan(2.0 * wheelbase * np.sin(alpha) / np.maximum(np.hypot(to[:, 0], to[:, 1]), 1e-6))
