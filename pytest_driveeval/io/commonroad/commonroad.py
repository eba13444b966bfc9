"""Read CommonRoad benchmark scenarios (XML, formats 2018b and 2020a) into plain numpy arrays.

Why not commonroad-io: it pins protobuf 3.20.2 and brings rtree, omegaconf, networkx, lxml, iso3166
and the vehicle models, which would constrain every user's environment (ray's protobuf among them).
So the package reads the XML itself with the standard library's expat (no external entities, no DTD
loading) and commonroad-io runs only in its own venv as the oracle of what we read
(benchmarks/commonroad_oracle/, tests/io/test_commonroad_oracle.py).

The two formats differ where it matters here: 2018b writes ``<obstacle>`` with ``<role>`` and
``<type>`` and a lanelet's ``<speedLimit>``; 2020a writes ``<dynamicObstacle>`` / ``<staticObstacle>``
and speed limits as ``<trafficSign>`` elements (German sign 274 with the limit as additional value)
that lanelets name by ``<trafficSignRef>``.  Read and kept: lanelet bounds and neighbours, obstacles
with their shape and states, planning problems with their goal states.  Skipped: line markings,
lanelet types, intersections, traffic lights, signs other than speed limits, environment and phantom
obstacles, signal states, z coordinates and the location: each is counted with its reason in the
scenario's ``notes`` (:class:`~.commonroad_types.ReadNote`; commonroad_notes), the list a data check
prints.  Set-valued states (a shape as position, intervals as values) are read at their middle with
their sets kept, and obstacles given by an ``<occupancySet>`` by their occupied shapes per time step
(commonroad_states).

An obstacle's states must cover consecutive time steps once each (in any order: they are sorted);
a gap or a repeated step is an error naming the obstacle and the step, since a replay needs every step.
A goal state is an error when it holds a ``<position>`` with no shape or lanelet in it, or when it
constrains nothing at all; a goal state without ``<position>`` (FRA_Anglet-1_1_T-1: time only) is
valid, as in CommonRoad: it is reached by time (and speed, heading) wherever the ego is.
"""
from __future__ import annotations

import math
import os
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from ...core.errors import display_path
from .commonroad_notes import read_notes
from .commonroad_states import StateReader
from .commonroad_types import (CommonRoadError, CommonRoadScenario, GoalState, Lanelet, Neighbour, Obstacle,
                               PlanningProblem, Shape, State, Trajectory)
from .commonroad_xml import XmlDoc, parse_xml

__all__ = ["read_commonroad", "planning_problem", "no_problem_message", "CommonRoadError"]

VERSIONS = ("2018b", "2020a")
SPEED_LIMIT_SIGNS = {"274", "R2-1"}  # German "Zulässige Höchstgeschwindigkeit" and the US speed limit sign


def read_commonroad(path: str | os.PathLike) -> CommonRoadScenario:
    """The scenario, lanelets, obstacles and planning problems of a CommonRoad XML file."""
    path = Path(path)
    root, doc = parse_xml(path)
    if root.tag != "commonRoad":
        raise doc.error(root, "not a CommonRoad file: the root element is not <commonRoad>")
    version = root.get("commonRoadVersion")
    if version not in VERSIONS:
        raise doc.error(root, f"unknown commonRoadVersion {version!r}: this reader knows {', '.join(VERSIONS)}")
    dt = doc.number(root, root.get("timeStepSize"), "timeStepSize")
    if not dt > 0:
        raise doc.error(root, f"timeStepSize: expected the seconds of one time step, above 0, got {dt:g}: "
                              "give the step of the recording (CommonRoad's benchmarks: 0.1)")
    lanelets = _lanelets(doc, root)
    states = StateReader(doc, lanelets)
    obstacles = _obstacles(doc, root, version, states)
    problems: dict[int, PlanningProblem] = {}
    for node in root.findall("planningProblem"):
        problem = PlanningProblem(doc.ident(node), states.state(node.find("initialState"), node),
                                  tuple(_goal(doc, g, node, lanelets) for g in node.findall("goalState")))
        if not problem.goals:
            raise doc.error(node, "planning problem without <goalState>")
        if problem.id in problems or problem.id in lanelets or problem.id in obstacles:
            raise doc.error(node, f"id {problem.id} is used twice")
        problems[problem.id] = problem
    scenario = CommonRoadScenario(path, root.get("benchmarkID", ""), version, dt, lanelets, obstacles, problems)
    scenario.notes.extend(read_notes(doc, root, scenario, states))
    return scenario


def planning_problem(scenario: CommonRoadScenario, problem_id: int | str) -> PlanningProblem:
    """The planning problem ``problem_id``; an error listing the ids there are when it is not in the file."""
    if not scenario.planning_problems:
        raise CommonRoadError(no_problem_message(scenario))
    try:
        return scenario.planning_problems[int(problem_id)]
    except (KeyError, ValueError):
        have = ", ".join(str(i) for i in scenario.planning_problems)
        raise CommonRoadError(f"{display_path(scenario.path)}: no planning problem with id {problem_id!r} "
                              f"(the file has: {have})") from None


def no_problem_message(scenario: CommonRoadScenario) -> str:
    """Why a file without a planning problem cannot be driven, naming it."""
    holds = f"{len(scenario.lanelets)} lanelet(s) and {len(scenario.obstacles)} obstacle(s)"
    return (f"{display_path(scenario.path)} has no <planningProblem> (it holds {holds} only): the benchmark "
            "drives an ego from a planning problem's initial state to its goal, so this file cannot be driven; "
            "name a scenario file that has one")


# ---------------------------------------------------------------- lanelets

def _neighbour(doc: XmlDoc, node: ET.Element | None) -> Neighbour | None:
    if node is None:
        return None
    return Neighbour(int(doc.number(node, node.get("ref"), "ref")), node.get("drivingDir", "same") == "same")


def _speed_limit_signs(doc: XmlDoc, root: ET.Element) -> dict[int, float]:
    limits = {}
    for sign in root.findall("trafficSign"):
        for element in sign.findall("trafficSignElement"):
            if (element.findtext("trafficSignID") or "").strip() in SPEED_LIMIT_SIGNS:
                value = element.find("additionalValue")
                if value is not None:
                    limits[doc.ident(sign)] = doc.number(value, value.text, "additionalValue")
    return limits


def _lanelets(doc: XmlDoc, root: ET.Element) -> dict[int, Lanelet]:
    signs = _speed_limit_signs(doc, root)
    lanelets: dict[int, Lanelet] = {}
    for node in root.findall("lanelet"):
        ident = doc.ident(node)
        if ident in lanelets:
            raise doc.error(node, f"lanelet id {ident} is used twice")
        left = doc.points(node.find("leftBound"), node, "leftBound")
        right = doc.points(node.find("rightBound"), node, "rightBound")
        if len(left) != len(right) or len(left) < 2:
            raise doc.error(node, f"left bound has {len(left)} points, right bound {len(right)}: "
                                  "both need the same count, at least 2")
        refs = tuple(int(doc.number(r, r.get("ref"), "ref")) for r in node.findall("trafficSignRef"))
        limit = node.find("speedLimit")
        speed = (doc.number(limit, limit.text, "speedLimit") if limit is not None
                 else min((signs[r] for r in refs if r in signs), default=None))
        lanelets[ident] = Lanelet(
            ident, left, right,
            tuple(int(doc.number(r, r.get("ref"), "ref")) for r in node.findall("predecessor")),
            tuple(int(doc.number(r, r.get("ref"), "ref")) for r in node.findall("successor")),
            _neighbour(doc, node.find("adjacentLeft")), _neighbour(doc, node.find("adjacentRight")), speed, refs)
    for node in root.findall("lanelet"):
        ll = lanelets[doc.ident(node)]
        named = [*ll.predecessors, *ll.successors] + [n.id for n in (ll.adjacent_left, ll.adjacent_right) if n]
        missing = sorted({i for i in named if i not in lanelets})
        if missing:
            raise doc.error(node, f"names lanelet(s) {missing} that the file does not define")
    return lanelets


# ---------------------------------------------------------------- obstacles

def _trajectory(doc: XmlDoc, node: ET.Element, states: list[State]) -> Trajectory:
    states = sorted(states, key=lambda s: s.time_step)
    steps = [s.time_step for s in states]
    for a, b in zip(steps, steps[1:]):
        if b == a:
            raise doc.error(node, f"time step {a} is given twice")
        if b != a + 1:
            raise doc.error(node, f"no state at time step {a + 1} (states jump from {a} to {b})")
    column = lambda name: np.array([getattr(s, name) for s in states], dtype=np.float64)
    return Trajectory(np.array(steps, dtype=np.int64), column("x"), column("y"), column("orientation"),
                      column("velocity"), column("acceleration"),
                      {s.time_step: s.set for s in states if s.set is not None})


def _obstacle(doc: XmlDoc, node: ET.Element, role: str, states: StateReader) -> Obstacle:
    ident = doc.ident(node)
    shape_node = node.find("shape")
    shapes = doc.shapes(shape_node) if shape_node is not None else []
    if len(shapes) != 1:
        raise doc.error(node, f"needs one shape (rectangle, circle or polygon), found {len(shapes)}")
    initial = states.state(node.find("initialState"), node)
    kind = (node.findtext("type") or "").strip() or "unknown"
    trajectory = node.find("trajectory")
    occupancy_set = node.find("occupancySet")
    if role == "dynamic" and trajectory is None and occupancy_set is not None:
        return Obstacle(ident, role, kind, shapes[0], initial, _trajectory(doc, node, [initial]),
                        states.occupancies(occupancy_set, node))
    all_states = [initial]
    if role == "dynamic":
        if trajectory is None or trajectory.find("state") is None:
            raise doc.error(node, "dynamic obstacle with an empty or missing <trajectory> (and no <occupancySet>)")
        all_states += [states.state(s, node) for s in trajectory.findall("state")]
    return Obstacle(ident, role, kind, shapes[0], initial, _trajectory(doc, node, all_states))


def _obstacles(doc: XmlDoc, root: ET.Element, version: str, states: StateReader) -> dict[int, Obstacle]:
    found: list[tuple[ET.Element, str]] = []
    if version == "2018b":
        for node in root.findall("obstacle"):
            role = (node.findtext("role") or "").strip()
            if role not in ("dynamic", "static"):
                raise doc.error(node, f"<role> must be dynamic or static, got {role!r}")
            found.append((node, role))
    else:
        found = [(n, "dynamic") for n in root.findall("dynamicObstacle")]
        found += [(n, "static") for n in root.findall("staticObstacle")]
    obstacles: dict[int, Obstacle] = {}
    for node, role in sorted(found, key=lambda f: doc.lines.get(f[0], 0)):
        obstacle = _obstacle(doc, node, role, states)
        if obstacle.id in obstacles:
            raise doc.error(node, f"obstacle id {obstacle.id} is used twice")
        obstacles[obstacle.id] = obstacle
    return obstacles


# ---------------------------------------------------------------- goals

def _goal(doc: XmlDoc, node: ET.Element, problem: ET.Element, lanelets: dict[int, Lanelet]) -> GoalState:
    # A goal state has no id of its own: messages name its planning problem and the goal state's line.
    owner = problem
    at = f"goal state at line {doc.lines.get(node, '?')}: "
    shapes: list[Shape] = []
    refs: tuple[int, ...] = ()
    position = node.find("position")
    if position is not None:
        shapes = doc.shapes(position)
        refs = tuple(int(doc.number(r, r.get("ref"), "ref")) for r in position.findall("lanelet"))
        if not shapes and not refs:
            raise doc.error(owner, f"{at}goal <position> holds no shape (rectangle, circle, polygon) and no lanelet")
        missing = [r for r in refs if r not in lanelets]
        if missing:
            raise doc.error(owner, f"{at}goal position names lanelet(s) {missing} that the file does not define")
    orientation = doc.value(node.find("orientation"), owner, exact=False)
    velocity = doc.value(node.find("velocity"), owner, exact=False)
    time = doc.value(node.find("time"), owner, exact=False)
    if not (shapes or refs) and orientation is velocity is time is None:
        raise doc.error(owner, f"{at}goal state constrains nothing: no position, orientation, velocity or time")
    if orientation is not None and not orientation.end - orientation.start < 2 * math.pi:
        raise doc.error(owner, f"{at}orientation interval [{orientation.start}, {orientation.end}] spans 2 pi or more")
    return GoalState(tuple(shapes), refs, tuple(lanelets[r].polygon for r in refs), orientation, velocity, time)
