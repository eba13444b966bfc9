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

from . import kernels
from .inputs import ScoreInputs
from .term import Term

STEP, HORIZON, LEAST_TTC, STOPPED_SPEED = 0.1, 3.0, 0.95, 5e-3
AHEAD, BEHIND = np.deg2rad(30.0), np.deg2rad(150.0)
STEPS = np.arange(STEP, HORIZON, STEP)  # 0.1 .. 2.9 s, as nuplan-devkit's arange gives them
REACH = HORIZON / STEP


def times_to_collision(inputs: ScoreInputs, in_one_lane: np.ndarray, in_intersection: np.ndarray,
                       collisions: list | None = None) -> np.ndarray:
    """(T,) each frame's time to collision, inf where none within the horizon.  ``collisions``: those the
    score counts (default ``inputs.collisions``): their agents leave the projection from their first
    contact on, and an at-fault one's frame has 0."""
    ego, agents = inputs.ego, inputs.agents
    collisions = inputs.collisions if collisions is None else collisions
    t = inputs.num_frames
    ttc = np.full(t, np.inf)
    at_fault = sorted({c.frame for c in collisions if c.at_fault})
    if agents.token.shape[1] == 0:
        ttc[at_fault] = 0.0
        return ttc
    rear = ego.rear_axle
    heading = ego.center[:, 2]
    moving = ego.speed > STOPPED_SPEED
    compiled = kernels.wanted()
    motion = _ego_motion(ego) if compiled else None
    # The bearing of the cells that could count only (most cells are empty, the ego stands still, or the
    # agent is far); agents already hit (at fault or not) are out of the projection from their first contact on.
    if compiled:
        frames, cols = _candidates(ego, agents, moving, collisions, motion)
    else:
        collided = np.zeros(agents.token.shape, dtype=bool)
        for c in collisions:
            collided[c.frame:] |= agents.token[c.frame:] == c.token
        frames, cols = np.nonzero(agents.available & ~collided & moving[:, None])
    to_agent = agents.xy[frames, cols] - rear[frames]
    bearing = np.arctan2(to_agent[:, 1], to_agent[:, 0]) - heading[frames]
    angle = np.abs(np.arctan2(np.sin(bearing), np.cos(bearing)))
    keep = angle < AHEAD
    side = ~keep & (angle <= BEHIND)
    if side.any():  # only an agent beside the ego asks whether it is in one lane (route.InOneLane: computed then)
        keep |= side & (~np.asarray(in_one_lane, dtype=bool) | in_intersection)[frames]
    frames, cols = frames[keep], cols[keep]
    if len(frames):
        first = (_first_meetings_compiled(ego, agents, frames, cols, motion) if compiled
                 else _first_meetings(ego, agents, frames, cols))
        hit = first >= 0
        np.minimum.at(ttc, frames[hit], STEPS[first[hit]])
    ttc[at_fault] = 0.0
    return ttc


#: metres added to an agent's reach in :func:`_candidates`' first test, far more than its rounding
REACH_MARGIN = 1.0
#: metres added to each half extent in :func:`_candidates`' swept-box test: its own cosines may differ from
#: numpy's in the last bit, which moves a box by about 1e-14 m
SWEPT_SLACK = 1e-6


def _ego_motion(ego) -> tuple[np.ndarray, ...]:
    """Per frame: the cosine and sine of the ego's heading, its step in STEP seconds, and its travel over
    the horizon (the numbers :func:`_first_meetings` computes per pair, taken per frame)."""
    e_cos, e_sin = ego.heading_unit
    e_step = ego.speed[:, None] * STEP * np.stack([e_cos, e_sin], axis=1)
    return e_cos, e_sin, e_step, REACH * np.hypot(*e_step.T)


def _candidates(ego, agents, moving: np.ndarray, collisions: list, motion: tuple | None = None
                ) -> tuple[np.ndarray, np.ndarray]:
    """The cells of available agents not yet hit, at frames where the ego moves (as np.nonzero gives them),
    less those that cannot meet the ego within the horizon (kernels' ``meeting_candidates``): all but a
    few percent of a real scene's, so the bearings and the exact sweeps are computed for few."""
    e_cos, e_sin, e_step, e_sweep = _ego_motion(ego) if motion is None else motion
    hit_frame = np.array([c.frame for c in collisions], dtype=np.int64)
    hit_token = np.array([c.token for c in collisions], dtype=np.int64)
    return kernels.kernels().meeting_candidates(
        agents.available, moving, agents.token, hit_frame, hit_token, np.ascontiguousarray(ego.center[:, :2]), e_cos,
        e_sin, e_step, e_sweep, float(ego.length), float(ego.width), agents.xy, agents.yaw, agents.velocity,
        agents.static, agents.length, agents.width, HORIZON, STEP, REACH / 2, REACH_MARGIN, SWEPT_SLACK)


def _wide(values: np.ndarray) -> np.ndarray:
    """float64 of a selection of cells (a log's float32 widens exactly: the numbers of float64 inputs)."""
    return values.astype(np.float64, copy=False)


def _cell_poses(agents, frames: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """(P, 3) x, y, heading of the cells (frames, cols), float64."""
    return np.concatenate([agents.xy[frames, cols], agents.yaw[frames, cols][:, None]], axis=1, dtype=np.float64)


def _first_meetings(ego, agents, frames: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """Per pair (frame, agent column), the index into STEPS of the first step at which the ego's box and
    the agent's, moved on at their speeds, overlap; -1 if none."""
    heading = ego.center[:, 2]
    e_step = ego.speed[frames, None] * STEP * np.stack([np.cos(heading[frames]), np.sin(heading[frames])], axis=1)
    a_center = _cell_poses(agents, frames, cols)
    a_speed = np.where(agents.static[frames, cols], 0.0, np.hypot(*_wide(agents.velocity[frames, cols]).T))
    a_step = a_speed[:, None] * STEP * np.stack([np.cos(a_center[:, 2]), np.sin(a_center[:, 2])], axis=1)
    e_ext = np.array([ego.length, ego.width])
    a_ext = np.stack([_wide(agents.length[frames, cols]), _wide(agents.width[frames, cols])], axis=1)
    # The swept boxes: length plus the 3 s of motion, centred half way along it.
    swept = oriented_boxes_overlap(
        ego.center[frames, :2] + REACH / 2 * e_step, heading[frames],
        e_ext + np.stack([REACH * np.hypot(*e_step.T), np.zeros(len(frames))], axis=1),
        a_center[:, :2] + REACH / 2 * a_step, a_center[:, 2],
        a_ext + np.stack([REACH * np.hypot(*a_step.T), np.zeros(len(frames))], axis=1))
    first = np.full(len(frames), -1)
    p = np.flatnonzero(swept)
    if len(p):
        k = np.arange(1, len(STEPS) + 1)[None, :, None]
        meet = oriented_boxes_overlap(ego.center[frames[p], None, :2] + k * e_step[p, None, :],
                                      heading[frames[p], None], e_ext,
                                      a_center[p, None, :2] + k * a_step[p, None, :], a_center[p, None, 2],
                                      a_ext[p, None, :])
        first[p] = np.where(meet.any(axis=1), np.argmax(meet, axis=1), -1)
    return first


def _first_meetings_compiled(ego, agents, frames: np.ndarray, cols: np.ndarray, motion: tuple | None = None
                             ) -> np.ndarray:
    """:func:`_first_meetings` in one kernel: the cosines, sines and hypotenuses from numpy, computed as
    there (the ego's per frame, then taken per pair: the same numbers), the rest in the kernel."""
    e_cos, e_sin, e_step, e_sweep = _ego_motion(ego) if motion is None else motion
    a_xy = _wide(agents.xy[frames, cols])
    a_yaw = _wide(agents.yaw[frames, cols])
    a_cos, a_sin = np.cos(a_yaw), np.sin(a_yaw)
    a_speed = np.where(agents.static[frames, cols], 0.0, np.hypot(*_wide(agents.velocity[frames, cols]).T))
    a_step = a_speed[:, None] * STEP * np.stack([a_cos, a_sin], axis=1)
    a_sweep = REACH * np.hypot(*a_step.T)
    out = np.empty(len(frames), dtype=np.int64)
    kernels.kernels().first_meeting(
        frames.astype(np.int64), np.ascontiguousarray(ego.center[:, :2]), e_cos, e_sin, e_step, e_sweep,
        float(ego.length), float(ego.width), a_xy, a_cos, a_sin, a_step, a_sweep,
        agents.length[frames, cols].astype(np.float64), agents.width[frames, cols].astype(np.float64),
        REACH / 2, len(STEPS), out)
    return out


def time_to_collision_within_bound(inputs: ScoreInputs, in_one_lane: np.ndarray, in_intersection: np.ndarray,
                                   collisions: list | None = None) -> Term:
    ttc = times_to_collision(inputs, in_one_lane, in_intersection, collisions)
    bad = np.flatnonzero(~(ttc > LEAST_TTC))
    term = Term("time_to_collision_within_bound", 0.0 if len(bad) else 1.0,
                detail={"min_time_to_collision": float(ttc.min()) if len(ttc) else float("inf"),
                        "frames_below_time_to_collision_bound": int(len(bad))}, series={"time_to_collision": ttc})
    if len(bad):
        term.frames = bad.tolist()
        term.places = [tuple(p) for p in inputs.ego.center[bad, :2].tolist()]
        worst = int(bad[np.argmin(ttc[bad])])
        term.message = (f"time to collision {ttc[worst]:.1f} s at frame {int(inputs.frame_numbers[worst])} "
                        f"({len(bad)} frame(s) at or below {LEAST_TTC:g} s)")
    return term
