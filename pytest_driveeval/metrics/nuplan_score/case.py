"""A score case (benchmarks/nuplan_oracle/CASE_FORMAT.md) as the score's inputs: what nuplan-devkit
and the harness are both fed when they are compared.  The score finds and blames the collisions by
nuPlan's rules (collisions.py); the engine's own (metrics.collisions, one agent at a time, each agent's
first contact) are kept in the inputs for ``blame="engine"``."""
from __future__ import annotations

import numpy as np

from pytest_driveeval.metrics.collisions import detect_collisions

from .inputs import GROUPS, AgentCells, EgoStates, ScoreInputs, first_collisions
from .lanes import ScoreMap

#: CASE_FORMAT's agent types -> the score's collision groups
GROUP_OF_TYPE = {"vehicle": 0, "pedestrian": 1, "bicycle": 1, "traffic_cone": 2, "barrier": 2, "czone_sign": 2,
                 "generic_object": 2}
STATIC_TYPES = {"traffic_cone", "barrier", "czone_sign", "generic_object"}


def _array(rows, width: int) -> np.ndarray:
    return np.asarray(rows, dtype=np.float64).reshape(-1, width)


def map_from_case(spec: dict | None) -> ScoreMap | None:
    if spec is None:
        return None
    lanes = spec.get("lanes", [])
    index = {lane["id"]: n for n, lane in enumerate(lanes)}
    limits = [np.nan if lane.get("speed_limit") is None else float(lane["speed_limit"]) for lane in lanes]
    blocks = {}
    for lane in lanes:  # lanes sharing a roadblock share its index; a lane without one has its own
        blocks.setdefault(lane.get("roadblock", ("lane", lane["id"])), len(blocks))
    counted = [lane.get("drivable") for lane in lanes]
    return ScoreMap(lane_ids=[lane["id"] for lane in lanes],
                    polygons=[_array(lane["polygon"], 2) for lane in lanes],
                    baselines=[_array(lane["baseline"], 2) for lane in lanes],
                    speed_limits=np.array(limits), connector=[bool(lane.get("connector")) for lane in lanes],
                    outgoing=[[index[o] for o in lane.get("outgoing", []) if o in index] for lane in lanes],
                    drivable=[_array(p, 2) for p in spec.get("drivable_area", [])],
                    intersections=[_array(p, 2) for p in spec.get("intersections", [])],
                    roadblock=[blocks[lane.get("roadblock", ("lane", lane["id"]))] for lane in lanes],
                    drivable_outlines=[_array(p, 2) for p in spec.get("drivable_outlines", [])],
                    road_edges=[_array(p, 2) for p in spec.get("road_edges", [])],
                    lane_drivable=None if all(c is None or c for c in counted) else [c is not False for c in counted])


def agents_from_case(specs: list[dict], frames: int) -> AgentCells:
    if not specs:
        return AgentCells.empty(frames)
    a = len(specs)
    cells = AgentCells(xy=np.zeros((frames, a, 2)), yaw=np.zeros((frames, a)), length=np.zeros((frames, a)),
                       width=np.zeros((frames, a)),
                       velocity=np.zeros((frames, a, 2)), available=np.zeros((frames, a), bool),
                       token=np.full((frames, a), -1, np.int64), group=np.zeros((frames, a), np.int8),
                       static=np.zeros((frames, a), bool))
    for column, spec in enumerate(specs):
        rows = np.asarray(spec["frames"], dtype=np.int64)
        center = _array(spec["center"], 3)
        cells.xy[rows, column], cells.yaw[rows, column] = center[:, :2], center[:, 2]
        cells.velocity[rows, column] = _array(spec.get("velocity", np.zeros((len(rows), 2))), 2)
        cells.length[rows, column], cells.width[rows, column] = spec["length"], spec["width"]
        cells.available[rows, column] = True
        cells.token[rows, column] = column
        cells.group[rows, column] = GROUP_OF_TYPE[spec["type"]]
        cells.static[rows, column] = spec["type"] in STATIC_TYPES
    return cells


def inputs_from_case(case: dict) -> ScoreInputs:
    times = np.asarray(case["timestamps"], dtype=np.float64)
    e = case["ego"]
    center = _array(e["center"], 3)
    ego = EgoStates(center, float(e["length"]), float(e["width"]), float(e["rear_axle_to_center"]),
                    _array(e["velocity"], 2), _array(e["acceleration"], 2),
                    np.asarray(e["angular_velocity"], dtype=np.float64),
                    np.asarray(e["angular_acceleration"], dtype=np.float64))
    agents = agents_from_case(case.get("agents", []), len(times))
    h = center[:, 2]
    world_velocity = np.stack([np.cos(h) * ego.velocity[:, 0] - np.sin(h) * ego.velocity[:, 1],
                               np.sin(h) * ego.velocity[:, 0] + np.cos(h) * ego.velocity[:, 1]], axis=1)
    records = []
    for column in range(agents.token.shape[1]):
        found = detect_collisions(center[:, :2], h, np.array([ego.length, ego.width]),
                                  agents.xy[:, column:column + 1], agents.yaw[:, column:column + 1],
                                  np.stack([agents.length[:, column:column + 1], agents.width[:, column:column + 1]], -1),
                                  agents.available[:, column:column + 1],
                                  np.where(agents.static[:, column:column + 1, None], 0.0,
                                           agents.velocity[:, column:column + 1]),
                                  world_velocity)
        for k in np.flatnonzero(found.kind > 0):
            records.append((int(k), column, bool(found.at_fault[k])))
    records.sort()
    groups = {c: GROUPS[GROUP_OF_TYPE[s["type"]]] for c, s in enumerate(case.get("agents", []))}
    collisions = first_collisions([r[0] for r in records], [r[1] for r in records], [r[2] for r in records], groups)
    return ScoreInputs(times, ego, _array(case["expert"]["center"], 3), agents, collisions,
                       map_from_case(case.get("map")))


def answer(case: dict) -> dict:
    """The harness's score of a case in the oracle's answer format (CASE_FORMAT.md, "What the oracle
    answers"), so that the two compare key by key."""
    from .score import score_scene

    result = score_scene(inputs_from_case(case))
    ttc = result.terms["time_to_collision_within_bound"].series["time_to_collision"]
    comfort = result.terms["ego_is_comfortable"].series
    return {"name": case.get("name"), "score": result.score,
            "metrics": {name: term.used for name, term in result.terms.items()},
            "comfort": {signal: [float(v.min()), float(v.max())] for signal, v in comfort.items()},
            "min_time_to_collision": None if not np.isfinite(ttc.min()) else float(ttc.min()),
            "time_to_collision": [None if not np.isfinite(v) else float(v) for v in ttc]}


TYPE_OF_GROUP = {0: "vehicle", 1: "pedestrian", 2: "generic_object"}


def case_from_inputs(inputs: ScoreInputs, name: str, *, lanes_as_connectors: bool = False) -> dict:
    """A scene's score inputs as a case, to feed nuplan-devkit the very numbers the harness scores: the
    map's lanes, connectors, lane graph and roadblocks (a roadblock's outline is the union of its lanes'
    ``polygons``), its drivable outlines (even-odd rings) and road edges, and which lanes' surfaces are
    part of the drivable area.  ``lanes_as_connectors`` makes every lane a lane connector in a roadblock of
    its own (the hand-made cases' maps)."""
    ego, agents = inputs.ego, inputs.agents
    specs = []
    for token in np.unique(agents.token[agents.available]):
        rows, cols = np.nonzero(agents.available & (agents.token == token))
        specs.append({"token": str(int(token)), "type": TYPE_OF_GROUP[int(agents.group[rows[0], cols[0]])],
                      "length": float(agents.length[rows[0], cols[0]]), "width": float(agents.width[rows[0], cols[0]]),
                      "frames": rows.tolist(), "center": agents.center[rows, cols].tolist(),
                      "velocity": agents.velocity[rows, cols].tolist()})
    return {"name": name, "timestamps": inputs.times.tolist(),
            "ego": {"length": ego.length, "width": ego.width, "rear_axle_to_center": ego.rear_axle_to_center,
                    "center": ego.center.tolist(), "velocity": ego.velocity.tolist(),
                    "acceleration": ego.acceleration.tolist(), "angular_velocity": ego.angular_velocity.tolist(),
                    "angular_acceleration": ego.angular_acceleration.tolist()},
            "expert": {"center": inputs.expert.tolist()}, "agents": specs,
            "map": None if inputs.map is None else _map_spec(inputs.map, lanes_as_connectors)}


def _map_spec(score_map: ScoreMap, lanes_as_connectors: bool) -> dict:
    ids = score_map.lane_ids
    incoming = [[ids[m] for m in before] for before in score_map.incoming]
    outgoing = [[ids[m] for m in ahead] for ahead in score_map.outgoing]
    connector = [lanes_as_connectors or bool(c) for c in score_map.connector]
    block = np.arange(len(ids)) if lanes_as_connectors else score_map.roadblock
    for n, lane in enumerate(ids):
        if connector[n] and not incoming[n] and not outgoing[n]:
            # nuPlan's speed limit on connectors is the max over their edges' limits, and max() of none
            # raises; its maps have no connector without edges, ScenarioNet's nuScenes lanes have no edges
            # at all.  Its own edge gives it its own limit, as a lane has, and changes no route: a lane
            # the ego left is not among the lanes holding it now.
            incoming[n], outgoing[n] = [lane], [lane]
    counted = (np.ones(len(ids), dtype=bool) if score_map.lane_drivable is None else score_map.lane_drivable)
    members: dict[int, list[int]] = {}
    for n, b in enumerate(block):
        members.setdefault(int(b), []).append(n)
    return {"lanes": [{"id": lane, "polygon": score_map.polygons[n].tolist(),
                       "baseline": score_map.baselines[n].tolist(),
                       "speed_limit": None if not np.isfinite(score_map.speed_limits[n])
                       else float(score_map.speed_limits[n]),
                       "roadblock": f"rb-{ids[members[int(block[n])][0]]}", "connector": connector[n],
                       "incoming": incoming[n], "outgoing": outgoing[n], "drivable": bool(counted[n])}
                      for n, lane in enumerate(ids)],
            "roadblocks": [{"id": f"rb-{ids[lanes[0]]}", "polygons": [score_map.polygons[n].tolist() for n in lanes],
                            "connector": connector[lanes[0]]} for lanes in members.values()],
            # the lanes' surfaces that count, and the map's other drivable polygons (driveways)
            "drivable_area": [score_map.polygons[n].tolist() for n in np.flatnonzero(counted)]
            + [p.tolist() for p in score_map.drivable_beyond_lanes],
            "drivable_outlines": [p.tolist() for p in score_map.drivable_outlines],
            "road_edges": [p.tolist() for p in score_map.road_edges],
            "intersections": [p.tolist() for p in score_map.intersections]}
