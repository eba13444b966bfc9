"""Merging: the ego's lane ends; it must merge into the main lane and reach a goal downstream.

Lane 0 (right, y = 0) ends ``merge_end`` m after its start; lane 1 (left,
the main lane) runs ``length`` m.  Traffic on both lanes: the main lane's at
the same speeds, the merge lane's merging by gap acceptance at the lane end
(see :mod:`pytest_driveeval.sim.agents`).

Where it differs from BARK-ML's ``MergingBlueprint`` (2021,
``DR_DEU_Merging_MT_v01``, an INTERACTION-dataset map):

* straight parallel lanes with a square lane end instead of the real map's
  taper; the drivable area ends with the lane;
* gaps 7-17 m span BARK-ML's "dense" (7-12) and "medium" (12-17) modes;
* the goal keeps BARK-ML's limits (lateral 0.9 m, heading 0.15 rad, speed
  5-15 m/s) but is a region ``goal_length`` m long centred ``goal_s`` m along
  the main lane, not any point of its centre line;
* the ego's start is drawn on its own (``ego_s``); BARK-ML picks one of the
  spawned vehicles of its lane.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from pytest_driveeval.sim.blueprints.base import (
    Blueprint,
    BlueprintParams,
    Spawn,
    finish_spawn,
    gap_floor,
    place_along,
    positive,
    scaled_gap,
    span,
)
from pytest_driveeval.sim.blueprints.road import Lane, Road

__all__ = ["MergingParams", "merging"]

MERGE_LANE, MAIN_LANE = 0, 1


@dataclass(frozen=True)
class MergingParams(BlueprintParams):
    name: ClassVar[str] = "merging"
    #: the parameters that set the road's size, named when it would not fit in memory
    EXTENT: ClassVar[tuple[str, ...]] = ("length", "lane_width")

    length: float = positive(300.0, "main lane length, m")
    merge_end: float = positive(100.0, "where the ego's lane ends, m from its start")
    gap: tuple[float, float] = span((7.0, 17.0), "spawn gaps, m (BARK-ML: dense 7-12, medium 12-17)", minimum=0.1)
    speed: tuple[float, float] = span((9.0, 11.0), "initial traffic speeds, m/s (BARK-ML)", minimum=0.0)
    desired_speed: tuple[float, float] = span((10.0, 10.0), "IDM desired speeds, m/s (BARK-ML: 10)", minimum=0.1)
    ego_speed: tuple[float, float] = span((9.0, 11.0), "m/s (BARK-ML: as traffic)", minimum=0.0)
    main_span: tuple[float, float] = span((5.0, 45.0), "where main-lane traffic is spawned, m (BARK-ML)", minimum=0.0)
    merge_span: tuple[float, float] = span((5.0, 25.0), "where merge-lane traffic is spawned, m (BARK-ML)",
                                           minimum=0.0)
    ego_s: tuple[float, float] = span((5.0, 25.0), "ego's start on the merge lane, m (BARK-ML's span)", minimum=0.0)
    goal_s: tuple[float, float] = span((110.0, 130.0), "goal centre along the main lane, m", minimum=0.0)
    goal_length: float = positive(60.0, "m")
    goal_speed: tuple[float, float] = span((5.0, 15.0), "m/s (BARK-ML)", minimum=0.0)

    def check(self):
        super().check()
        if self.merge_end >= self.length:
            raise self.error("merge_end", f"must be below the main lane's length {self.length}")
        if self.merge_span[1] >= self.merge_end:
            raise self.error("merge_span", f"must end before the lane end {self.merge_end}")
        if self.ego_s[1] >= self.merge_end:
            raise self.error("ego_s", f"must end before the lane end {self.merge_end}")
        if self.main_span[1] > self.length:
            raise self.error("main_span", f"ends beyond the main lane's length {self.length}")
        if self.goal_s[1] + 0.5 * self.goal_length > self.length:
            raise self.error("goal_s", f"the goal may reach beyond the main lane's length {self.length}")


def merging(params: MergingParams) -> Blueprint:
    w = params.lane_width
    lanes = (Lane(np.array([[0.0, 0.0], [params.merge_end, 0.0]]), w, "merge"),
             Lane(np.array([[0.0, w], [params.length, w]]), w, "main"))
    # Main-lane traffic never changes into a lane that is about to end.
    road = Road(lanes, left=(MAIN_LANE, -1), right=(-1, -1), ends=(True, False))

    def spawn(rng: np.random.Generator, agent_limit: int, gap_scale: float = 1.0) -> Spawn:
        gap, floor = scaled_gap(params, gap_scale), gap_floor(params)
        ego_s = rng.uniform(*params.ego_s)
        ego_speed = rng.uniform(*params.ego_speed)
        goal_s = rng.uniform(*params.goal_s)
        main = place_along(rng, *params.main_span, params.gap, gap_scale, floor)
        merge = place_along(rng, *params.merge_span, params.gap, gap_scale, floor)
        merge = merge[np.abs(merge - ego_s) >= gap[0]]
        lane = np.concatenate([np.full(len(merge), MERGE_LANE), np.full(len(main), MAIN_LANE)])
        s = np.concatenate([merge, main])
        return finish_spawn(rng, params, road, lane, s, MERGE_LANE, ego_s, ego_speed, MAIN_LANE, goal_s,
                            agent_limit)

    return Blueprint("merging", params, road, spawn)
