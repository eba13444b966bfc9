"""The collisions nuPlan's score counts, found and classified by nuplan-devkit's own rules
(docs/nuplan_score.md §3.1: ``no_ego_at_fault_collisions``, ``collision_utils``): at every frame, each
agent not hit before whose box meets the ego's (touching counts) is a collision, once per agent for the
whole scene; its type is decided at that frame.

    stopped ego   the ego's speed is at most 0.05 m/s                          never at fault
    stopped track the agent is static, or its speed is at most 0.05 m/s         at fault
    active rear   the agent's centre is more than 150 deg off the ego's heading,
                  seen from the rear axle                                       never at fault
    active front  the ego's front bumper (front-left to front-right corner)
                  meets the agent's box                                         at fault
    active lateral otherwise                                                    at fault where the ego's
                  corners are not in one lane, or in two connected ones (straddling, or off the lanes)

The engine's own blame (metrics.collisions, l5kit's one partner per frame) is the other choice,
``ScoreInputs.blame = "engine"``: its collisions are then taken as recorded.
"""
from __future__ import annotations

import numpy as np

from pytest_driveeval.geometry.boxes import oriented_boxes_overlap, segment_meets_box

from . import kernels
from .inputs import GROUPS, Collision, ScoreInputs

STOPPED_SPEED = 0.05
BEHIND = np.deg2rad(150.0)
STOPPED_EGO, STOPPED_TRACK, ACTIVE_FRONT, ACTIVE_REAR, ACTIVE_LATERAL = (
    "stopped ego", "stopped track", "active front", "active rear", "active lateral")


def contacts(inputs: ScoreInputs) -> tuple[np.ndarray, np.ndarray]:
    """(frames, cols) of every cell whose agent's box meets the ego's box (shapely's ``intersects``, after
    nuplan-devkit's bounding-circle precheck), in frame order."""
    ego, agents = inputs.ego, inputs.agents
    if agents.token.shape[1] == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    ego_radius = float(np.hypot(ego.width, ego.length))
    if kernels.wanted():
        e_cos, e_sin = ego.heading_unit
        return kernels.kernels().box_contacts(agents.available, agents.xy, agents.yaw, agents.length, agents.width,
                                              np.ascontiguousarray(ego.center[:, :2]), e_cos, e_sin, float(ego.length),
                                              float(ego.width), ego_radius)
    frames, cols = np.nonzero(agents.available)
    xy = agents.xy[frames, cols].astype(np.float64)
    length = agents.length[frames, cols].astype(np.float64)
    width = agents.width[frames, cols].astype(np.float64)
    centre = ego.center[frames, :2]
    # nuPlan's precheck: centres nearer than the two half diagonals (strictly)
    near = np.hypot(*(xy - centre).T) < (ego_radius + np.hypot(width, length)) / 2.0
    frames, cols, xy, length, width = frames[near], cols[near], xy[near], length[near], width[near]
    meet = oriented_boxes_overlap(ego.center[frames, :2], ego.center[frames, 2], np.array([ego.length, ego.width]),
                                  xy, agents.yaw[frames, cols].astype(np.float64), np.stack([length, width], axis=1))
    return frames[meet], cols[meet]


def collision_type(inputs: ScoreInputs, frame: int, col: int) -> str:
    """nuplan-devkit's ``_get_collision_type`` of the ego and the agent in cell (frame, col)."""
    ego, agents = inputs.ego, inputs.agents
    if ego.speed[frame] <= STOPPED_SPEED:
        return STOPPED_EGO
    velocity = agents.velocity[frame, col].astype(np.float64)
    if agents.static[frame, col] or np.hypot(*velocity) <= STOPPED_SPEED:
        return STOPPED_TRACK
    to_agent = agents.xy[frame, col].astype(np.float64) - ego.rear_axle[frame]
    heading = ego.center[frame, 2]
    # the angle as nuPlan takes it, arccos of the cosine (NaN where the centres coincide: not behind)
    with np.errstate(invalid="ignore", divide="ignore"):
        cosine = np.dot([np.cos(heading), np.sin(heading)], to_agent / np.linalg.norm(to_agent))
        if np.arccos(cosine) > BEHIND:
            return ACTIVE_REAR
    front_left, front_right = ego.corners[frame, 0], ego.corners[frame, 1]
    box = (agents.xy[frame, col].astype(np.float64), float(agents.yaw[frame, col]),
           np.array([agents.length[frame, col], agents.width[frame, col]], dtype=np.float64))
    if segment_meets_box(front_left, front_right, *box):
        return ACTIVE_FRONT
    return ACTIVE_LATERAL


def nuplan_collisions(inputs: ScoreInputs, in_one_lane: np.ndarray) -> tuple[list[Collision], dict[int, int]]:
    """Each agent's first contact, typed and blamed by nuPlan's rules, and per agent the later frames in
    contact that nuPlan does not count (for the term's reason).  ``in_one_lane`` (T,): the ego's corners
    in one lane or two connected ones (nuPlan's ``timestamps_in_common_or_connected_route_objs``)."""
    frames, cols = contacts(inputs)
    tokens = inputs.agents.token[frames, cols]
    out: list[Collision] = []
    later: dict[int, int] = {}
    seen: set[int] = set()
    for frame, col, token in zip(frames.tolist(), cols.tolist(), tokens.tolist()):
        if token in seen:
            later[token] = later.get(token, 0) + 1
            continue
        seen.add(token)
        kind = collision_type(inputs, frame, col)
        at_fault = kind in (STOPPED_TRACK, ACTIVE_FRONT) or (kind == ACTIVE_LATERAL and not in_one_lane[frame])
        group = GROUPS[int(inputs.agents.group[frame, col])]
        out.append(Collision(frame, token, group, at_fault, kind))
    return out, later
