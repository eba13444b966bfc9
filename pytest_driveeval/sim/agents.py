"""Traffic: IDM car following, MOBIL lane changes, gap acceptance, vectorised over (episodes, agents).

Column 0 of every (E, A) array is the ego: it takes part as a leader and as
a follower others must not cut in front of, but is moved by the engine.

Each step, every agent (the ego too) is projected onto every lane
(:meth:`Road.project <pytest_driveeval.sim.blueprints.road.Road.project>`).
An agent *occupies* a lane when it is assigned to it or its box overlaps it
laterally, so a vehicle halfway through a lane change blocks both lanes and
an ego crossing a lane is seen by that lane's traffic.  An agent *wishes* to
enter a lane when it is the ego and its box comes within ``yield_margin`` of
the lane's edge, or a vehicle within ``merge_zone`` of the end of a lane that
ends, towards the lane it must merge into.

* Longitudinal (IDM, highway-env 1.12's constants): the acceleration is the
  free-road term minus the strongest interaction with any vehicle ahead on the
  agent's lane, not only the nearest; a lane that ends is a standing obstacle
  at its end.  A vehicle that wishes to enter counts as a leader when the
  follower can take it in braking no harder than ``max_imposed_braking``: a
  follower yields when the gap is acceptable and drives on when it is not.
  Once yielding it keeps yielding to that agent (``yield_to``) while the wish
  lasts, even if the braking grows: IDM's final approach to a standing
  obstacle brakes harder than its start, and re-judging the gap every step
  would make the follower give up halfway and drive into the gap it opened.
* Lateral (MOBIL, politeness 0 as in highway-env, so the followers' gains
  drop out): change when the own acceleration on the target lane beats the
  current one by ``lane_change_gain`` and no follower there would have to
  brake harder than ``max_imposed_braking``.  At a lane end the current
  acceleration is the braking for the end, which is what forces the merge; the
  safety condition is the gap acceptance.  At most one vehicle per episode
  starts a change per step, so two never dive into one gap together.
* Motion: vehicles advance along their lane (ballistic update that stops at
  zero speed); a lane change blends the lateral offset to the new lane's
  centre with a smoothstep over ``lane_change_duration``; vehicles past the
  end of a lane that does not end leave the map (``valid`` turns False).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from pytest_driveeval.sim.blueprints.base import Parameters, positive
from pytest_driveeval.sim.blueprints.road import Road

__all__ = ["Traffic", "TrafficModel", "change_blocked", "idm_advance", "idm_free", "idm_interaction",
           "step_traffic"]

# Gaps are floored here so the interaction stays finite (and huge) for overlapping vehicles.
_MIN_GAP = 0.01
# Below this speed the heading of a lane change is taken at this speed: no sideways-facing boxes at standstill.
_YAW_SPEED_FLOOR = 2.0


@dataclass(frozen=True)
class TrafficModel(Parameters):
    """IDM / MOBIL constants: highway-env 1.12's (``IDMVehicle``), except the
    standstill gap, which is BARK's ``BehaviorIDMClassic`` 2 m (highway-env's is
    5 m plus a length, too wide for BARK-ML's 7 m merging spawn gaps)."""

    name: ClassVar[str] = "traffic"

    max_accel: float = positive(3.0, "IDM a, m/s^2 (highway-env COMFORT_ACC_MAX)")
    comfort_decel: float = positive(5.0, "IDM b, m/s^2 (highway-env -COMFORT_ACC_MIN)")
    max_brake: float = positive(8.0, "hardest braking a vehicle can do, m/s^2")
    time_headway: float = positive(1.5, "IDM T, s (highway-env TIME_WANTED)")
    delta: float = positive(4.0, "IDM exponent (highway-env DELTA)")
    min_gap: float = positive(2.0, "IDM s0, bumper to bumper, m")
    lane_change_gain: float = positive(0.2, "MOBIL threshold, m/s^2 (highway-env)", inclusive=True)
    max_imposed_braking: float = positive(2.0, "MOBIL safety limit and yield limit, m/s^2 (highway-env)")
    lane_change_duration: float = positive(2.5, "s to blend onto the new lane")
    lane_change_cooldown: float = positive(1.0, "s after a change before the next (highway-env LANE_CHANGE_DELAY)",
                                           inclusive=True)
    yield_margin: float = positive(0.5, "how close to a lane's edge the ego asks to enter, m", inclusive=True)
    merge_zone: float = positive(50.0, "distance before a lane end from which its vehicles ask to merge, m")

    def check(self):
        if self.max_brake < self.comfort_decel:
            raise self.error("max_brake", f"must be >= comfort_decel ({self.comfort_decel})")


@dataclass(frozen=True, eq=False)
class Traffic:
    """Per-vehicle state, each (E, A); column 0 (the ego's) is carried along unused."""

    lane: np.ndarray  # int, index into the road's lanes
    s: np.ndarray  # m along the lane
    d: np.ndarray  # m lateral offset (non-zero while changing lanes)
    speed: np.ndarray  # m/s
    desired_speed: np.ndarray  # m/s, IDM v0
    change_offset: np.ndarray  # m, lateral offset when the current change started
    change_time: np.ndarray  # s since the last change started
    yield_to: np.ndarray  # int, the agent this vehicle is letting in, -1: none
    valid: np.ndarray  # bool: a vehicle on the map (padding and vehicles that left: False)


def idm_free(model: TrafficModel, speed: np.ndarray, desired_speed: np.ndarray) -> np.ndarray:
    """IDM's free-road acceleration a (1 - (|v| / v0)^delta)."""
    r = np.abs(speed / desired_speed)
    if model.delta == 4.0:  # the default; np.power is ~20x slower than two products
        r = r * r
        return model.max_accel * (1.0 - r * r)
    return model.max_accel * (1.0 - r ** model.delta)


def idm_interaction(model: TrafficModel, speed: np.ndarray, lead_speed: np.ndarray, gap: np.ndarray) -> np.ndarray:
    """(s* / s)^2, what IDM subtracts (times a) for a leader ``gap`` m ahead (bumper to bumper)."""
    dv = speed - lead_speed
    wanted = model.min_gap + np.maximum(
        0.0, speed * model.time_headway + speed * dv / (2.0 * np.sqrt(model.max_accel * model.comfort_decel)))
    return (wanted / np.maximum(gap, _MIN_GAP)) ** 2


def change_blocked(model: TrafficModel, s: np.ndarray, half: np.ndarray, speed: np.ndarray, ego_speed: np.ndarray,
                   desired: np.ndarray, others_desired: Any, there: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """An expert's lane change checked against the vehicles on the lane it would take (MOBIL's safety
    criterion, as the experts apply it).  (E, A), column 0 the ego: ``s`` arclength along that lane,
    ``half`` half lengths along it, ``speed`` speeds along it, ``there`` which vehicles are on it;
    ``ego_speed`` (E, 1), ``desired`` (E,) the ego's desired speed, ``others_desired`` theirs.  A vehicle
    blocks the change when the gap to it is under ``min_gap``, or when the one behind, following the
    other, would brake harder than ``max_imposed_braking``.  Returns (blocks, gap, ahead)."""
    ahead_by = s - s[:, :1]
    gap = np.abs(ahead_by) - half - half[:, :1]
    ahead = ahead_by >= 0.0
    me_behind = idm_free(model, ego_speed, desired[:, None]) - model.max_accel * idm_interaction(
        model, ego_speed, speed, gap)
    it_behind = idm_free(model, speed, others_desired) - model.max_accel * idm_interaction(model, speed, ego_speed, gap)
    blocks = there & ((gap < model.min_gap) | (np.where(ahead, me_behind, it_behind) < -model.max_imposed_braking))
    return blocks, gap, ahead


def idm_advance(model: TrafficModel, speed: np.ndarray, accel: np.ndarray, dt: float
                ) -> tuple[np.ndarray, np.ndarray]:
    """(distance travelled, speed after ``dt``) under ``accel`` clipped to
    [-max_brake, max_accel]: a ballistic update that stops at zero speed
    instead of reversing.  The traffic here and the closed loop's reactive
    agents (sim.logreplay.reactive) both move by it."""
    a = np.clip(accel, -model.max_brake, model.max_accel)
    v_next = speed + a * dt
    stops = v_next < 0.0
    travel = np.where(stops, speed * speed / (2.0 * np.maximum(-a, 1e-9)),
                      0.5 * (speed + np.maximum(v_next, 0.0)) * dt)
    return travel, np.maximum(v_next, 0.0)


def step_traffic(road: Road, model: TrafficModel, traffic: Traffic, xy: np.ndarray, yaw: np.ndarray,
                 speed: np.ndarray, size: tuple[float, float], dt: float) -> tuple[Traffic, np.ndarray, np.ndarray]:
    """One step of ``dt`` for every vehicle, from every agent's pose now.

    ``xy`` (E, A, 2), ``yaw``, ``speed`` (E, A): all agents, the ego in column 0;
    ``size``: (length, width) of every box.  Returns the next state and the
    vehicles' poses (xy, yaw); column 0 of those is left for the engine to fill.
    """
    e_n, a_n = traffic.s.shape
    lanes = np.arange(road.num_lanes)
    hl = 0.5 * size[0]
    is_vehicle = traffic.valid.copy()
    is_vehicle[:, 0] = False
    present = is_vehicle.copy()
    present[:, 0] = True

    # Every agent on every lane: (E, A, L).
    proj, cos_rel, half_long, clearance = road.footprint(xy, yaw, *size)
    assigned = is_vehicle[..., None] & (traffic.lane[..., None] == lanes)
    occupies = present[..., None] & (assigned | (clearance < 0.0))
    lane = traffic.lane
    own_s = traffic.s
    end_s = road.end_s[lane]
    left_of = road.left_of[lane]
    target = np.where(np.isfinite(end_s) & (own_s > end_s - model.merge_zone), left_of, -1)
    wishes = is_vehicle[..., None] & (target[..., None] == lanes)
    wishes[:, 0] = ~occupies[:, 0] & (clearance[:, 0] < model.yield_margin)

    # The lanes each vehicle looks at: its own, then left and right (-1: none).
    looked = np.stack([lane, left_of, road.right_of[lane]], axis=-1)  # (E, A, 3)
    exists = looked >= 0
    looked = np.where(exists, looked, 0)
    v_along = speed[..., None] * cos_rel
    # Each agent's free-road term as a follower on each lane, for the MOBIL safety check.
    free_along = idm_free(model, v_along, traffic.desired_speed[..., None])
    # One gather for all six fields; field-major so each field comes out contiguous.
    table = np.stack([proj.s, half_long, v_along, occupies, wishes, free_along])  # (6, E, A, L)
    table = np.swapaxes(table, 2, 3).reshape(6, e_n * road.num_lanes, a_n)
    rows = (np.arange(e_n)[:, None, None] * road.num_lanes + looked).reshape(e_n, a_n * 3)
    other = table[:, rows].reshape(6, e_n, a_n, 3, a_n)  # [., e, i, k, j]: agent j seen on lane k of vehicle i
    other_s, other_half, other_v, other_occ, other_wish, other_free = other
    other_occ, other_wish = other_occ > 0.5, other_wish > 0.5
    self_s = np.take_along_axis(proj.s, looked, axis=2)  # (E, A, 3)
    self_half = np.take_along_axis(half_long, looked, axis=2)
    self_v = np.take_along_axis(v_along, looked, axis=2)

    ahead_by = other_s - self_s[..., None]
    gap = np.abs(ahead_by) - other_half - self_half[..., None]
    not_self = ~np.eye(a_n, dtype=bool)[:, None, :]  # (i, k, j)
    ahead = (ahead_by >= 0.0) & not_self
    v = traffic.speed
    free = idm_free(model, v, traffic.desired_speed)  # (E, A)
    lead = idm_interaction(model, v[..., None, None], other_v, gap)  # (E, A, 3, A): i behind j
    strongest = np.max(np.where(ahead & other_occ, lead, 0.0), axis=-1)  # (E, A, 3)
    # Wishes count on the own lane only: if taking the wisher in is acceptable, or already promised.
    lead_own = lead[:, :, 0]
    agents = np.arange(a_n)
    letting_in = other_wish[:, :, 0] & ahead[:, :, 0] & (
        (free[..., None] - model.max_accel * lead_own >= -model.max_imposed_braking)
        | (traffic.yield_to[..., None] == agents))
    yielded = np.where(letting_in, lead_own, 0.0)
    strongest[..., 0] = np.maximum(strongest[..., 0], np.max(yielded, axis=-1))
    yield_to = np.where(np.any(letting_in, axis=-1), np.argmax(yielded, axis=-1), -1)
    end_gap = road.end_s[looked] - self_s - self_half
    lane_end = idm_interaction(model, v[..., None], 0.0, end_gap)  # 0 where the lane does not end (inf gap)
    accel = free[..., None] - model.max_accel * (strongest + lane_end)  # now (k=0), after a change (k=1, 2)

    # MOBIL on the neighbouring lanes: new followers must not brake harder than allowed.
    behind = (ahead_by < 0.0) & other_occ
    follow = other_free - model.max_accel * idm_interaction(model, other_v, self_v[..., None], gap)
    safe = ~np.any(behind & (follow < -model.max_imposed_braking), axis=-1)
    gain = accel[..., 1:] - accel[..., :1]
    ready = is_vehicle & (traffic.change_time >= model.lane_change_duration + model.lane_change_cooldown)
    ok = (exists[..., 1:] & safe[..., 1:] & (accel[..., 1:] >= -model.max_imposed_braking)
          & (gain > model.lane_change_gain) & ready[..., None])
    gain = np.where(ok, gain, -np.inf)
    side = 1 + np.argmax(gain, axis=-1)  # (E, A): 1 left, 2 right
    best = np.max(gain, axis=-1)
    first = np.argmax(best, axis=-1)  # one change per episode and step: the largest gain
    starts = (np.arange(a_n) == first[:, None]) & np.isfinite(best)

    # Longitudinal motion on the lane the vehicle ends the step on.
    travel, v_next = idm_advance(model, v, accel[..., 0], dt)
    new_lane = np.where(starts, np.take_along_axis(looked, side[..., None], axis=2)[..., 0], lane)
    start_d = np.take_along_axis(proj.d, new_lane[..., None], axis=2)[..., 0]
    s_next = np.where(starts, np.take_along_axis(self_s, side[..., None], axis=2)[..., 0], own_s) + travel
    offset = np.where(starts, start_d, traffic.change_offset)
    t_change = np.where(starts, 0.0, traffic.change_time) + dt
    x = np.minimum(t_change / model.lane_change_duration, 1.0)
    d_next = offset * (1.0 - x * x * (3.0 - 2.0 * x))
    d_rate = -offset * 6.0 * x * (1.0 - x) / model.lane_change_duration

    still = is_vehicle & (s_next <= road.lengths[new_lane] + hl)
    keep = ~is_vehicle
    nxt = Traffic(np.where(keep, lane, new_lane), np.where(keep, own_s, s_next), np.where(keep, traffic.d, d_next),
                  np.where(keep, v, v_next), traffic.desired_speed, np.where(keep, traffic.change_offset, offset),
                  np.where(keep, traffic.change_time, t_change), np.where(keep | starts, -1, yield_to),
                  still | (traffic.valid & keep))
    new_xy, heading = road.pose(nxt.lane, nxt.s, nxt.d)
    new_yaw = heading + np.arctan2(np.where(keep, 0.0, d_rate), np.maximum(nxt.speed, _YAW_SPEED_FLOOR))
    return nxt, new_xy, new_yaw
