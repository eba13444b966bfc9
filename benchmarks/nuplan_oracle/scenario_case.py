"""A score case (CASE_FORMAT.md) built by the oracle itself from a raw ScenarioNet file and the ego's
driven poses: the map (scenario_map.py), the agents and their types, the expert and the ego's
dynamic state all come from the file and from nuplan-devkit's own functions, not from
pytest_driveeval (which this module never imports).  Runs in the nuplan-devkit venv.

* **Times**: the file's ``metadata.ts`` at the driven frames (its ``sample_rate`` x frame without).
* **Ego box**: the file's self-driving car (``metadata.sdc_id``): its length and width at the first
  driven frame.  ScenarioNet's nuScenes converter writes the ego's size as ``[4.08, 1.73, 1.56]``
  (length first) into the ``size`` slot whose annotations are ``[width, length, height]``, so every
  nuScenes file holds the ego as 1.73 m long and 4.08 m wide: a box wider than long is turned
  (said in the notes).  The rear axle is nuPlan's Pacifica's share of the length behind the centre
  (1.461 / 5.176): ScenarioNet does not give it.
* **Ego dynamic state**, from the poses as nuPlan derives a state from planned poses
  (``ml_planner/transform_utils._get_velocity_and_acceleration``): the rear axle's x, y
  differentiated by ``approximate_derivatives`` (Savitzky-Golay, window 5, order 2; order 1 for the
  velocity, 2 for the acceleration), projected on the heading by ``_project_from_global_to_ego_centric_ds``
  (nuPlan's own function, whose lateral component is the negative of the body frame's y: kept, as
  nuPlan has it).  That path leaves the angular velocity 0; here the angular velocity and acceleration
  are nuPlan's ``extract_ego_yaw_rate`` of the poses (deriv 1, order 2; deriv 2, order 3: the calls
  its comfort metrics make), so that ``center_acceleration_2d`` sees the turn.
* **Expert**: the file's self-driving car at the same frames, as box centres.
* **Agents**: every other track valid at a driven frame, with the file's position, heading, length,
  width and (world-frame) velocity; its ScenarioNet type as nuPlan's ``TrackedObjectType``
  (TYPES below; any other type a generic object, which nuPlan scores as a static object).
"""
from __future__ import annotations

from typing import Any, Dict, List, Optional, Tuple

import numpy as np

import nuplan_metrics  # first: it stubs the sensor modules the devkit's observation types import
from nuplan.planning.metrics.utils.state_extractors import approximate_derivatives, extract_ego_yaw_rate
from nuplan.planning.simulation.planner.ml_planner.transform_utils import _project_from_global_to_ego_centric_ds
from scenario_map import scenario_map

#: ScenarioNet (MetaDrive) object types -> nuPlan's TrackedObjectType names (lower case)
TYPES = {"VEHICLE": "vehicle", "PEDESTRIAN": "pedestrian", "CYCLIST": "bicycle", "TRAFFIC_CONE": "traffic_cone",
         "TRAFFIC_BARRIER": "barrier"}
#: nuPlan's Pacifica: its rear axle lies this share of the length behind the box centre
REAR_AXLE_SHARE = 1.461 / 5.176


def _state(track: Dict[str, Any], key: str) -> np.ndarray:
    return np.asarray(track["state"][key], dtype=np.float64)


def _times(scenario: Dict[str, Any], frames: List[int]) -> np.ndarray:
    metadata = scenario["metadata"]
    ts = metadata.get("ts")
    if ts is not None and len(np.asarray(ts)) > max(frames):
        return np.asarray(ts, dtype=np.float64)[frames]
    return np.asarray(frames, dtype=np.float64) * float(metadata.get("sample_rate", 0.1))


def ego_box(scenario: Dict[str, Any], frame: int, notes: List[str]) -> Tuple[float, float]:
    sdc = scenario["tracks"][scenario["metadata"]["sdc_id"]]
    length, width = float(_state(sdc, "length").reshape(-1)[frame]), float(_state(sdc, "width").reshape(-1)[frame])
    if length < width:
        notes.append(f"the file's ego is {length:g} m long and {width:g} m wide (ScenarioNet's nuScenes converter "
                     f"swaps them): taken as {width:g} x {length:g}")
        length, width = width, length
    return length, width


def ego_dynamics(center: np.ndarray, times: np.ndarray, length: float, width: float) -> Dict[str, Any]:
    """The case's ``ego`` from centre poses (T, 3), as described in the module's docstring."""
    d = REAR_AXLE_SHARE * length
    heading = center[:, 2]
    rear = center[:, :2] - d * np.stack([np.cos(heading), np.sin(heading)], axis=1)
    poses = np.concatenate([rear, heading[:, None]], axis=1)
    velocity = _project_from_global_to_ego_centric_ds(poses, approximate_derivatives(rear, times, axis=0))
    acceleration = _project_from_global_to_ego_centric_ds(
        poses, approximate_derivatives(rear, times, axis=0, deriv_order=2))
    ego = {"length": length, "width": width, "rear_axle_to_center": d, "center": center.tolist(),
           "velocity": velocity.tolist(), "acceleration": acceleration.tolist(),
           "angular_velocity": [0.0] * len(times), "angular_acceleration": [0.0] * len(times)}
    states = nuplan_metrics.ego_states({"timestamps": times.tolist(), "ego": ego})
    ego["angular_velocity"] = extract_ego_yaw_rate(states).tolist()
    ego["angular_acceleration"] = extract_ego_yaw_rate(states, deriv_order=2, poly_order=3).tolist()
    return ego


def agents(scenario: Dict[str, Any], frames: List[int], notes: List[str]) -> List[Dict[str, Any]]:
    out = []
    other_types: Dict[str, int] = {}
    sdc_id = scenario["metadata"]["sdc_id"]
    for token, track in scenario["tracks"].items():
        if token == sdc_id:
            continue
        valid = np.asarray(track["state"]["valid"], dtype=bool).reshape(-1)
        length, width = _state(track, "length").reshape(-1), _state(track, "width").reshape(-1)
        rows = [k for k, f in enumerate(frames) if f < len(valid) and valid[f] and length[f] > 0 and width[f] > 0]
        if not rows:
            continue
        kind = TYPES.get(str(track.get("type")))
        if kind is None:
            other_types[str(track.get("type"))] = other_types.get(str(track.get("type")), 0) + 1
            kind = "generic_object"
        picked = [frames[k] for k in rows]
        position, heading = _state(track, "position")[picked, :2], _state(track, "heading").reshape(-1)[picked]
        out.append({"token": str(token), "type": kind,
                    # nuPlan's agents hold one box size; the first driven frame's, as OrientedBox takes one
                    "length": float(length[picked[0]]), "width": float(width[picked[0]]), "frames": rows,
                    "center": np.concatenate([position, heading[:, None]], axis=1).tolist(),
                    "velocity": _state(track, "velocity")[picked, :2].tolist()})
        sizes = np.stack([length[picked], width[picked]])
        if np.ptp(sizes, axis=1).max() > 1e-6:
            notes.append(f"agent {token}: its size changes over the frames; the first frame's is used")
    if other_types:
        notes.append(f"object types that are none of nuPlan's agents, scored as generic objects: {other_types}")
    return out


def case_from_scenario(scenario: Dict[str, Any], driven: Dict[str, Any], name: str,
                       ego_size: Optional[Tuple[float, float]] = None,
                       map_spec: Optional[Dict[str, Any]] = None) -> Tuple[Dict[str, Any], List[str]]:
    """(the case, notes) of one driven scene: ``driven`` as closed_loop.json's ``driven`` holds it
    (frames, center); ``ego_size`` (length, width) instead of the file's; ``map_spec``: scenario_map(scenario)
    already made (a caller driving one scene several times builds its map once; it is not changed here)."""
    notes: List[str] = []
    frames = [int(f) for f in driven["frames"]]
    steps = int(scenario.get("length") or len(np.asarray(scenario["metadata"].get("ts", []))))
    if steps and max(frames) >= steps:
        raise ValueError(f"the drive reaches frame {max(frames)}; the file has {steps} frames")
    times = _times(scenario, frames)
    length, width = ego_size if ego_size is not None else ego_box(scenario, frames[0], notes)
    center = np.asarray(driven["center"], dtype=np.float64)
    sdc = scenario["tracks"][scenario["metadata"]["sdc_id"]]
    expert = np.concatenate([_state(sdc, "position")[frames, :2], _state(sdc, "heading").reshape(-1)[frames, None]],
                            axis=1)
    start_gap = float(np.hypot(*(center[0, :2] - expert[0, :2])))
    if start_gap > 1e-3:
        notes.append(f"the drive starts {start_gap:.3f} m from the file's ego at frame {frames[0]} (a perturbed start, "
                     "or not this scene's file)")
    map_spec = dict(map_spec if map_spec is not None else scenario_map(scenario))
    notes.extend(map_spec.pop("notes"))
    case = {"name": name, "timestamps": times.tolist(), "ego": ego_dynamics(center, times, length, width),
            "expert": {"center": expert.tolist()}, "agents": agents(scenario, frames, notes), "map": map_spec}
    return case, notes
