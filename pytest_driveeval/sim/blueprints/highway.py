"""Highway: the ego must change lanes to reach a goal region on a neighbouring lane.

Where it differs from BARK-ML's ``HighwayBlueprint`` (2021, ``round_highway.xodr``):

* the road is straight (BARK-ML: a closed curved loop), ``length`` m long, lanes
  numbered from the right (lane 0) with lane 0's centre on y = 0, driving
  towards +x;
* gaps 15-35 m span BARK-ML's "dense" (15-30) and "medium" (20-35) modes;
* the goal is a region ``goal_length`` m long on a neighbouring lane
  (``goal_lanes``, one drawn per seed) ``goal_ahead`` m in front of the ego's
  start, with BARK-ML's merging limits (lateral 0.9 m, heading 0.15 rad) and
  speeds 10-20 m/s around the traffic's.  BARK-ML's current highway goal is a
  polygon off the map (its evaluator shapes a speed reward instead); its 2020
  one was any point of the left lane's centre line within those limits;
* only the ``agent_limit - 1`` vehicles nearest to the ego's start exist (BARK-ML
  simulates all, and its observer keeps the nearest).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from pytest_driveeval.sim.blueprints.base import (
    Blueprint,
    BlueprintParams,
    Spawn,
    count,
    indices,
    finish_spawn,
    gap_floor,
    place_along,
    positive,
    scaled_gap,
    span,
)
from pytest_driveeval.sim.blueprints.road import Lane, Road

__all__ = ["HighwayParams", "highway"]


@dataclass(frozen=True)
class HighwayParams(BlueprintParams):
    name: ClassVar[str] = "highway"
    #: the parameters that set the road's size, named when it would not fit in memory
    EXTENT: ClassVar[tuple[str, ...]] = ("length", "lanes", "lane_width")

    lanes: int = count(4, "lanes, all in one direction (BARK-ML: 4)", minimum=2)
    length: float = positive(1000.0, "road length, m")
    gap: tuple[float, float] = span((15.0, 35.0), "spawn gaps, m (BARK-ML: dense 15-30, medium 20-35)",
                                    minimum=0.1)
    speed: tuple[float, float] = span((12.5, 17.5), "initial traffic speeds, m/s (BARK-ML)", minimum=0.0)
    desired_speed: tuple[float, float] = span((12.0, 17.0), "IDM desired speeds, m/s (BARK-ML: 12-17 per lane)",
                                              minimum=0.1)
    ego_speed: tuple[float, float] = span((12.5, 17.5), "m/s (BARK-ML: as traffic)", minimum=0.0)
    traffic_span: tuple[float, float] = span((0.0, 250.0), "where traffic is spawned along the road, m (BARK-ML)",
                                             minimum=0.0)
    ego_lane: int = count(1, "lane the ego starts on, 0 = rightmost", minimum=0)
    ego_s: tuple[float, float] = span((40.0, 80.0), "ego's start along the road, m (BARK-ML)", minimum=0.0)
    goal_lanes: tuple[int, ...] = indices((0, 2), "candidate goal lanes, one drawn per seed")
    goal_ahead: tuple[float, float] = span((100.0, 150.0), "goal centre ahead of the ego's start, m", minimum=0.0)
    goal_length: float = positive(100.0, "m: about 3 to 13 s of driving in which to be on the goal lane")
    goal_speed: tuple[float, float] = span((10.0, 20.0), "m/s", minimum=0.0)

    def check(self):
        super().check()
        if self.ego_lane >= self.lanes:
            raise self.error("ego_lane", f"must be below lanes ({self.lanes}), got {self.ego_lane}")
        for lane in self.goal_lanes:
            if lane >= self.lanes or lane == self.ego_lane:
                raise self.error("goal_lanes", f"lane {lane} is not another lane of the {self.lanes}")
        if self.traffic_span[1] > self.length:
            raise self.error("traffic_span", f"ends beyond the road's length {self.length}")
        if self.ego_s[1] + self.goal_ahead[1] + 0.5 * self.goal_length > self.length:
            raise self.error("goal_ahead", f"the goal may lie beyond the road's length {self.length}")


def highway(params: HighwayParams) -> Blueprint:
    w = params.lane_width
    lanes = tuple(Lane(np.array([[0.0, k * w], [params.length, k * w]]), w, f"lane{k}") for k in range(params.lanes))
    n = params.lanes
    road = Road(lanes, left=tuple(k + 1 if k + 1 < n else -1 for k in range(n)),
                right=tuple(k - 1 for k in range(n)))
    goal_lanes = np.array(params.goal_lanes)

    def spawn(rng: np.random.Generator, agent_limit: int, gap_scale: float = 1.0) -> Spawn:
        gap, floor = scaled_gap(params, gap_scale), gap_floor(params)
        ego_s = rng.uniform(*params.ego_s)
        ego_speed = rng.uniform(*params.ego_speed)
        goal_lane = int(goal_lanes[rng.integers(len(goal_lanes))])
        goal_s = ego_s + rng.uniform(*params.goal_ahead)
        lane, s = [], []
        for k in range(n):
            pos = place_along(rng, *params.traffic_span, params.gap, gap_scale, floor)
            if k == params.ego_lane:
                pos = pos[np.abs(pos - ego_s) >= gap[0]]
            lane.append(np.full(len(pos), k))
            s.append(pos)
        lane, s = np.concatenate(lane), np.concatenate(s)
        return finish_spawn(rng, params, road, lane, s, params.ego_lane, ego_s, ego_speed, goal_lane, goal_s,
                            agent_limit)

    return Blueprint("highway", params, road, spawn)
