"""The score's terms that read the map or the expert, and the collision multiplier
(docs/nuplan_score.md §3.1-3.5, 3.7: what nuplan-devkit's source computes, and where the harness differs)."""
from __future__ import annotations

import numpy as np

from .inputs import ScoreInputs
from .lanes import ScoreMap
from .route import first_lanes
from .term import Term

#: nuplan-devkit's thresholds (its simulation_metric configs)
DRIVABLE_MARGIN = 0.3
#: metres: a corner further off the drivable area is reported as this far (the term fails either way)
DEPTH_REPORTED = 3.0
DIRECTION_COMPLIANCE, DIRECTION_VIOLATION, DIRECTION_HORIZON = 2.0, 6.0, 1.0
MIN_PROGRESS_RATIO = 0.2
MAX_OVERSPEED = 2.23
#: nuPlan's allowance of at-fault collisions per group before the multiplier reaches 0
ALLOWED = {"vehicle": 0, "vru": 0, "object": 1}


def no_ego_at_fault_collisions(inputs: ScoreInputs, collisions: list | None = None,
                               later: dict[int, int] | None = None) -> Term:
    """``collisions``: those the score counts (default ``inputs.collisions``), one per agent; ``later``: per
    agent, its frames in contact after the first, which nuPlan does not count (said in the message)."""
    collisions = inputs.collisions if collisions is None else collisions
    later = later or {}
    counts = {g: 0 for g in ALLOWED}
    blamed = [c for c in collisions if c.at_fault]
    for c in blamed:
        counts[c.group] = counts.get(c.group, 0) + 1
    value = 1.0
    for group, n in counts.items():
        value *= max(0.0, 1.0 - n / (ALLOWED.get(group, 0) + 1))
    rules = "nuPlan's" if inputs.blame == "nuplan" else "the engine's"
    term = Term("no_ego_at_fault_collisions", value,
                detail={**{f"at_fault_{g}": n for g, n in counts.items()}, "collisions": len(collisions)})
    xy = inputs.ego.center[:, :2]
    if collisions:
        term.frames = [c.frame for c in blamed]
        term.places = [tuple(map(float, xy[c.frame])) for c in blamed]
        parts = [f"agent {c.token} ({c.group}{', ' + c.kind if c.kind else ''}) at frame "
                 f"{int(inputs.frame_numbers[c.frame])}, {'at fault' if c.at_fault else 'not at fault'}"
                 for c in collisions]
        repeats = [f"{n} later contact frame(s) with agent {token}" for token, n in sorted(later.items())]
        term.message = (f"{len(blamed)} at-fault collision(s) of {len(collisions)} by {rules} rules: "
                        + "; ".join(parts) + "; counted once per agent, as nuPlan counts"
                        + (": " + ", ".join(repeats) + " not counted" if repeats else ""))
    return term


def ego_corners(inputs: ScoreInputs) -> np.ndarray:
    """(T, 4, 2) corners FL, FR, RR, RL of the ego's box."""
    return inputs.ego.corners


def drivable_area_compliance(inputs: ScoreInputs, corners: np.ndarray, corner_on_lane: np.ndarray,
                             route: list[list[int]]) -> Term:
    """``corner_on_lane`` (4T,): each corner (frame by frame, FL, FR, RR, RL) on some lane."""
    name = "drivable_area_compliance"
    if inputs.map is None:
        return Term.not_available(name, "the scene has no map")
    score_map: ScoreMap = inputs.map
    t = len(corners)
    points = corners.reshape(-1, 2)
    # where a lane's surface is a stand-in and the map gives the area itself, being on a lane settles nothing
    outside = ~corner_on_lane if score_map.every_lane_drivable else np.ones(len(points), dtype=bool)
    outside[outside] = ~score_map.in_drivable(points[outside])
    far = np.zeros(len(points), dtype=bool)
    depth = np.zeros(len(points))
    rows = np.flatnonzero(outside)
    if len(rows):
        # One query up to DEPTH_REPORTED serves both: a distance under the margin is the least over the
        # polygons within the margin as well (any nearer than that lies within it).  How far out a corner
        # is is measured up to DEPTH_REPORTED; beyond, only that it is at least that.
        reported = score_map.distance_to_drivable(points[rows], DEPTH_REPORTED)
        to_drivable = np.where(reported < DRIVABLE_MARGIN, reported, np.inf)
        counted = score_map.lane_drivable
        near = [route[r // 4] if counted is None else [n for n in route[r // 4] if counted[n]] for r in rows]
        to_route = score_map.distance_to_lanes(points[rows], near, DRIVABLE_MARGIN)
        far[rows] = ~((to_drivable < DRIVABLE_MARGIN) | (to_route < DRIVABLE_MARGIN))
        depth[rows] = np.where(far[rows], np.minimum(reported, DEPTH_REPORTED),
                               np.where(np.isfinite(to_drivable), to_drivable, 0.0))
    far = far.reshape(t, 4)
    frames = np.flatnonzero(far.any(axis=1))
    term = Term(name, 0.0 if len(frames) else 1.0, reason=score_map.drivable_reason,
                detail={"frames_off_drivable_area": int(len(frames)),
                        "max_corner_off_drivable_area": float(depth.max()) if len(depth) else 0.0})
    if len(frames):
        depth = depth.reshape(t, 4)
        corner = np.argmax(np.where(far[frames], depth[frames], -1), axis=1).tolist()
        term.frames = frames.tolist()
        term.places = [tuple(p) for p in corners[frames, corner].tolist()]
        k0, c0 = frames[0], corner[0]
        term.message = (f"a corner {depth[k0, c0]:.2f} m off the drivable area at frame "
                        f"{int(inputs.frame_numbers[k0])} ({len(frames)} frame(s)); {DRIVABLE_MARGIN:g} m tolerated"
                        + (f"; {score_map.drivable_reason}" if score_map.drivable_stand_in else ""))
    return term


def driving_direction_compliance(inputs: ScoreInputs, route: list[list[int]]) -> Term:
    name = "driving_direction_compliance"
    if inputs.map is None:
        return Term.not_available(name, "the scene has no map")
    score_map: ScoreMap = inputs.map
    xy = inputs.ego.center[:, :2]
    lane_of = first_lanes(route)
    along = np.zeros(len(route))
    on = np.flatnonzero(lane_of >= 0)
    along[on] = score_map.along(xy[on], lane_of[on])
    steps = np.zeros(len(route))
    # Over the frames on a lane: a step is the change of position along it since the last such frame, on the
    # same lane, unless that frame changed lanes (or was the first, if off every lane at the start: it starts
    # nowhere), or the position is 0 (nuplan-devkit counts no step there).
    lanes, s = lane_of[on], along[on]
    changed = np.empty(len(on), dtype=bool)
    changed[:1] = bool(lane_of[0] < 0)  # (a scalar: no frame on a lane leaves nothing to set)
    changed[1:] = lanes[1:] != lanes[:-1]
    stepped = np.flatnonzero(~changed[1:] & ~changed[:-1] & (s[1:] != 0)) + 1
    steps[on[stepped]] = s[stepped] - s[stepped - 1]
    spacing = inputs.spacing if len(inputs.times) > 1 else 0.1
    n = int(DIRECTION_HORIZON / spacing) if spacing > 0 else 0
    window = np.convolve(steps, np.ones(n + 1))[:len(steps)]  # each frame's last n + 1 steps
    worst = abs(float(window.min())) if len(window) else 0.0
    value = 1.0 if worst < DIRECTION_COMPLIANCE else 0.5 if worst < DIRECTION_VIOLATION else 0.0
    term = Term(name, value, detail={"max_backward_motion": worst})
    if value < 1.0:
        bad = np.flatnonzero(-window >= DIRECTION_COMPLIANCE)
        term.frames = bad.tolist()
        term.places = [tuple(p) for p in xy[bad].tolist()]
        term.message = (f"{worst:.2f} m against the lane's direction within {(n + 1) * spacing:.1f} s, worst "
                        f"at frame {int(inputs.frame_numbers[int(np.argmin(window))])} "
                        f"(under {DIRECTION_COMPLIANCE:g} m complies, from {DIRECTION_VIOLATION:g} m scores 0)")
    return term


def ego_is_making_progress(progress: Term) -> Term:
    value = 1.0 if progress.used >= MIN_PROGRESS_RATIO else 0.0
    term = Term("ego_is_making_progress", value, reason=progress.reason)
    if not value:
        term.message = f"progress ratio {progress.used:.3f} < {MIN_PROGRESS_RATIO:g}: {progress.message}"
    return term


def speed_limit_compliance(inputs: ScoreInputs, route: list[list[int]]) -> Term:
    name = "speed_limit_compliance"
    if inputs.map is None:
        return Term.not_available(name, "the scene has no map")
    score_map: ScoreMap = inputs.map
    first = first_lanes(route)
    usable = np.where(np.isfinite(score_map.speed_limits) & (score_map.speed_limits > 0), score_map.speed_limits,
                      np.nan)
    limits = np.where(first >= 0, usable[first], np.nan)
    known_limits: dict = {}  # the frames on the same connectors share their limit
    for k in np.flatnonzero((first >= 0) & score_map.connector[first]).tolist():
        lanes = tuple(route[k])
        if lanes not in known_limits:
            # a connector's limit: the highest of the lanes into and out of its frame's connectors, if all have
            # one (a connector with neither takes its own: nuPlan's max() of no limit raises, and the oracle's
            # cases give such a connector itself as its edge)
            around = [m for n in lanes for m in ((*score_map.outgoing[n], *score_map.incoming[n]) or (n,))]
            values = usable[around] if around else np.array([np.nan])
            known_limits[lanes] = values.max() if np.all(np.isfinite(values)) else np.nan
        limits[k] = known_limits[lanes]
    known = np.isfinite(limits)
    if not known.any():
        why = "no lane the ego drove on gives a speed limit" if score_map.has_speed_limits else \
            f"no speed limit in the map ({score_map.no_limits_reason})" if score_map.no_limits_reason else \
            "no speed limit in the map"
        return Term.not_available(name, f"{why}: counted 1, as nuPlan counts a frame without one", used=1.0)
    over = np.where(known, np.maximum(0.0, inputs.ego.speed - np.where(known, limits, 0.0)), 0.0)
    duration = float(inputs.times[-1] - inputs.times[0])
    if not over.any() or duration <= 0:
        value = 1.0
    else:
        loss = over.sum() * inputs.spacing / (max(MAX_OVERSPEED, 1e-3) * duration)
        value = max(0.0, 1.0 - loss)
    term = Term(name, value, detail={"max_over_speed_limit": float(over.max()),
                                     "frames_with_speed_limit": int(known.sum())})
    if value < 1.0:
        bad = np.flatnonzero(over > 0)
        term.frames = bad.tolist()
        term.places = [tuple(p) for p in inputs.ego.center[bad, :2].tolist()]
        worst = int(np.argmax(over))
        term.message = (f"over the speed limit on {len(bad)} frame(s), by up to {over[worst]:.2f} m/s at frame "
                        f"{int(inputs.frame_numbers[worst])}")
    return term

