"""What the CommonRoad reader read, skipped and assumed in one file, and why: ``CommonRoadScenario.notes``.

A data check prints these lines (``ReadNote.render``); a test or a tool reads their fields.  Each kind
of element the benchmark does not use is counted once, with its reason; nothing here changes what was
read.
"""
from __future__ import annotations

import xml.etree.ElementTree as ET

from .commonroad_states import StateReader
from .commonroad_types import CommonRoadScenario, ReadNote
from .commonroad_xml import XmlDoc

__all__ = ["read_notes", "SKIPPED"]

#: top-level elements not used, and why
SKIPPED = {
    "environmentObstacle": "buildings, vegetation and other surroundings: the lanelets bound where the ego may "
                           "drive, so these are neither replayed nor collided with",
    "phantomObstacle": "hypothetical traffic behind occlusions, given by occupancy sets: not recorded traffic, "
                       "not replayed",
    "trafficLight": "the benchmark replays the recorded traffic and does not check the ego against lights",
    "intersection": "the intersections' lanelet groups: the lanelets themselves are read",
    "location": "geographic location and environment: not used",
    "scenarioTags": "tags: not used",
}


def _first(doc: XmlDoc, nodes: list[ET.Element]) -> int | None:
    return min((doc.lines.get(n, 0) for n in nodes), default=None) or None


def read_notes(doc: XmlDoc, root: ET.Element, scenario: CommonRoadScenario, states: StateReader) -> list[ReadNote]:
    notes: list[ReadNote] = []
    obstacles = list(scenario.obstacles.values())
    set_based = [o for o in obstacles if o.set_based]
    notes.append(ReadNote("read", "<lanelet>", len(scenario.lanelets), "bounds, neighbours and speed limits: the "
                          "road and its drivable area"))
    if obstacles:
        notes.append(ReadNote("read", "obstacles", len(obstacles),
                              f"{len(scenario.dynamic_obstacles())} dynamic, {len(scenario.static_obstacles())} "
                              "static, replayed at their recorded states and collided with"))
    if set_based:
        notes.append(ReadNote("read", "obstacles given by <occupancySet>", len(set_based),
                              "a collision with one is a collision with the shapes it occupies at that time step; "
                              "present at its initial state (its shape there, as commonroad-io) and at the steps its occupancies cover"))
    notes.append(ReadNote("read", "<planningProblem>", len(scenario.planning_problems),
                          "each one an item of the CommonRoad benchmark" if scenario.planning_problems
                          else "none: the file has no problem to drive, so the benchmark cannot run it"))
    for what, count in sorted(states.set_valued.items()):
        notes.append(ReadNote("assumed", f"states with {what}", count,
                              "replayed at the set's middle (a shape's centre, an interval's midpoint), as "
                              "commonroad-io's Shape.center; collisions take the whole set",
                              states.first_line.get(what)))
    if states.point_mass:
        notes.append(ReadNote("assumed", "point-mass states (velocity, velocityY, no orientation)", states.point_mass,
                              "heading atan2(velocityY, velocity) and speed their norm, as commonroad-io's PMState",
                              states.first_line.get("point mass")))
    for tag, count in sorted(states.unused.items()):
        notes.append(ReadNote("skipped", f"<{tag}> of states", count,
                              "not used by the replay (position, heading, speed and time are)",
                              states.first_line.get(tag)))
    for tag, why in SKIPPED.items():
        nodes = root.findall(tag)
        if nodes:
            notes.append(ReadNote("skipped", f"<{tag}>", len(nodes), why, _first(doc, nodes)))
    signs = root.findall("trafficSign")
    if signs:
        notes.append(ReadNote("read", "<trafficSign>", len(signs), "speed limits (German 274, US R2-1) only; other "
                              "signs are not checked", _first(doc, signs)))
    signals = [n for tag in ("initialSignalState", "signalSeries") for n in root.iter(tag)]
    if signals:
        notes.append(ReadNote("skipped", "signal states (indicators, brake lights)", len(signals),
                              "not used by the replay", _first(doc, signals)))
    heights = [n for n in root.iter("z")]
    if heights:
        notes.append(ReadNote("skipped", "<z> coordinates", len(heights),
                              "the benchmark is planar: points are read as (x, y)", _first(doc, heights)))
    return notes
