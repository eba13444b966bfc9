"""``Model: pdm_closed``: PDM-Closed (Dauner et al. 2023, autonomousvision/tuplan_garage's
``pdm_closed_planner``), batched over the scenes of a step.

Every step, for each scene: the ego is placed on the route's centre line (:mod:`.pdm_centreline`) as a
station, a lateral offset and a heading error; proposals are made for every lateral offset in ``offsets``
and every target speed in ``fractions`` of the speed limit; each is rolled out for ``horizon`` seconds by
IDM along the line (the leader: the nearest agent ahead in its corridor, every agent moving on at constant
velocity) with a kinematic bicycle in the line's frame that steers onto the offset (a linear feedback on
the lateral error and its rate, the LQR-shaped law of PDM's tracker, yaw rate and steering bounded); the
rollouts are scored by nuPlan's terms (:mod:`.pdm_scoring`); the best one is returned, and the engine drives
its first pose.  It replans at every simulation step (10 Hz, nuPlan's own planner rate).

Departures from the paper, each for a reason: nuScenes' maps give no speed limits, so ``default_limit``
stands in; the target speed is also capped where the line bends (``lateral_comfort``), and acceleration
changes by at most ``jerk`` per second from what the ego did last, because the score judges comfort on the
driven trajectory and a planner replanning every 0.1 s would otherwise jump between proposals.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pytest_driveeval.policies.pdm_centreline import SPACING, Centrelines, centrelines, one_line, route_line, straight
from pytest_driveeval.policies.pdm_scoring import score_proposals
from pytest_driveeval.policies.planner_api import Observation, PlannerContext

__all__ = ["PDMClosed", "PDMOptions"]


@dataclass(frozen=True)
class PDMOptions:
    fractions: tuple[float, ...] = (1.0, 0.8, 0.6, 0.4, 0.2)   # of the speed limit (tuplan_garage's five)
    offsets: tuple[float, ...] = (0.0, -1.0, 1.0)               # metres left of the line (tuplan_garage's three)
    horizon: float = 4.0                                        # seconds, as PDM's proposals
    rollout_step: float = 0.2                                   # s per rollout step (returned at the loop's step)
    default_limit: float = 13.9                                 # m/s (50 km/h) where the map has no limit
    accel: float = 2.0                                          # IDM's maximum acceleration (tuplan_garage: 1.5)
    decel: float = 3.0                                          # IDM's comfortable deceleration (tuplan_garage)
    brake: float = 6.0                                          # the hardest braking a rollout may use
    headway: float = 1.5                                        # s (tuplan_garage)
    min_gap: float = 1.0                                        # m (tuplan_garage)
    jerk: float = 4.0                                           # m/s^3 between steps, speeding up
    brake_jerk: float = 15.0                                    # m/s^3 between steps, braking (safety first)
    lateral_comfort: float = 3.0                                # m/s^2 through bends
    max_yaw_rate: float = 0.6                                   # rad/s the tracker commands
    gains: tuple[float, float] = (0.6, 1.2)                     # lateral error, its rate (omega 0.77, zeta 0.77)


class PDMClosed:
    """The planner; see the module doc.  A scene without a route (no map) follows a straight line from where
    its ego is first seen, with the same IDM and scoring (so it still brakes for what is ahead)."""

    def __init__(self, options: PDMOptions = PDMOptions()):
        self.options = options
        self.lines: Centrelines | None = None

    def initialize(self, context: PlannerContext) -> None:
        from pytest_driveeval.metrics.nuplan_score import kernels

        if kernels.AVAILABLE:
            # The proposals ask the score's map ~500 points per scene per step: the score's compiled queries
            # (which run once numba is loaded, metrics.nuplan_score.kernels) repay their start within a step.
            import numba  # noqa: F401
        self.context = context
        self.maps = [scene.map for scene in context.scenes]
        o = self.options
        self._lines = [route_line(scene.map.map if scene.map is not None else None, scene.route, o.default_limit)
                       for scene in context.scenes]
        self.lines = None
        self.station = np.full(len(context.scenes), np.nan)  # where each ego was last placed on its line
        self.accel_now = np.zeros(len(context.scenes))

    def _table(self, obs: Observation) -> Centrelines:
        missing = [r for r in obs.rows.tolist() if self._lines[r] is None]
        if missing or self.lines is None:
            for r in missing:  # no route: a straight line ahead of where the ego is now
                b = int(np.flatnonzero(obs.rows == r)[0])
                self._lines[r] = one_line(straight(obs.ego_xy[b], float(obs.ego_yaw[b]), 20.0),
                                          np.full(40, self.options.default_limit))
            self.lines = centrelines(self._lines)
        return self.lines

    def plan(self, obs: Observation) -> dict:
        o, dt = self.options, self.options.rollout_step
        lines = self._table(obs)
        rows = obs.rows
        s0, e0, psi0 = self._place(lines, rows, obs.ego_xy, obs.ego_yaw)
        self.station[rows] = s0
        steps = int(round(o.horizon / dt))
        obs = _nearby(obs, steps * dt, o.default_limit)
        agents = _agents_on_line(lines, rows, obs, s0)
        n_off, n_speed = len(o.offsets), len(o.fractions)
        shape = (len(rows), n_off * n_speed)
        offset = np.broadcast_to(np.repeat(np.asarray(o.offsets), n_speed), shape)
        fraction = np.broadcast_to(np.tile(np.asarray(o.fractions), n_off), shape)
        rollout = _roll_out(lines, rows, o, dt, steps, s0, e0, psi0, np.asarray(obs.ego_speed, dtype=np.float64),
                            self.accel_now[rows], offset, fraction, agents)
        scores = score_proposals(rollout, obs, self.maps, self.context.ego_extent, dt)
        best = np.argmax(scores, axis=1)  # ties: the first, the centre line at the highest speed
        pick = np.arange(len(rows))
        self.accel_now[rows] = rollout["accel"][pick, best, 0]
        # the chosen rollout at the loop's own step: linear between the rollout's poses
        at = np.arange(1, self.context.future_frames + 1) * self.context.step_time / dt
        i = np.minimum(at.astype(np.int64), steps - 1)
        w = (at - i)[None, :]
        xy = rollout["xy"][pick, best]
        yaw = np.unwrap(rollout["yaw"][pick, best], axis=1)
        xy = xy[:, i] * (1 - w[..., None]) + xy[:, i + 1] * w[..., None]
        yaw = yaw[:, i] * (1 - w) + yaw[:, i + 1] * w
        positions, yaws = obs.to_ego_frame(xy, yaw)
        self.last_scores, self.last_choice = scores, best
        return {"positions": positions.astype(np.float32), "yaws": yaws[..., None].astype(np.float32)}

    def _place(self, lines: Centrelines, rows: np.ndarray, xy: np.ndarray, yaw: np.ndarray):
        """Station, lateral offset (left +) and heading error of each ego: the nearest point of its line near
        where it was last placed (anywhere on the line, among points heading its way, the first time)."""
        last = self.station[rows]
        n = lines.xy.shape[1]
        centre = np.where(np.isnan(last), 0, last / SPACING).astype(np.int64)
        for b in np.flatnonzero(np.isnan(last)):  # the first time: the whole line, among points heading its way
            r = rows[b]
            d = np.hypot(*(lines.xy[r, :lines.length[r]] - xy[b]).T)
            off = np.abs(np.angle(np.exp(1j * (lines.heading[r, :lines.length[r]] - yaw[b]))))
            centre[b] = int(np.argmin(d + np.where(off > np.pi / 2, 1e3, 0.0)))
        idx = np.clip(centre[:, None] + np.arange(-40, 121), 0, n - 1)
        pts = lines.xy[rows[:, None], idx]
        d = np.hypot(pts[..., 0] - xy[:, None, 0], pts[..., 1] - xy[:, None, 1])
        k = idx[np.arange(len(rows)), np.argmin(d, axis=1)]
        h = lines.heading[rows, k]
        rel = xy - lines.xy[rows, k]
        along = rel[:, 0] * np.cos(h) + rel[:, 1] * np.sin(h)
        lateral = -rel[:, 0] * np.sin(h) + rel[:, 1] * np.cos(h)
        s = np.clip(k * SPACING + along, 0.0, (lines.length[rows] - 1) * SPACING)
        return s, lateral, np.angle(np.exp(1j * (yaw - h)))


def _nearby(obs: Observation, horizon: float, fastest: float) -> Observation:
    """The observation with only the agents that may come within reach of a proposal within the horizon:
    at the start, halfway or at the end of their constant-velocity path, within what the ego can drive
    (``fastest`` for ``horizon`` seconds) plus 15 m of it (the scoring's cost grows with the agents)."""
    radius = np.maximum(obs.ego_speed, fastest) * horizon + 15.0
    near = np.zeros(obs.agents_available.shape, dtype=bool)
    for t in (0.0, 0.5 * horizon, horizon):
        d = obs.agents_xy + obs.agents_velocity * t - obs.ego_xy[:, None]
        near |= np.hypot(d[..., 0], d[..., 1]) < radius[:, None]
    return obs.only_agents(near & obs.agents_available)


def _agents_on_line(lines: Centrelines, rows: np.ndarray, obs: Observation, s0: np.ndarray) -> dict:
    """Each agent's station and lateral offset on its scene's line now, and their rates (constant velocity)."""
    n = lines.xy.shape[1]
    window = np.arange(-40, 241)  # 20 m behind the ego to 120 m ahead
    idx = np.clip((s0 / SPACING).astype(np.int64)[:, None] + window, 0, n - 1)
    pts = lines.xy[rows[:, None], idx]                                     # (B, W, 2)
    a = obs.agents_xy                                                      # (B, A, 2)
    d = np.hypot(a[:, :, None, 0] - pts[:, None, :, 0], a[:, :, None, 1] - pts[:, None, :, 1])
    near = np.argmin(d, axis=2) if d.shape[2] else np.zeros(a.shape[:2], np.int64)
    k = np.take_along_axis(idx, near, axis=1)                              # (B, A)
    h = lines.heading[rows[:, None], k]
    c, s = np.cos(h), np.sin(h)
    rel = a - lines.xy[rows[:, None], k]
    v = obs.agents_velocity
    return dict(s=k * SPACING + rel[..., 0] * c + rel[..., 1] * s, e=-rel[..., 0] * s + rel[..., 1] * c,
                vs=v[..., 0] * c + v[..., 1] * s, ve=-v[..., 0] * s + v[..., 1] * c,
                length=obs.agents_extent[..., 0], width=obs.agents_extent[..., 1],
                ok=obs.agents_available & (np.min(d, axis=2) < 8.0 if d.shape[2] else obs.agents_available))


def _roll_out(lines, rows, o: PDMOptions, dt, steps, s0, e0, psi0, v0, a0, offset, fraction, agents) -> dict:
    """Every proposal (B, P) rolled out ``steps`` steps: poses (B, P, steps + 1), speeds, accelerations."""
    b, p = offset.shape
    length, width = 4.869, 1.852
    s = np.repeat(s0[:, None], p, 1)
    e = np.repeat(e0[:, None], p, 1)
    psi = np.repeat(psi0[:, None], p, 1)
    v = np.repeat(v0[:, None], p, 1)
    a_prev = np.repeat(a0[:, None], p, 1)
    r = np.broadcast_to(rows[:, None], (b, p))
    xy = np.zeros((b, p, steps + 1, 2))
    yaw = np.zeros((b, p, steps + 1))
    speed = np.zeros((b, p, steps + 1))
    accel = np.zeros((b, p, steps))
    yaw_rate = np.zeros((b, p, steps))
    kp, kd = o.gains
    corridor = 0.5 * (width + agents["width"])[:, None] + 0.3                     # (B, 1, A)
    reach = 0.5 * (length + agents["length"])[:, None]
    ok = agents["ok"][:, None]
    for k in range(steps + 1):
        point, heading, kappa, limit, bend = lines.at(r, s)
        normal = np.stack([-np.sin(heading), np.cos(heading)], -1)
        xy[:, :, k] = point + normal * e[..., None]
        yaw[:, :, k] = heading + psi
        speed[:, :, k] = v
        if k == steps:
            break
        # the target speed: a fraction of the limit, no faster than the bends ahead allow
        target = np.minimum(fraction * limit, np.sqrt(o.lateral_comfort / np.maximum(bend, 1e-4)))
        target = np.maximum(target, 0.5)
        # IDM's leader: the nearest agent ahead in this proposal's corridor, each at constant velocity
        t = k * dt
        a_s = agents["s"][:, None] + agents["vs"][:, None] * t
        a_e = agents["e"][:, None] + agents["ve"][:, None] * t
        gap = a_s - s[..., None] - reach
        inside = ok & (np.abs(a_e - e[..., None]) < corridor) & (a_s > s[..., None])
        gap = np.where(inside, gap, np.inf)
        lead = np.argmin(gap, axis=-1) if gap.shape[-1] else np.zeros((b, p), np.int64)
        g = np.take_along_axis(gap, lead[..., None], -1)[..., 0] if gap.shape[-1] else np.full((b, p), np.inf)
        v_lead = np.take_along_axis(np.broadcast_to(agents["vs"][:, None], gap.shape), lead[..., None], -1)[..., 0] \
            if gap.shape[-1] else np.zeros((b, p))
        free = 1.0 - (v / target) ** 4
        wanted = o.min_gap + np.maximum(0.0, v * o.headway + v * (v - v_lead) / (2 * np.sqrt(o.accel * o.decel)))
        interact = np.where(np.isfinite(g), (wanted / np.maximum(g, 0.1)) ** 2, 0.0)
        a = np.clip(o.accel * (free - interact), -o.brake, o.accel)
        a = np.clip(a, a_prev - o.brake_jerk * dt, a_prev + o.jerk * dt)
        a = np.where(v + a * dt < 0, -v / dt, a)  # stop, do not reverse
        a_prev = a
        accel[:, :, k] = a
        # the tracker: lateral acceleration from the error to the offset and its rate, as a heading rate
        lateral_rate = v * np.sin(psi)
        demand = -kp * (e - offset) - kd * lateral_rate
        psi_rate = np.clip(demand / np.maximum(v, 1.0), -o.max_yaw_rate, o.max_yaw_rate)
        yaw_rate[:, :, k] = psi_rate + kappa * v
        # the step at its mean speed: with the speed of its start only, the first pose (the one the ego
        # is moved to) would never show a proposal's braking or speeding up
        v_next = np.maximum(v + a * dt, 0.0)
        mean = 0.5 * (v + v_next)
        s = s + mean * np.cos(psi) * dt
        e = e + mean * np.sin(psi) * dt
        psi = psi + psi_rate * dt
        v = v_next
    return dict(xy=xy, yaw=yaw, speed=speed, accel=accel, yaw_rate=yaw_rate, station=s, start=s0,
                fraction=fraction, offset=offset)
