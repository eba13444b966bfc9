"""``time_to_collision_within_bound`` (docs/nuplan_score.md §3.6): each frame, the ego and the agents
ahead of it (and beside it, where it straddles lanes or is in an intersection) move on at constant
speed along their headings in 0.1 s steps up to 2.9 s; the first step at which the ego's box meets one
is the frame's time to collision.  An at-fault collision frame has 0; the term fails when a frame's
time is not above 0.95 s.

All frames and agents at once: a pair whose swept boxes (each box stretched over its 3 s of motion,
nuplan-devkit's own prefilter) do not meet cannot collide, and only the rest are stepped."""
from __future__ import annotations

import numpy as np

from pytest_driveeval.geometry.boxes import oriented_boxes_overlap

from .inputs import ScoreInputs
from .term import Term

STEP, HORIZON, LEAST_TTC, STOPPED_SPEED = 0.1, 3.0, 0.95, 5e-3
AHEAD, BEHIND = np.deg2rad(30.0), np.deg2rad(150.0)
STEPS = np.arange(STEP, HORIZON, STEP)  # 0.1 .. 2.9 s, as nuplan-devkit's arange gives them


def times_to_collision(inputs: ScoreInputs, in_one_lane: np.ndarray, in_intersection: np.ndarray) -> np.ndarray:
    """(T,) each frame's time to collision, inf where none within the horizon."""
    ego, agents = inputs.ego, inputs.agents
    t = inputs.num_frames
    ttc = np.full(t, np.inf)
    at_fault = sorted({c.frame for c in inputs.collisions if c.at_fault})
    if agents.center.shape[1] == 0:
        ttc[at_fault] = 0.0
        return ttc
    # Agents already hit (at fault or not) are out of the projection from their first contact on.
    collided = np.zeros(agents.token.shape, dtype=bool)
    for c in inputs.collisions:
        collided[c.frame:] |= agents.token[c.frame:] == c.token
    rear = ego.rear_axle
    heading = ego.center[:, 2]
    to_agent = agents.center[..., :2] - rear[:, None, :]
    bearing = np.arctan2(to_agent[..., 1], to_agent[..., 0]) - heading[:, None]
    angle = np.abs(np.arctan2(np.sin(bearing), np.cos(bearing)))
    beside = (~in_one_lane | in_intersection)[:, None] & (angle <= BEHIND)
    considered = agents.available & ~collided & ((angle < AHEAD) | beside)
    considered &= (ego.speed > STOPPED_SPEED)[:, None]
    frames, cols = np.nonzero(considered)
    if len(frames):
        e_step = ego.speed[frames, None] * STEP * np.stack([np.cos(heading[frames]), np.sin(heading[frames])], axis=1)
        a_center = agents.center[frames, cols]
        a_speed = np.where(agents.static[frames, cols], 0.0, np.hypot(*agents.velocity[frames, cols].T))
        a_step = a_speed[:, None] * STEP * np.stack([np.cos(a_center[:, 2]), np.sin(a_center[:, 2])], axis=1)
        e_ext = np.array([ego.length, ego.width])
        a_ext = np.stack([agents.length[frames, cols], agents.width[frames, cols]], axis=1)
        reach = HORIZON / STEP
        # The swept boxes: length plus the 3 s of motion, centred half way along it.
        swept = oriented_boxes_overlap(
            ego.center[frames, :2] + reach / 2 * e_step, heading[frames],
            e_ext + np.stack([reach * np.hypot(*e_step.T), np.zeros(len(frames))], axis=1),
            a_center[:, :2] + reach / 2 * a_step, a_center[:, 2],
            a_ext + np.stack([reach * np.hypot(*a_step.T), np.zeros(len(frames))], axis=1))
        p = np.flatnonzero(swept)
        if len(p):
            k = np.arange(1, len(STEPS) + 1)[None, :, None]
            meet = oriented_boxes_overlap(ego.center[frames[p], None, :2] + k * e_step[p, None, :],
                                          heading[frames[p], None], e_ext,
                                          a_center[p, None, :2] + k * a_step[p, None, :], a_center[p, None, 2],
                                          a_ext[p, None, :])
            hit = meet.any(axis=1)
            first = STEPS[np.argmax(meet, axis=1)]
            np.minimum.at(ttc, frames[p[hit]], first[hit])
    ttc[at_fault] = 0.0
    return ttc


def time_to_collision_within_bound(inputs: ScoreInputs, in_one_lane: np.ndarray, in_intersection: np.ndarray
                                   ) -> Term:
    ttc = times_to_collision(inputs, in_one_lane, in_intersection)
    bad = np.flatnonzero(~(ttc > LEAST_TTC))
    term = Term("time_to_collision_within_bound", 0.0 if len(bad) else 1.0,
                detail={"min_time_to_collision": float(ttc.min()) if len(ttc) else float("inf"),
                        "frames_below_time_to_collision_bound": int(len(bad))}, series={"time_to_collision": ttc})
    if len(bad):
        term.frames = bad.tolist()
        term.places = [tuple(map(float, inputs.ego.center[k, :2])) for k in bad]
        worst = int(bad[np.argmin(ttc[bad])])
        term.message = (f"time to collision {ttc[worst]:.1f} s at frame {int(inputs.frame_numbers[worst])} "
                        f"({len(bad)} frame(s) at or below {LEAST_TTC:g} s)")
    return term
