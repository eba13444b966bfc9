"""Plausible synthetic l5kit scenes for demos and tests.

One road layout is shared by all scenes of a call (see :func:`road_layout`):
a main road with two eastbound lanes and one westbound lane that runs straight
and then bends left, a bike lane and two sidewalks alongside it, and a
northbound road crossing it at a signalised junction.  Every road user,
the ego included, moves along one lane with the Intelligent Driver Model,
so it keeps its distance to the one ahead and stops for red lights.  Per scene
the traffic, the ego's speeds and the signal timing are drawn from the seed;
in a share of scenes (``red_light_fraction``) the signal is timed so the ego
must stop at the junction.

Public API::

    arrays = generate_scenes(num_scenes, num_frames=100, seed=0, **knobs)  # L5Arrays
    generate_zarr(path, num_scenes, num_frames=100, seed=0, **knobs)       # writes a store, its map and meta.json
    road_layout() -> dict of lane name -> (N, 2) centerline, travel direction order
    semantic_map(num_frames=100, **knobs) -> SemanticMap                    # the layout as an L5 semantic map
    boxes_overlap(...)  # vectorised oriented-box overlap test

Scenes are rejected and redrawn (deterministically) if any agent box overlaps
the ego box, so the logged ego trajectory is collision-free by construction.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pytest_driveeval.geometry import oriented_boxes_overlap, yaw_as_rotation33
from pytest_driveeval.io.l5.l5_semantic_map import (GREEN, RED, YELLOW, Polylines, SemanticMap, encode_semantic_map,
                                                  write_semantic_map)
from pytest_driveeval.io.l5.l5kit_zarr import (
    AGENT_DTYPE,
    FRAME_DTYPE,
    SCENE_DTYPE,
    TL_FACE_DTYPE,
    L5Arrays,
    label_index,
    write_l5_zarr,
)

__all__ = ["EGO_EXTENT", "WORLD_TO_ECEF", "generate_scenes", "generate_zarr", "road_layout", "semantic_map"]

DT = 0.1  # l5kit logs at 10 Hz
EGO_EXTENT = np.array([4.869, 1.852, 1.61])  # l5kit's ego dimensions (length, width, height)
LANE_WIDTH = 3.5
START_TIME_NS = 1_600_000_000_000_000_000
# The world frame of the Lyft Level 5 dataset (its meta.json, as in l5kit's test
# artefacts): generated scenes sit in the same frame as the real ones, so one
# meta.json beside both kinds of zarr is right for either.
WORLD_TO_ECEF = np.array([
    [0.846617444, 0.323463078, -0.422623402, -2698767.44],
    [-0.532201938, 0.514559352, -0.672301845, -4293151.58],
    [-3.05311332e-16, 0.794103464, 0.6077826, 3855164.76],
    [0.0, 0.0, 0.0, 1.0],
])
_MAX_ATTEMPTS = 20
_STOP_MARGIN = 2.5  # stop line to the crossing lane's edge, room for a crosswalk

# Signal phases, seconds.
AMBER, ALL_RED = 3.0, 2.0
# Lateral offsets (m, left positive) from the eastbound reference lane.
_OFFSETS = {"east_0": 0.0, "east_1": LANE_WIDTH, "west_0": 2 * LANE_WIDTH, "bike_east": -3.0,
            "walk_south": -5.5, "walk_north": 2 * LANE_WIDTH + 5.0}


@dataclass(frozen=True)
class _Kind:
    label: str
    extent: tuple[float, float, float]  # mean length, width, height
    speed: tuple[float, float]  # desired speed range, m/s
    accel: float  # IDM maximum acceleration
    decel: float  # IDM comfortable deceleration
    min_gap: float  # IDM standstill distance
    headway: float  # IDM time headway, s


_CAR = _Kind("CAR", (4.5, 1.9, 1.6), (10.0, 15.0), 1.5, 2.5, 2.0, 1.4)
_CYCLIST = _Kind("CYCLIST", (1.8, 0.6, 1.7), (3.5, 6.0), 1.0, 2.0, 1.0, 1.0)
_PEDESTRIAN = _Kind("PEDESTRIAN", (0.6, 0.6, 1.75), (1.0, 1.6), 0.8, 1.5, 0.5, 0.8)
_EGO = _Kind("CAR", tuple(EGO_EXTENT), (11.0, 14.0), 1.8, 2.5, 2.0, 1.4)


@dataclass(frozen=True)
class _Lane:
    name: str
    points: np.ndarray  # (N, 2) centerline in travel direction
    arclength: np.ndarray  # (N,)
    kind: _Kind
    light: str  # which signal governs it: "main" or "cross"
    stop_s: float  # arclength of its stop line
    density: float  # road users per metre


def _reference_line(length: float, straight: float, radius: float, bend: float, spacing: float = 0.5):
    """Points, headings of a line going +x, then bending left by ``bend`` rad, then straight."""
    s = np.arange(0.0, length + spacing, spacing)
    heading = np.clip((s - straight) / radius, 0.0, bend)
    # Integrate heading exactly piecewise so offsets stay parallel on the bend.
    ds = np.diff(s, prepend=s[0])
    mid_heading = np.concatenate([[0.0], 0.5 * (heading[1:] + heading[:-1])])
    x = np.cumsum(ds * np.cos(mid_heading))
    y = np.cumsum(ds * np.sin(mid_heading))
    return np.stack([x, y], axis=1), heading


def _polyline(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    seg = np.linalg.norm(np.diff(points, axis=0), axis=1)
    return points, np.concatenate([[0.0], np.cumsum(seg)])


def _build_lanes(length: float, knobs: dict) -> tuple[list[_Lane], float]:
    """Lanes and the x of the junction (on the straight part of the main road)."""
    # The junction's stop lines assume a straight road there; the bend comes after it.
    straight = max(0.55 * length, knobs["junction_at"] + 60.0)
    length = max(length, straight + knobs["bend_radius"] * np.radians(knobs["bend_degrees"]) + 100.0)
    ref, heading = _reference_line(length, straight, knobs["bend_radius"], np.radians(knobs["bend_degrees"]))
    normal = np.stack([-np.sin(heading), np.cos(heading)], axis=1)
    junction_x = knobs["junction_at"]
    if junction_x < 100.0:  # the ego starts up to 90 m before it
        raise ValueError(f"junction_at={junction_x}: must be at least 100 m from the start of the road")
    half_cross = LANE_WIDTH / 2
    lanes = []
    for name, offset in _OFFSETS.items():
        pts, s = _polyline(ref + offset * normal)
        eastbound = name != "west_0" and name != "walk_north"
        if not eastbound:
            pts, s = _polyline(pts[::-1])
        kind = _PEDESTRIAN if name.startswith("walk") else _CYCLIST if name.startswith("bike") else _CAR
        # Stop line: just before the crossing lane (plus a margin for the crosswalk).
        margin = 1.0 if kind is _PEDESTRIAN else _STOP_MARGIN
        stop_x = junction_x - half_cross - margin if eastbound else junction_x + half_cross + margin
        # Junction lies on the straight part, so arclength maps to x linearly there.
        stop_s = stop_x if eastbound else s[-1] - stop_x
        density = {"walk_south": 0.02, "walk_north": 0.02, "bike_east": 0.008}.get(name, knobs["car_density"])
        lanes.append(_Lane(name, pts, s, kind, "main", float(stop_s), density))
    # The crossing road, northbound through the junction; its stop line clears the south sidewalk.
    cross_len = 2 * knobs["cross_half_length"]
    y = np.arange(-knobs["cross_half_length"], knobs["cross_half_length"] + 0.5, 0.5)
    pts, s = _polyline(np.stack([np.full_like(y, junction_x), y], axis=1))
    stop_y = _OFFSETS["walk_south"] - 1.5
    lanes.append(_Lane("cross_north", pts, s, _CAR, "cross", float(stop_y + cross_len / 2), knobs["car_density"]))
    return lanes, junction_x


def road_layout(num_frames: int = 100, **knobs) -> dict:
    """Centerlines used by :func:`generate_scenes` with the same arguments.

    Returns ``{"lanes": {name: (N, 2) array}, "stop_lines": {name: (x, y)},
    "junction": (x, y)}``; lane points run in the travel direction.
    """
    knobs = _knobs(knobs)
    lanes, junction_x = _build_lanes(_lane_length(num_frames, knobs), knobs)
    return {
        "lanes": {lane.name: lane.points for lane in lanes},
        "stop_lines": {lane.name: tuple(float(v) for v in _at(lane, np.array([lane.stop_s]))[0][0]) for lane in lanes},
        "junction": (float(junction_x), 0.0),
    }


_DEFAULT_KNOBS = dict(
    host="host-synth",
    red_light_fraction=0.5,  # share of scenes where the ego meets a red light
    car_density=1 / 30,  # cars per metre of lane
    perception_range=50.0,  # agents farther than this from the ego are not logged
    junction_at=250.0,  # x of the junction; the ego starts 50-90 m before it
    bend_radius=150.0,
    bend_degrees=35.0,
    cross_half_length=150.0,
    extent_jitter=0.06,  # relative std of agent sizes
)


def _knobs(knobs: dict) -> dict:
    unknown = set(knobs) - set(_DEFAULT_KNOBS)
    if unknown:
        raise TypeError(f"unknown scene generator knob(s) {sorted(unknown)}; known: {sorted(_DEFAULT_KNOBS)}")
    return {**_DEFAULT_KNOBS, **knobs}


def _lane_length(num_frames: int, knobs: dict) -> float:
    # Long enough that nobody the ego can see runs off either end during the scene.
    return knobs["junction_at"] + 20.0 * num_frames * DT + 200.0


def _at(lane: _Lane, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Positions (..., 2) and headings (...) at arclengths ``s`` (extrapolated straight past the ends)."""
    seg = np.clip(np.searchsorted(lane.arclength, s, side="right") - 1, 0, len(lane.arclength) - 2)
    p0, p1 = lane.points[seg], lane.points[seg + 1]
    d = p1 - p0
    seg_len = np.linalg.norm(d, axis=-1)
    frac = (s - lane.arclength[seg]) / seg_len
    pos = p0 + frac[..., None] * d
    return pos, np.arctan2(d[..., 1], d[..., 0])


def _signal_states(t: np.ndarray, cycle: dict) -> dict[str, np.ndarray]:
    """0 green, 1 amber, 2 red for each signal at times ``t`` (s)."""
    g1, g2 = cycle["main_green"], cycle["cross_green"]
    period = g1 + g2 + 2 * (AMBER + ALL_RED)
    tau = np.mod(t + cycle["phase"], period)
    main = np.where(tau < g1, 0, np.where(tau < g1 + AMBER, 1, 2))
    c0 = g1 + AMBER + ALL_RED
    cross = np.where((tau >= c0) & (tau < c0 + g2), 0, np.where((tau >= c0 + g2) & (tau < c0 + g2 + AMBER), 1, 2))
    return {"main": main, "cross": cross}


def _simulate(lane_id, s0, v0, v_desired, params, length, stop_s, light_state, num_frames):
    """IDM on 1-D lanes; returns arclength and speed, each (T, N).

    ``light_state`` is (T, N): 0 green, 1 amber, 2 red for each road user's signal.
    """
    n = s0.size
    s, v = s0.astype(float).copy(), v0.astype(float).copy()
    accel, decel, gap0, headway = params.T
    out_s, out_v = np.empty((num_frames, n)), np.empty((num_frames, n))
    decision = np.zeros(n, dtype=np.int8)  # 0 undecided, 1 stop at the line, 2 go (too late to stop)
    for t in range(num_frames):
        out_s[t], out_v[t] = s, v
        order = np.lexsort((s, lane_id))
        l_o = lane_id[order]
        has_leader = np.append(l_o[1:] == l_o[:-1], False)
        leader = np.empty(n, dtype=int)
        leader[order] = np.where(has_leader, np.append(order[1:], 0), -1)
        ok = leader >= 0
        gap = np.full(n, np.inf)
        gap[ok] = s[leader[ok]] - s[ok] - 0.5 * (length[leader[ok]] + length[ok])
        v_lead = np.where(ok, v[np.maximum(leader, 0)], v)
        # Signals: decide once per amber/red, stop if comfortably possible, else commit to go.
        front_gap = stop_s - s - 0.5 * length
        before_line = front_gap > 0
        green = light_state[t] == 0
        decision[green] = 0
        undecided = ~green & (decision == 0) & before_line
        can_stop = front_gap >= v * v / (2 * decel) + 0.5
        decision[undecided] = np.where(can_stop[undecided], 1, 2)
        stopping = (decision == 1) & before_line
        gap = np.where(stopping & (front_gap < gap), front_gap, gap)
        v_lead = np.where(stopping & (front_gap <= gap), 0.0, v_lead)
        # IDM
        dv = v - v_lead
        desired_gap = gap0 + np.maximum(0.0, v * headway + v * dv / (2 * np.sqrt(accel * decel)))
        a = accel * (1 - (v / v_desired) ** 4 - (desired_gap / np.maximum(gap, 0.1)) ** 2)
        a = np.clip(a, -8.0, accel)
        # IDM only approaches standstill asymptotically; real drivers come to a halt.
        # Nor do they creep up from standstill: a halted vehicle waits until there is room.
        halt = ((a < 0) & (v + a * DT < 0.3)) | ((v == 0.0) & (gap < gap0 + 2.0))
        v_new = np.where(halt, 0.0, np.maximum(v + a * DT, 0.0))
        s_new = s + 0.5 * (v + v_new) * DT
        # Discrete IDM can overshoot in hard braking; never close in closer than half the standstill gap.
        limit = np.where(ok, out_s[t][np.maximum(leader, 0)] - 0.5 * (length[np.maximum(leader, 0)] + length) - 0.5 * gap0, np.inf)
        limit = np.where(stopping, np.minimum(limit, stop_s - 0.5 * length), limit)
        clamp = s_new > limit
        s_new = np.where(clamp, np.maximum(limit, s), s_new)
        v_new = np.where(clamp, (s_new - s) / DT, v_new)
        s, v = s_new, v_new
    return out_s, out_v


def _one_scene(rng: np.random.Generator, num_frames: int, lanes: list[_Lane], junction_x: float,
               red_light: bool, knobs: dict):
    """Simulate one scene; returns per-frame ego pose and the dense agent states."""
    ego_lane = 0  # east_0
    cycle = {"main_green": rng.uniform(15, 25), "cross_green": rng.uniform(8, 14)}
    period = cycle["main_green"] + cycle["cross_green"] + 2 * (AMBER + ALL_RED)
    if red_light:
        # The ego approaches a red light slowly enough to stop, waits, and leaves on green.
        ego_v0 = rng.uniform(3.0, 9.0)
        ego_s0 = lanes[ego_lane].stop_s - 0.5 * EGO_EXTENT[0] - ego_v0**2 / (2 * 2.0) - rng.uniform(2.0, 15.0)
        wait = rng.uniform(1.5, 3.5)
        cycle["phase"] = period - (num_frames * DT + 1.0)  # red throughout; green timed after a dry run
    else:
        ego_v0 = rng.uniform(6.0, 12.0)
        ego_s0 = junction_x - rng.uniform(50.0, 90.0)
        cycle["phase"] = rng.uniform(0, cycle["main_green"] * 0.3)  # green for at least the first seconds
    ego_vd = rng.uniform(*_EGO.speed)

    # Populate lanes with gaps drawn around the lane's density; keep clear of the ego's spot.
    lane_ids, s_init, kinds = [], [], []
    for i, lane in enumerate(lanes):
        mean_gap = 1.0 / lane.density
        s = rng.uniform(0, mean_gap)
        while s < lane.arclength[-1]:
            if not (i == ego_lane and abs(s - ego_s0) < 15.0):
                lane_ids.append(i), s_init.append(s), kinds.append(lane.kind)
            s += mean_gap * rng.uniform(0.5, 1.5) + lane.kind.extent[0] + lane.kind.min_gap
    n_agents = len(s_init)
    lane_id = np.array(lane_ids + [ego_lane])
    s_init = np.array(s_init + [ego_s0])
    kinds = kinds + [_EGO]
    v_desired = np.array([rng.uniform(*k.speed) for k in kinds[:-1]] + [ego_vd])
    v_init = np.concatenate([v_desired[:-1] * rng.uniform(0.7, 1.0, n_agents), [ego_v0]])
    params = np.array([(k.accel, k.decel, k.min_gap, k.headway) for k in kinds])
    jitter = 1 + knobs["extent_jitter"] * rng.standard_normal((n_agents, 3))
    extent = np.vstack([np.array([k.extent for k in kinds[:-1]]).reshape(-1, 3) * np.clip(jitter, 0.8, 1.2),
                        EGO_EXTENT[None]])
    stop_s = np.array([lanes[i].stop_s for i in lane_id])

    labels = np.array([label_index(k.label) for k in kinds])
    setup = (lane_id, s_init, v_init, v_desired, params, extent, stop_s, labels)
    result = _run(lanes, junction_x, num_frames, cycle, *setup)
    if red_light:
        # The dry run kept the light red; let it turn green a little after the ego has halted.
        ego_speed = result[2][:, -1]
        halted = np.flatnonzero(ego_speed == 0.0)
        t_green = halted[0] * DT + wait if halted.size else 0.65 * num_frames * DT
        cycle["phase"] = period - max(t_green, 1.0)
        result = _run(lanes, junction_x, num_frames, cycle, *setup)
    return result


def _run(lanes, junction_x, num_frames, cycle, lane_id, s_init, v_init, v_desired, params, extent, stop_s, labels):
    """Simulate one signal timing; the last road user is the ego."""
    states = _signal_states(np.arange(num_frames) * DT, cycle)
    light_of = np.array([lanes[i].light == "cross" for i in lane_id])
    light_state = np.where(light_of[None, :], states["cross"][:, None], states["main"][:, None])
    # Start consistent with the signal: nobody inside the junction against a red light, and
    # everybody before a red line slow enough to stop there.
    red0 = light_state[0] != 0
    pos0 = np.concatenate([_at(lanes[i], s_init[j:j + 1])[0] for j, i in enumerate(lane_id)])
    in_junction = np.where(light_of, np.abs(pos0[:, 1] - LANE_WIDTH) < 11.0, np.abs(pos0[:, 0] - junction_x) < 6.0)
    keep = ~(red0 & in_junction)
    keep[-1] = True
    front_gap = stop_s - s_init - 0.5 * extent[:, 0]
    v_stoppable = np.sqrt(2 * params[:, 1] * np.maximum(front_gap - 1.0, 0.0))
    v_init = np.where(red0 & (front_gap > 0), np.minimum(v_init, v_stoppable), v_init)
    lane_id, s_init, v_init, v_desired = lane_id[keep], s_init[keep], v_init[keep], v_desired[keep]
    params, extent, stop_s, labels = params[keep], extent[keep], stop_s[keep], labels[keep]

    s, v = _simulate(lane_id, s_init, v_init, v_desired, params, extent[:, 0], stop_s, light_state[:, keep], num_frames)
    pos = np.empty((num_frames, lane_id.size, 2))
    yaw = np.empty((num_frames, lane_id.size))
    for i, lane in enumerate(lanes):  # one vectorised lookup per lane
        cols = lane_id == i
        pos[:, cols], yaw[:, cols] = _at(lane, s[:, cols])
    return pos, yaw, v, extent, labels, states, lane_id.size - 1


def _overlaps_ego(pos, yaw, extent, n_agents, visible) -> bool:
    ego_pos, ego_yaw = pos[:, -1:], yaw[:, -1:]
    near = np.linalg.norm(pos[:, :n_agents] - ego_pos, axis=-1) < 10.0
    near &= visible
    if not near.any():
        return False
    t, a = np.nonzero(near)
    hit = oriented_boxes_overlap(ego_pos[t, 0], ego_yaw[t, 0], EGO_EXTENT[None], pos[t, a], yaw[t, a], extent[a])
    return bool(hit.any())


def generate_scenes(num_scenes: int, num_frames: int = 100, seed: int = 0, **knobs) -> L5Arrays:
    """Generate ``num_scenes`` scenes of ``num_frames`` frames as l5kit structured arrays.

    Knobs (keyword arguments): ``host``, ``red_light_fraction``, ``car_density``,
    ``perception_range``, ``junction_at``, ``bend_radius``, ``bend_degrees``,
    ``cross_half_length``, ``extent_jitter``.  Same arguments -> identical arrays.
    """
    if num_scenes < 0 or num_frames < 1:
        raise ValueError(f"need num_scenes >= 0 and num_frames >= 1, got {num_scenes}, {num_frames}")
    knobs = _knobs(knobs)
    rng = np.random.default_rng(seed)
    lanes, junction_x = _build_lanes(_lane_length(num_frames, knobs), knobs)
    red_scenes = rng.random(num_scenes) < knobs["red_light_fraction"]

    scenes = np.zeros(num_scenes, dtype=SCENE_DTYPE)
    frames = np.zeros(num_scenes * num_frames, dtype=FRAME_DTYPE)
    agent_blocks, face_blocks = [], []
    n_agent_rows = n_face_rows = 0
    for k in range(num_scenes):
        for attempt in range(_MAX_ATTEMPTS):
            pos, yaw, speed, extent, labels, states, n_agents = _one_scene(rng, num_frames, lanes, junction_x,
                                                                          bool(red_scenes[k]), knobs)
            dist = np.linalg.norm(pos[:, :n_agents] - pos[:, -1:], axis=-1)
            visible = dist < knobs["perception_range"]
            if not _overlaps_ego(pos, yaw, extent, n_agents, visible):
                break
        else:
            raise RuntimeError(f"scene {k}: no collision-free draw in {_MAX_ATTEMPTS} attempts (seed {seed})")

        t0 = START_TIME_NS + k * (num_frames + 50) * 100_000_000  # scenes are separated by 5 s
        rows = slice(k * num_frames, (k + 1) * num_frames)
        fr = frames[rows]
        fr["timestamp"] = t0 + np.arange(num_frames, dtype=np.int64) * 100_000_000
        fr["ego_translation"][:, :2] = pos[:, -1]
        fr["ego_rotation"] = yaw_as_rotation33(yaw[:, -1])

        # Agents, frame-major; track ids 1.. in order of first appearance.
        t_idx, a_idx = np.nonzero(visible)
        first_seen = np.where(visible.any(0), visible.argmax(0), num_frames)
        order = np.lexsort((np.arange(n_agents), first_seen))
        track_id = np.empty(n_agents, dtype=np.uint64)
        track_id[order] = np.arange(1, n_agents + 1, dtype=np.uint64)
        ag = np.zeros(t_idx.size, dtype=AGENT_DTYPE)
        ag["centroid"] = pos[t_idx, a_idx]
        ag["yaw"] = yaw[t_idx, a_idx]
        ag["extent"] = extent[a_idx]
        ag["velocity"] = speed[t_idx, a_idx, None] * np.stack([np.cos(yaw[t_idx, a_idx]), np.sin(yaw[t_idx, a_idx])], -1)
        ag["track_id"] = track_id[a_idx]
        ag["label_probabilities"][np.arange(t_idx.size), labels[a_idx]] = 1.0
        counts = visible.sum(1)
        ends = n_agent_rows + np.cumsum(counts)
        fr["agent_index_interval"] = np.stack([ends - counts, ends], 1)
        n_agent_rows += t_idx.size
        agent_blocks.append(ag)

        faces = _faces(states, np.linalg.norm(pos[:, -1] - [junction_x, 0.0], axis=1) < 80.0)
        counts = faces[1]
        ends = n_face_rows + np.cumsum(counts)
        fr["traffic_light_faces_index_interval"] = np.stack([ends - counts, ends], 1)
        n_face_rows += len(faces[0])
        face_blocks.append(faces[0])

        scenes[k] = ((k * num_frames, (k + 1) * num_frames), f"{knobs['host']}-{k % 100:02d}"[:16],
                     fr["timestamp"][0], fr["timestamp"][-1])
    agents = np.concatenate(agent_blocks) if agent_blocks else np.zeros(0, AGENT_DTYPE)
    faces = np.concatenate(face_blocks) if face_blocks else np.zeros(0, TL_FACE_DTYPE)
    return L5Arrays(scenes, frames, agents, faces)


# Each signal has a red, amber and green face; status columns are (active, inactive, unknown).
_FACE_IDS = {"main": ("main_red", "main_amber", "main_green"), "cross": ("cross_red", "cross_amber", "cross_green")}


def _faces(states: dict[str, np.ndarray], in_view: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    num_frames = in_view.size
    per_frame = np.zeros((num_frames, 6), dtype=TL_FACE_DTYPE)
    for j, (light, ids) in enumerate(_FACE_IDS.items()):
        lit_face = 2 - states[light]  # state 0 green -> face 2, 1 amber -> 1, 2 red -> 0
        for f, face_id in enumerate(ids):
            col = per_frame[:, 3 * j + f]
            col["face_id"], col["traffic_light_id"] = face_id, f"tl_{light}"
            active = lit_face == f
            col["traffic_light_face_status"] = np.stack([active, ~active, np.zeros_like(active)], 1)
            per_frame[:, 3 * j + f] = col
    counts = np.where(in_view, 6, 0)
    return per_frame[in_view].reshape(-1), counts


# The map's lanes are the drivable ones (sidewalks are not lanes in an L5 map),
# cut at the stop line and where they leave the junction; the piece across the
# junction carries its signal's traffic light and faces, so a raster of the map
# colours the way through the junction by the light's state.
_MAP_LANE_WIDTH = {"bike_east": 1.5}  # others LANE_WIDTH
_FACE_COLOURS = {"red": RED, "amber": YELLOW, "green": GREEN}
_CROSSWALK_WIDTH = _STOP_MARGIN  # between the main road's stop lines and the crossing road


def _normals(points: np.ndarray) -> np.ndarray:
    d = np.gradient(points, axis=0)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return np.stack([-d[:, 1], d[:, 0]], axis=1)  # left of the direction of travel


def _piece(lane: _Lane, s0: float, s1: float) -> np.ndarray:
    """The centerline between arclengths s0 < s1, cut points included."""
    inside = lane.points[(lane.arclength > s0) & (lane.arclength < s1)]
    ends = _at(lane, np.array([s0, s1]))[0]
    return np.vstack([ends[:1], inside, ends[1:]])


def semantic_map(num_frames: int = 100, **knobs) -> SemanticMap:
    """The road layout of :func:`generate_scenes` (same arguments) as an L5 semantic map.

    Lane ids are ``<lane name>/approach``, ``/junction`` and ``/exit``; faces
    are the ``face_id`` strings of the zarr's traffic_light_faces.
    """
    knobs = _knobs(knobs)
    lanes, junction_x = _build_lanes(_lane_length(num_frames, knobs), knobs)
    face_ids = [face for ids in _FACE_IDS.values() for face in ids]
    lights = list(_FACE_IDS)
    half_cross = LANE_WIDTH / 2
    ids, lefts, rights, controls = [], [], [], []
    for lane in lanes:
        if lane.kind is _PEDESTRIAN:
            continue
        # The junction piece runs from the stop line to the far side's stop line (or sidewalk).
        if lane.light == "cross":
            across = (_OFFSETS["walk_north"] + 1.5) - (_OFFSETS["walk_south"] - 1.5)
        else:
            across = 2 * (half_cross + _STOP_MARGIN)
        cuts = [0.0, lane.stop_s, lane.stop_s + across, float(lane.arclength[-1])]
        width = _MAP_LANE_WIDTH.get(lane.name, LANE_WIDTH)
        for part, s0, s1 in zip(("approach", "junction", "exit"), cuts[:-1], cuts[1:]):
            centre = _piece(lane, s0, s1)
            offset = 0.5 * width * _normals(centre)
            ids.append(f"{lane.name}/{part}")
            lefts.append(centre + offset)
            rights.append(centre - offset)
            controls.append([f"tl_{lane.light}", *_FACE_IDS[lane.light]] if part == "junction" else [])
    x_in, x_out = junction_x - half_cross, junction_x + half_cross
    y_south = _OFFSETS["bike_east"] - 0.5 * _MAP_LANE_WIDTH["bike_east"]
    y_north = _OFFSETS["west_0"] + half_cross

    def box(x0, y0, x1, y1):
        return np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]])  # counter-clockwise

    crosswalks = {
        "crosswalk_west": box(x_in - _CROSSWALK_WIDTH, y_south, x_in, y_north),
        "crosswalk_east": box(x_out, y_south, x_out + _CROSSWALK_WIDTH, y_north),
        "crosswalk_south": box(x_in, _OFFSETS["walk_south"] - 1.5, x_out, _OFFSETS["walk_south"] + 1.5),
        "crosswalk_north": box(x_in, _OFFSETS["walk_north"] - 1.5, x_out, _OFFSETS["walk_north"] + 1.5),
    }
    return SemanticMap(
        lane_ids=np.array(ids),
        lanes_left=Polylines.from_list(lefts),
        lanes_right=Polylines.from_list(rights),
        lane_control_offsets=np.concatenate([[0], np.cumsum([len(c) for c in controls])]).astype(np.int64),
        lane_control_ids=np.array([c for cs in controls for c in cs]),
        crosswalk_ids=np.array(list(crosswalks)),
        crosswalks=Polylines.from_list(list(crosswalks.values())),
        face_ids=np.array(face_ids),
        face_colours=np.array([_FACE_COLOURS[f.split("_")[1]] for f in face_ids], np.int8),
        world_to_ecef=WORLD_TO_ECEF,
        traffic_light_ids=np.array([f"tl_{light}" for light in lights]),
        face_light_index=np.repeat(np.arange(len(lights)), 3).astype(np.int64),
    )


def generate_zarr(path: str | os.PathLike, num_scenes: int, num_frames: int = 100, seed: int = 0,
                  overwrite: bool = False, map_dir: str | os.PathLike | None = None, **knobs) -> Path:
    """Generate scenes and write them as an l5kit zarr store, with the road as an L5 map.

    The lane centerlines also go into the group ``.zattrs`` under
    ``driveeval_layout``.  ``semantic_map.pb`` and ``meta.json`` are written into
    ``map_dir`` (default: beside the zarr, as in l5kit's test artefacts); a map
    already there that differs is replaced only with ``overwrite``.
    """
    arrays = generate_scenes(num_scenes, num_frames, seed, **knobs)
    layout = road_layout(num_frames, **knobs)
    attrs = {"driveeval_layout": {
        "lanes": {name: np.round(pts, 3).tolist() for name, pts in layout["lanes"].items()},
        "stop_lines": layout["stop_lines"],
        "junction": layout["junction"],
        "generator": {"seed": seed, "num_scenes": num_scenes, "num_frames": num_frames, **knobs},
    }}
    map_dir = Path(path).parent if map_dir is None else Path(map_dir)
    road = semantic_map(num_frames, **knobs)
    pb_path, meta_path = map_dir / "semantic_map.pb", map_dir / "meta.json"
    if not overwrite and pb_path.exists() and pb_path.read_bytes() != encode_semantic_map(road):
        raise FileExistsError(f"{pb_path} holds another map (another layout or l5kit's); pass overwrite=True "
                              "to replace it, or map_dir= to write this one elsewhere")
    written = write_l5_zarr(path, *arrays, attrs=attrs, overwrite=overwrite)
    write_semantic_map(pb_path, meta_path, road)
    return written
