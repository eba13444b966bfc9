"""Intersection: an unprotected left turn across crossing traffic.

A four-way junction centred on the origin, one lane each way per arm,
``arm_length`` m long, right-hand traffic: eastbound (lane 0, y = -w/2),
westbound (lane 1, y = +w/2), northbound (lane 2, x = +w/2), southbound
(lane 3, x = -w/2).  The ego comes north on lane 2 and turns left into the
westbound lane, crossing the eastbound one; traffic drives straight through on
both crossing lanes and gives way only by gap acceptance (see
:mod:`pytest_driveeval.sim.agents`).  Kerbs at the four corners are rounded
with ``kerb_radius``.

Where it differs from BARK-ML's ``IntersectionBlueprint`` (2021,
``4way_intersection.xodr``):

* the ego's steering bound is 0.5 rad, not BARK-ML's 0.2: with a 2.7 m
  wheelbase 0.2 rad turns on a 13.3 m radius, and a left turn from a 3.5 m
  lane into the far lane needs about 5 m;
* the goal is a region on the westbound lane ``goal_distance`` m past the
  junction with heading (0.3 rad) and speed (0-15 m/s) bounds; BARK-ML's is
  the polygon of the exit lane's last piece, without either bound;
* crossing traffic is spawned over ``traffic_span`` around the junction
  (BARK-ML: 5-50 m from each lane's source point), gaps 10-25 m, 10-12 m/s.
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
    span,
)
from pytest_driveeval.sim.blueprints.road import Lane, Road

__all__ = ["IntersectionParams", "intersection"]

EAST, WEST, NORTH, SOUTH = 0, 1, 2, 3


@dataclass(frozen=True)
class IntersectionParams(BlueprintParams):
    name: ClassVar[str] = "intersection"
    #: the parameters that set the road's size, named when it would not fit in memory
    EXTENT: ClassVar[tuple[str, ...]] = ("arm_length", "lane_width")

    arm_length: float = positive(100.0, "each arm's length from the junction centre, m")
    kerb_radius: float = positive(5.0, "corner rounding, m")
    ego_max_steer: float = positive(0.5, "rad (BARK-ML: 0.2, too tight for the turn)")
    gap: tuple[float, float] = span((10.0, 25.0), "spawn gaps, m (BARK-ML)", minimum=0.1)
    speed: tuple[float, float] = span((10.0, 12.0), "initial traffic speeds, m/s (BARK-ML)", minimum=0.0)
    desired_speed: tuple[float, float] = span((10.0, 12.0), "IDM desired speeds, m/s", minimum=0.1)
    ego_speed: tuple[float, float] = span((5.0, 10.0), "m/s (BARK-ML)", minimum=0.0)
    traffic_span: tuple[float, float] = span((-60.0, 15.0), "crossing traffic's spawn span relative to the "
                                             "junction centre along its lane, m (negative: upstream)")
    ego_distance: tuple[float, float] = span((15.0, 25.0), "ego's front bumper at the start, m before the "
                                             "junction", minimum=0.0)
    goal_distance: tuple[float, float] = span((10.0, 20.0), "goal centre, m past the junction", minimum=0.0)
    goal_length: float = positive(15.0, "m")
    goal_heading_tol: float = positive(0.3, "rad")
    goal_speed: tuple[float, float] = span((0.0, 15.0), "m/s", minimum=0.0)

    def check(self):
        super().check()
        w = self.lane_width
        if self.ego_distance[1] + w + self.vehicle_length >= self.arm_length:
            raise self.error("ego_distance", f"the ego must start on its arm ({self.arm_length} m)")
        if self.goal_distance[1] + w + 0.5 * self.goal_length > self.arm_length:
            raise self.error("goal_distance", f"the goal may lie beyond the arm ({self.arm_length} m)")
        if not -self.arm_length <= self.traffic_span[0] <= self.traffic_span[1] <= self.arm_length:
            raise self.error("traffic_span", f"must lie within +-{self.arm_length} m")


def _kerbs(w: float, r: float) -> tuple[np.ndarray, ...]:
    """The four corner fillets between the arms: the square of side r at each
    junction corner minus the quarter disc of radius r centred on its far corner."""
    theta = np.linspace(0.0, 0.5 * np.pi, 9)
    out = []
    for sx, sy in ((1, 1), (-1, 1), (-1, -1), (1, -1)):
        cx, cy = sx * (w + r), sy * (w + r)
        arc = np.stack([cx - sx * r * np.cos(theta), cy - sy * r * np.sin(theta)], axis=1)
        out.append(np.concatenate([[[sx * w, sy * w]], arc]))
    return tuple(out)


def intersection(params: IntersectionParams) -> Blueprint:
    w, arm, h = params.lane_width, params.arm_length, 0.5 * params.lane_width
    lanes = (Lane(np.array([[-arm, -h], [arm, -h]]), w, "eastbound"),
             Lane(np.array([[arm, h], [-arm, h]]), w, "westbound"),
             Lane(np.array([[h, -arm], [h, arm]]), w, "northbound"),
             Lane(np.array([[-h, arm], [-h, -arm]]), w, "southbound"))
    road = Road(lanes, areas=_kerbs(w, params.kerb_radius))

    def spawn(rng: np.random.Generator, agent_limit: int, gap_scale: float = 1.0) -> Spawn:
        floor = gap_floor(params)
        ego_s = arm - w - 0.5 * params.vehicle_length - rng.uniform(*params.ego_distance)
        ego_speed = rng.uniform(*params.ego_speed)
        goal_s = arm + w + rng.uniform(*params.goal_distance)
        lane, s = [], []
        for k in (EAST, WEST):
            pos = arm + place_along(rng, *params.traffic_span, params.gap, gap_scale, floor)
            lane.append(np.full(len(pos), k))
            s.append(pos)
        lane, s = np.concatenate(lane), np.concatenate(s)
        return finish_spawn(rng, params, road, lane, s, NORTH, ego_s, ego_speed, WEST, goal_s,
                            agent_limit)

    return Blueprint("intersection", params, road, spawn)
