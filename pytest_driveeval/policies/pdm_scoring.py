"""PDM-Closed's proposal scorer: nuPlan's closed-loop terms over each proposal's 4 s rollout, against the
agents moving on at constant velocity, all proposals of all scenes at once.

It reads the harness's own nuPlan score wherever that applies to a rollout: the map's drivable-area queries
and margin (``ScoreMap.lanes_holding`` / ``in_drivable`` / ``distance_to_drivable``, ``terms.DRIVABLE_MARGIN``),
the score's box overlap test (``geometry.oriented_boxes_overlap``, which its collision and TTC terms use),
the TTC bound and ahead cone (``ttc.LEAST_TTC``, ``ttc.AHEAD``), the comfort bounds (``comfort.BOUNDS``), the
progress threshold and the terms' weights (``term.WEIGHTS``).  The score's whole-scene term functions are not
called per proposal: they take a logged scene's inputs and cost milliseconds each, and a step has 15
proposals per scene; PDM's own scorer makes the same cut (nuPlan's terms, re-implemented over proposals).

The terms as PDM scores them: multipliers for an at-fault collision and for leaving the drivable area;
weighted progress (against the best proposal's), time to collision and comfort.  Driving direction and the
speed limit are left out: no proposal drives against its lane (the offsets are 1 m), and none is faster than
its limit (the target speeds are fractions of it).
"""
from __future__ import annotations

import numpy as np

from pytest_driveeval.geometry.boxes import box_corners, oriented_boxes_overlap
from pytest_driveeval.metrics.nuplan_score.comfort import BOUNDS
from pytest_driveeval.metrics.nuplan_score.progress import PROGRESS_THRESHOLD
from pytest_driveeval.metrics.nuplan_score.term import WEIGHTS
from pytest_driveeval.metrics.nuplan_score.terms import DRIVABLE_MARGIN
from pytest_driveeval.metrics.nuplan_score.ttc import AHEAD, LEAST_TTC

#: rollout steps (of 0.1 s) whose corners are checked against the drivable area
DRIVABLE_STEPS = (1, 2, 3, 5, 8, 10, 15, 20)
#: seconds the ego and an agent are projected ahead for the time-to-collision check
TTC_PROJECTIONS = (0.3, 0.6, LEAST_TTC)
STOPPED = 0.05
assert AHEAD + np.pi / 3 <= np.pi / 2  # "ahead" below is a positive forward distance


def drivable(rollout: dict, maps: list, rows: np.ndarray, extent) -> np.ndarray:
    """(B, P) every checked corner on the drivable area or within the score's margin of it."""
    xy, yaw = rollout["xy"], rollout["yaw"]
    b, p, steps = yaw.shape
    keep = [k for k in DRIVABLE_STEPS if k < steps]
    out = np.ones((b, p), dtype=bool)
    corners = box_corners(xy[:, :, keep], yaw[:, :, keep], extent)  # (B, P, K, 4, 2)
    for i, row in enumerate(rows.tolist()):
        query = maps[row]
        if query is None:
            continue
        score_map = query.map
        points = corners[i].reshape(-1, 2)
        _, held, _ = score_map.lanes_holding(points)
        off = ~held if score_map.every_lane_drivable else np.ones(len(points), dtype=bool)
        rest = np.flatnonzero(off)
        if len(rest):
            off[rest] = ~score_map.in_drivable(points[rest])
        rest = np.flatnonzero(off)
        if len(rest):
            off[rest] = ~(score_map.distance_to_drivable(points[rest], DRIVABLE_MARGIN) < DRIVABLE_MARGIN)
        out[i] = ~off.reshape(p, -1).any(axis=1)
    return out


def _agents_at(obs, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Agents' centres (B, 1, K, A, 2) at times ``t`` (K,), at constant velocity, and their yaws (B, 1, 1, A)."""
    xy = obs.agents_xy[:, None, None] + obs.agents_velocity[:, None, None] * t[None, None, :, None, None]
    return xy, obs.agents_yaw[:, None, None]


def _within_reach(obs, rollout: dict, extent, dt: float):
    """The observation with only the agents whose constant-velocity path comes near the box around all of
    its scene's rollouts (with the TTC projection): the others can neither collide nor come close."""
    xy = rollout["xy"]
    lo, hi = xy.min(axis=(1, 2)), xy.max(axis=(1, 2))                         # (B, 2)
    horizon = (rollout["yaw"].shape[2] - 1) * dt + LEAST_TTC
    margin = 0.5 * (np.hypot(extent[0], extent[1]) + np.hypot(obs.agents_extent[..., 0], obs.agents_extent[..., 1]))
    margin = margin + rollout["speed"].max(axis=(1, 2))[:, None] * LEAST_TTC  # (B, A)
    end = obs.agents_xy + obs.agents_velocity * horizon
    a_lo, a_hi = np.minimum(obs.agents_xy, end), np.maximum(obs.agents_xy, end)
    near = obs.agents_available & np.all((a_hi + margin[..., None] > lo[:, None]) &
                                         (a_lo - margin[..., None] < hi[:, None]), axis=-1)
    return obs.only_agents(near)


def collisions_and_ttc(rollout: dict, obs, extent, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """(B, P) the first rollout step with an at-fault collision (the number of steps where none), and (B, P) a
    time to collision under the bound somewhere.

    At fault as nuPlan blames: the ego was moving and the agent was not behind it (a rear-end is the other's)."""
    steps = np.arange(1, rollout["yaw"].shape[2])
    b, p = rollout["yaw"].shape[:2]
    obs = _within_reach(obs, rollout, extent, dt)
    a = obs.agents_xy.shape[1]
    if a == 0:
        return np.full((b, p), rollout["yaw"].shape[2]), np.zeros((b, p), bool)
    ego_xy = rollout["xy"][:, :, steps]            # (B, P, K, 2)
    ego_yaw = rollout["yaw"][:, :, steps]
    ego_v = rollout["speed"][:, :, steps]
    length, width = extent[0], extent[1]
    a_ext = obs.agents_extent[:, None, None, :, :2]
    ok = obs.agents_available[:, None, None, :]
    reach = 0.5 * (np.hypot(length, width) + np.hypot(a_ext[..., 0], a_ext[..., 1]))
    heading = np.stack([np.cos(ego_yaw), np.sin(ego_yaw)], -1)
    first_hit = np.full((b, p), rollout["yaw"].shape[2])
    short = np.zeros((b, p), bool)
    for tau in (0.0,) + TTC_PROJECTIONS:
        a_xy, a_yaw = _agents_at(obs, steps * dt + tau)
        e_xy = ego_xy + heading * (ego_v * tau)[..., None]
        rel = a_xy - e_xy[:, :, :, None]
        near = rel[..., 0] ** 2 + rel[..., 1] ** 2 < reach ** 2
        forward = rel[..., 0] * heading[..., None, 0] + rel[..., 1] * heading[..., None, 1]
        moving = (ego_v > STOPPED)[..., None]
        # a collision is the ego's unless the agent is behind it; a short time to collision counts for agents
        # ahead (within AHEAD of the heading, widened by 60 degrees: the score also looks beside the ego where
        # it straddles lanes or crosses a junction, which a rollout does not track)
        candidate = ok & near & moving & (forward > (-0.25 * length if tau == 0.0 else 0.0))
        hit = np.zeros(candidate.shape, bool)
        where = np.nonzero(candidate)
        if len(where[0]):
            bb, pp, kk, aa = where
            hit[where] = oriented_boxes_overlap(e_xy[bb, pp, kk], ego_yaw[bb, pp, kk], np.array([length, width]),
                                                a_xy[bb, 0, kk, aa], a_yaw[bb, 0, 0, aa], a_ext[bb, 0, 0, aa])
        if tau == 0.0:
            any_hit = hit.any(axis=3)
            first_hit = np.where(any_hit.any(axis=2), steps[np.argmax(any_hit, axis=2)], first_hit)
        else:
            short |= hit.any(axis=(2, 3))
    return first_hit, short


def comfortable(rollout: dict) -> np.ndarray:
    """(B, P) the rollout's longitudinal and lateral accelerations and yaw rate inside the score's bounds."""
    accel, rate = rollout["accel"], rollout["yaw_rate"]
    lateral = rollout["speed"][:, :, :-1] * rate
    ok = (accel > BOUNDS["ego_lon_acceleration"][0]) & (accel < BOUNDS["ego_lon_acceleration"][1])
    ok &= np.abs(lateral) < BOUNDS["ego_lat_acceleration"][1]
    ok &= np.abs(rate) < BOUNDS["ego_yaw_rate"][1]
    return ok.all(axis=2)


def score_proposals(rollout: dict, obs, maps: list, extent, dt: float) -> np.ndarray:
    """(B, P) each proposal's score: multipliers times the weighted mean of progress, TTC and comfort."""
    first_hit, short = collisions_and_ttc(rollout, obs, extent, dt)
    steps = rollout["yaw"].shape[2]
    multiplier = ((first_hit == steps) & drivable(rollout, maps, obs.rows, extent)).astype(np.float64)
    progress = rollout["station"] - rollout["start"][:, None]
    best = np.max(np.where(multiplier > 0, progress, -np.inf), axis=1, keepdims=True)
    scale = np.where(best > PROGRESS_THRESHOLD, best, 1.0)  # no proposal goes far: progress does not decide
    ratio = np.where(best > PROGRESS_THRESHOLD, np.clip(progress / scale, 0.0, 1.0), 1.0)
    w_progress = WEIGHTS["ego_progress_along_expert_route"]
    w_ttc = WEIGHTS["time_to_collision_within_bound"]
    w_comfort = WEIGHTS["ego_is_comfortable"]
    weighted = (w_progress * ratio + w_ttc * ~short + w_comfort * comfortable(rollout)) / (w_progress + w_ttc + w_comfort)
    # where every proposal scores 0, the one that collides last (a collision it may yet avoid next step),
    # then the better weighted terms: a tie-break far below any proposal that scores
    fallback = 1e-3 * (first_hit / steps) + 1e-4 * weighted
    return multiplier * weighted + fallback
