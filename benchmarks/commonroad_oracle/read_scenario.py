"""What commonroad-io reads from a CommonRoad XML file, as JSON on stdout; runs inside the oracle's venv.

Imports nothing from pytest_driveeval. Prints lanelets (id, bounds, neighbours, speed limits from the
speed-limit signs commonroad-io makes of a 2018b <speedLimit> or reads in 2020a), obstacles (id, role,
type, shape, states by time step), planning problems (initial state, goal states) and, for each state
in the ``--states`` JSON list ({"planning_problem", "x", "y", "orientation", "velocity", "time_step"}),
commonroad-io's ``GoalRegion.is_reached``; each obstacle's occupancy outline at each of its time steps;
for each point in the ``--points`` JSON list, the lanelets ``find_lanelet_by_position`` finds there.

    ~/.cache/driveeval-bench/commonroad/bin/python read_scenario.py scenario.xml [--states s.json] [--points p.json]
"""
from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path
from typing import Any, Dict, List, Optional

import numpy as np
from commonroad.common.file_reader import CommonRoadFileReader
from commonroad.scenario.state import CustomState


def vertices(array: np.ndarray) -> List[List[float]]:
    return [[float(x), float(y)] for x, y in np.asarray(array)]


def shape_json(shape: Any) -> Any:
    """Any commonroad-io shape or occupancy (dataclasses in 2026.1) as plain JSON: shapely points as [x, y],
    shapely polygons as their exterior's vertices (closed), groups as lists."""
    if hasattr(shape, "occupancies"):
        return [shape_json(s) for s in shape.occupancies]
    if hasattr(shape, "geom_type"):  # a shapely geometry
        if shape.geom_type == "Point":
            return [float(shape.x), float(shape.y)]
        if shape.geom_type == "Polygon":
            return vertices(np.asarray(shape.exterior.coords))
        return shape.wkt
    if dataclasses.is_dataclass(shape):
        out = {"kind": type(shape).__name__}
        for f in dataclasses.fields(shape):
            out[f.name] = shape_json(getattr(shape, f.name))
        return out
    if isinstance(shape, np.ndarray):
        return shape.tolist()
    if isinstance(shape, (int, float, np.floating, np.integer)):
        return float(shape)
    return str(shape)


def number(value: Any) -> Any:
    if value is None:
        return None
    if hasattr(value, "start") and hasattr(value, "end"):
        return [float(value.start), float(value.end)]
    return float(value)


def state_json(state: Any) -> Dict[str, Any]:
    out: Dict[str, Any] = {"time_step": number(state.time_step)}
    position = getattr(state, "position", None)
    if isinstance(position, np.ndarray) or getattr(position, "geom_type", None) == "Point":
        xy = np.asarray(position.coords[0] if hasattr(position, "coords") else position, dtype=float)
        out["x"], out["y"] = float(xy[0]), float(xy[1])
    elif position is not None:
        out["position"] = shape_json(position)
    for name in ("orientation", "velocity", "acceleration", "yaw_rate", "slip_angle"):
        if name in state.attributes and getattr(state, name, None) is not None:
            out[name] = number(getattr(state, name))
    return out


def speed_limits(scenario: Any) -> Dict[int, float]:
    limits = {}
    for sign in scenario.lanelet_network.traffic_signs:
        for element in sign.traffic_sign_elements:
            # commonroad-io maps a file's sign ids onto the scenario's country (FRA: 274 becomes B14)
            if element.traffic_sign_element_id.name == "MAX_SPEED" and element.additional_values:
                limits[sign.traffic_sign_id] = float(element.additional_values[0])
    return limits


def read(path: str, states: List[Dict[str, Any]], points: List[List[float]]) -> Dict[str, Any]:
    scenario, problems = CommonRoadFileReader(path).open()
    signs = speed_limits(scenario)
    lanelets = []
    for ll in scenario.lanelet_network.lanelets:
        limit = min((signs[s] for s in ll.traffic_signs if s in signs), default=None)
        lanelets.append({
            "id": ll.lanelet_id, "left": vertices(ll.left_vertices), "right": vertices(ll.right_vertices),
            "predecessors": sorted(ll.predecessor), "successors": sorted(ll.successor),
            "adjacent_left": None if ll.adj_left is None else [ll.adj_left, bool(ll.adj_left_same_direction)],
            "adjacent_right": None if ll.adj_right is None else [ll.adj_right, bool(ll.adj_right_same_direction)],
            "speed_limit": limit})
    obstacles = []
    for obstacle in scenario.obstacles:
        states_of = [obstacle.initial_state]
        prediction = getattr(obstacle, "prediction", None)
        if prediction is not None and hasattr(prediction, "trajectory"):
            states_of += list(prediction.trajectory.state_list)
        outlines = []
        for s in states_of:
            occupancy = obstacle.occupancy_at_time(s.time_step)
            outlines.append(vertices(np.asarray(occupancy.shapely_object.exterior.coords)[:-1]))
        obstacles.append({"id": obstacle.obstacle_id, "role": obstacle.obstacle_role.value,
                          "type": obstacle.obstacle_type.value, "shape": shape_json(obstacle.obstacle_shape),
                          "states": [state_json(s) for s in states_of], "outlines": outlines})
    planning = []
    for pid, problem in problems.planning_problem_dict.items():
        lanelet_refs = problem.goal.lanelets_of_goal_position or {}
        planning.append({"id": pid, "initial": state_json(problem.initial_state),
                         "goals": [dict(state_json(g), lanelets=sorted(lanelet_refs.get(i, [])))
                                   for i, g in enumerate(problem.goal.state_list)]})
    reached: List[Optional[bool]] = []
    for s in states:
        problem = problems.planning_problem_dict[int(s["planning_problem"])]
        state = CustomState(time_step=int(s["time_step"]), position=np.array([s["x"], s["y"]], dtype=float),
                            orientation=float(s["orientation"]), velocity=float(s["velocity"]))
        reached.append(bool(problem.goal.is_reached(state)))
    on_lanelets = scenario.lanelet_network.find_lanelet_by_position([np.array(p, dtype=float) for p in points]) \
        if points else []
    return {"benchmark_id": str(scenario.scenario_id), "dt": scenario.dt, "lanelets": lanelets,
            "obstacles": obstacles, "planning_problems": planning, "goal_reached": reached,
            "lanelets_at": [sorted(int(i) for i in ids) for ids in on_lanelets]}


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("scenario")
    parser.add_argument("--states", help="JSON file: a list of states to test against their planning problem's goal")
    parser.add_argument("--points", help="JSON file: a list of [x, y] points to look lanelets up at")
    args = parser.parse_args()
    states, points = (json.loads(Path(name).read_text()) if name else [] for name in (args.states, args.points))
    print(json.dumps(read(args.scenario, states, points), default=str))
