"""CommonRoad's own verdicts on ego trajectories: goal reached, collision, off-road per time step, as JSON.

Runs inside the crime venv (``~/.cache/driveeval-bench/crime``: commonroad-io 2024.3 and
commonroad-drivability-checker 2025.3.1, made by benchmarks/nuplan_oracle/crime_ttc.py) and imports
nothing from pytest_driveeval.  The input JSON::

    {"scenario": "path.xml", "planning_problem": 100, "length": 4.508, "width": 1.61,
     "trajectories": [{"name": "...", "time_step": [...], "x": [...], "y": [...],
                       "orientation": [...], "velocity": [...]}, ...]}

(x, y: the ego box's centre).  For each trajectory and time step it answers

* ``goal``: ``planning_problem.goal.is_reached`` on a commonroad-io ``CustomState``;
* ``collision``: the drivability checker's collision checker of the scenario
  (``create_collision_checker``: every dynamic obstacle over its recorded time steps, the static ones
  always), ``time_slice(t).collide`` with the ego's ``pycrcc.RectOBB``;
  ``collision_shapely``: the same question by shapely on commonroad-io's ``occupancy_at_time`` shapes;
* ``off_road``: the ego's box not enclosed in the drivability checker's lanelet polygons
  (``create_road_polygons(method="lanelet_polygons")``, ``obb_enclosure_polygons_static``);
  ``off_road_shapely``: the box not covered by the union of ``lanelet.polygon.shapely_object``;
  ``corner_off_road``: some corner of the box outside that union (the rule pytest_driveeval rasterises);
  ``corner_edge_distance``: the smallest distance of a box corner to the union's boundary, m (how near
  the edge a verdict is); ``outside_area``: the box's area outside that union, m² (hairline gaps
  between lanelets whose shared bounds differ slightly in the file show as a few mm²);
  ``off_road_dc_buffered``: the drivability checker's enclosure in its lanelet polygons buffered by 1 mm.

    ~/.cache/driveeval-bench/crime/bin/python check_trajectory.py input.json
"""
from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import Any, Dict, List

import numpy as np
from commonroad.common.file_reader import CommonRoadFileReader
from commonroad.scenario.state import CustomState
from commonroad_dc import pycrcc
from commonroad_dc.boundary.boundary import create_road_polygons
from commonroad_dc.collision.collision_detection.pycrcc_collision_dispatch import create_collision_checker
from commonroad_dc.collision.trajectory_queries.trajectory_queries import obb_enclosure_polygons_static
from shapely.geometry import Point, Polygon
from shapely.ops import unary_union


def box(x: float, y: float, yaw: float, length: float, width: float) -> Polygon:
    c, s = math.cos(yaw), math.sin(yaw)
    local = [(0.5 * length, 0.5 * width), (-0.5 * length, 0.5 * width), (-0.5 * length, -0.5 * width),
             (0.5 * length, -0.5 * width)]
    return Polygon([(x + c * a - s * b, y + s * a + c * b) for a, b in local])


def obstacle_shapes(scenario: Any, t: int) -> List[Any]:
    shapes = []
    for obstacle in scenario.obstacles:
        occupancy = obstacle.occupancy_at_time(t)
        if occupancy is not None:
            shapes.append(occupancy.shape.shapely_object)
    return shapes


def check(request: Dict[str, Any]) -> Dict[str, Any]:
    scenario, problems = CommonRoadFileReader(request["scenario"]).open()
    problem = problems.planning_problem_dict[int(request["planning_problem"])]
    length, width = float(request["length"]), float(request["width"])
    checker = create_collision_checker(scenario)
    road_dc = create_road_polygons(scenario, method="lanelet_polygons")
    # its option that closes the hairline gaps between lanelets whose shared bound differs in the file
    road_dc_buffered = create_road_polygons(scenario, method="lanelet_polygons", buffer=1, buf_width=1e-3)
    road = unary_union([ll.polygon.shapely_object for ll in scenario.lanelet_network.lanelets])
    edge = road.boundary
    shapes_at: Dict[int, List[Any]] = {}
    out = []
    for traj in request["trajectories"]:
        verdicts: Dict[str, List[Any]] = {k: [] for k in ("goal", "collision", "collision_shapely", "off_road",
                                                         "off_road_shapely", "corner_off_road",
                                                         "corner_edge_distance", "outside_area",
                                                         "off_road_dc_buffered")}
        for t, x, y, yaw, v in zip(traj["time_step"], traj["x"], traj["y"], traj["orientation"], traj["velocity"]):
            t = int(t)
            state = CustomState(time_step=t, position=np.array([x, y], dtype=float), orientation=float(yaw),
                                velocity=float(v))
            verdicts["goal"].append(bool(problem.goal.is_reached(state)))
            ego_obb = pycrcc.RectOBB(0.5 * length, 0.5 * width, float(yaw), float(x), float(y))
            verdicts["collision"].append(bool(checker.time_slice(t).collide(ego_obb)))
            ego = box(x, y, yaw, length, width)
            if t not in shapes_at:
                shapes_at[t] = obstacle_shapes(scenario, t)
            verdicts["collision_shapely"].append(any(ego.intersects(s) for s in shapes_at[t]))
            # answers [enclosed, ...]: [True, False] inside the road, [False, False] far outside it
            verdicts["off_road"].append(not obb_enclosure_polygons_static(road_dc, ego_obb)[0])
            verdicts["off_road_dc_buffered"].append(not obb_enclosure_polygons_static(road_dc_buffered, ego_obb)[0])
            verdicts["off_road_shapely"].append(not road.covers(ego))
            verdicts["outside_area"].append(float(ego.difference(road).area))
            corners = [Point(p) for p in list(ego.exterior.coords)[:4]]
            verdicts["corner_off_road"].append(not all(road.covers(p) for p in corners))
            verdicts["corner_edge_distance"].append(min(edge.distance(p) for p in corners))
        out.append({"name": traj.get("name"), **verdicts})
    return {"scenario": str(scenario.scenario_id), "trajectories": out}


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("request", help="JSON file: scenario, planning problem, ego size, trajectories")
    args = parser.parse_args()
    print(json.dumps(check(json.loads(Path(args.request).read_text()))))
