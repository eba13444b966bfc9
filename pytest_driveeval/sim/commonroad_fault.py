"""Whose fault an episode's collision on a CommonRoad scene is, by nuPlan's rules for the ego
(metrics.nuplan_score.collisions, nuplan-devkit's ``_get_collision_type``), decided at the step the
episode ended in a collision, against every obstacle whose box meets the ego's there:

    stopped ego     the ego's speed is at most 0.05 m/s                            not at fault
    stopped track   the obstacle is static, or its speed is at most 0.05 m/s       at fault
    active rear     the obstacle's centre is more than 150 deg off the ego's
                    heading, seen from the rear axle                               not at fault
    active front    the ego's front bumper meets the obstacle's box                 at fault
    active lateral  otherwise: at fault unless every corner of the ego lies in one lanelet or
                    in a lanelet and its successor (the ego kept to its lane and was hit from the side)

A replayed recording does not react: a car recorded behind drives into an ego that is slower than the
recorded driver was.  So an expert is judged on the collisions that are its fault, as nuPlan judges one.
An episode hit by several obstacles at once is at fault when any of those collisions is.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from pytest_driveeval.geometry.boxes import box_corners, oriented_boxes_overlap, segment_meets_box
from pytest_driveeval.io.commonroad.commonroad_geometry import lanelets_at
from pytest_driveeval.metrics.episode_outcomes import COLLISION
from pytest_driveeval.metrics.nuplan_score.collisions import (ACTIVE_FRONT, ACTIVE_LATERAL, ACTIVE_REAR, BEHIND,
                                                              STOPPED_EGO, STOPPED_SPEED, STOPPED_TRACK)

__all__ = ["FaultRecorder", "collision_kinds"]


def _in_one_lane(scenario: Any, corners: np.ndarray) -> bool:
    holders = [set(ids) for ids in lanelets_at(scenario, corners[:, 0], corners[:, 1])]
    for ident in set().union(*holders):
        ll = scenario.lanelets[ident]
        lane = {ident, *ll.successors, *ll.predecessors}
        if all(h & lane for h in holders):
            return True
    return False


def collision_kinds(episodes: Any, rows: np.ndarray) -> list[tuple[str, bool]]:
    """(kind, at fault) of the collision of each episode in ``rows`` (CommonRoadEpisodes) as it stands now."""
    size = episodes.size
    ego_extent = size[0]
    wheelbase = episodes.blueprint.params.ego_wheelbase
    out = []
    for e in rows.tolist():
        xy, yaw, v = episodes.xy[e, 0], float(episodes.yaw[e, 0]), float(episodes.speed[e, 0])
        valid = episodes.valid[e].copy()
        valid[0] = False
        hit = np.flatnonzero(valid & oriented_boxes_overlap(xy[None], np.array([yaw]), ego_extent, episodes.xy[e],
                                                            episodes.yaw[e], size))
        if v <= STOPPED_SPEED:
            out.append((STOPPED_EGO, False))
            continue
        corners = box_corners(xy, yaw, ego_extent)
        kinds = []
        for j in hit.tolist():
            role = episodes.blueprint.scenario.obstacles[int(episodes.blueprint.obstacle_ids[j - 1])].role
            if role == "static" or episodes.speed[e, j] <= STOPPED_SPEED:
                kinds.append((STOPPED_TRACK, True))
                continue
            rear = xy - 0.5 * wheelbase * np.array([np.cos(yaw), np.sin(yaw)])
            to = episodes.xy[e, j] - rear
            cosine = float(np.dot([np.cos(yaw), np.sin(yaw)], to / max(np.linalg.norm(to), 1e-12)))
            if np.arccos(np.clip(cosine, -1.0, 1.0)) > BEHIND:
                kinds.append((ACTIVE_REAR, False))
            elif segment_meets_box(corners[0], corners[1], episodes.xy[e, j], episodes.yaw[e, j], size[j]):
                kinds.append((ACTIVE_FRONT, True))
            else:
                kinds.append((ACTIVE_LATERAL, not _in_one_lane(episodes.blueprint.scenario, corners)))
        # the shapes' refinement may clear a box hit the engine did not count: take the boxes' verdict
        out.append(next((k for k in kinds if k[1]), kinds[0] if kinds else ("shape only", True)))
    return out


class FaultRecorder:
    """A ``run_policy`` step sink: each episode's collision kind and fault, when it ends in one."""

    def __init__(self) -> None:
        self.kind: dict[int, str] = {}
        self.at_fault: dict[int, bool] = {}
        self._seen: np.ndarray | None = None

    def __call__(self, episodes: Any) -> None:
        ended = episodes.outcome == COLLISION
        new = ended if self._seen is None else ended & ~self._seen
        self._seen = ended
        rows = np.flatnonzero(new)
        for e, (kind, fault) in zip(rows.tolist(), collision_kinds(episodes, rows)):
            self.kind[e], self.at_fault[e] = kind, fault

    def faults(self, n: int) -> np.ndarray:
        """(n,) bool: episode ended in a collision that was its fault."""
        return np.array([self.at_fault.get(e, False) for e in range(n)])
