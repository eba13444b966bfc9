"""``Inputs: {Map: ...}``: l5kit's vectorised map keys, the route and the goal in the policy's batch.

The engine asks for extra inputs at every step (``unroll(extra_inputs=...)``); this gives it, for every
scene of the step at once, in the ego's driven pose's frame:

* ``lanes``, ``lanes_availabilities``, ``lanes_mid``, ``lanes_mid_availabilities``, ``crosswalks``,
  ``crosswalks_availabilities``: l5kit 1.5's ``Vectorizer`` keys (sim.logreplay.map_inputs), the
  third value of ``lanes_mid`` the traffic-light feature from the faces lit at that frame (L5's
  ``traffic_light_faces``; a ScenarioNet scene's ``dynamic_map_states``);
* ``lanes_mid_on_route`` (L,) bool: the lane is on the route, nuPlan's way: the roadblocks of the lanes
  the logged ego drives (metrics.nuplan_score.route.centre_route, as the score assigns them); a lane
  is on it when its roadblock is (an L5 map has no roadblocks: each lane is its own);
* ``goal_position`` (2,), ``goal_yaw`` (1,): the log's last ego pose, nuPlan's mission goal.
"""
from __future__ import annotations

from typing import Any, Callable, Sequence

import numpy as np

from pytest_driveeval.sim.logreplay.map_inputs import MapLimits, VectorMap

__all__ = ["map_inputs", "places", "route_lanes"]


def route_lanes(score_map: Any, xy: np.ndarray, yaw: np.ndarray) -> set[str]:
    """The ids of the lanes on the route of a logged drive ``xy`` (T, 2), ``yaw`` (T,) on ``score_map``."""
    from pytest_driveeval.metrics.nuplan_score.route import centre_route

    driven = {lane for frame in centre_route(score_map, xy, yaw) for lane in frame}
    blocks = {int(score_map.roadblock[lane]) for lane in driven}
    return {str(score_map.lane_ids[n]) for n in range(len(score_map.lane_ids)) if int(score_map.roadblock[n]) in blocks}


def places(dataset: Any, ids: Sequence[int], semantic_map: Any) -> tuple[list[Any], np.ndarray]:
    """The maps the rows of scenes ``ids`` read, and each row's index among them: a ScenarioNet
    dataset's scenes by the place they lie in (``metadata.map``; one map per place, its scenes' maps
    merged), else ``semantic_map`` for every row."""
    if not hasattr(dataset, "scenario_map"):
        return [semantic_map], np.zeros(len(ids), np.int64)
    from pytest_driveeval.io.scenarionet.scenarionet_map import merged

    names = [str(dataset.source(i).metadata.get("map", "")) for i in ids]
    order = list(dict.fromkeys(names))
    maps = [merged([dataset.scenario_map(i) for i, name in zip(ids, names) if name == place]) for place in order]
    return maps, np.array([order.index(name) for name in names], np.int64)


def map_inputs(limits: MapLimits, log: Any, scenes: Sequence[Any], maps: Sequence[Any], place: np.ndarray,
               score_maps: Sequence[Any]) -> Callable:
    """The engine's ``extra_inputs`` for the map keys: log row r reads ``maps[place[r]]``;
    ``score_maps``: each row's score map (None: no route for that row)."""
    import torch

    from pytest_driveeval.raster.semantic import active_faces

    vector = VectorMap(list(maps), limits)
    faces = active_faces(scenes, log.ego_xy.shape[1])
    face_of = vector.face_index(faces.ids)
    n_faces = len(vector.face_ids)
    on_route = np.zeros((log.ego_xy.shape[0], len(vector.lane_ids) + 1), bool)  # last column: the empty slot
    routes: dict = {}  # copies of one scene (a search's, a benchmark's) share their route
    for row, score_map in enumerate(score_maps):
        if score_map is not None:
            n = int(log.num_frames[row])
            key = (id(score_map), log.ego_xy[row, :n].tobytes(), log.ego_yaw[row, :n].tobytes())
            if key not in routes:
                routes[key] = list(route_lanes(score_map, log.ego_xy[row, :n], log.ego_yaw[row, :n]))
            route = routes[key]
            on_route[row, :-1] = np.isin(vector.lane_ids, route) & (vector.lane_place == place[row])
    last = np.maximum(log.num_frames - 1, 0)
    goal_xy = log.ego_xy[np.arange(len(last)), last]
    goal_yaw = log.ego_yaw[np.arange(len(last)), last]

    def lit(rows: np.ndarray, t: int) -> np.ndarray:
        at = rows * faces.n_frames + t
        starts, ends = faces.offsets[at], faces.offsets[at + 1]
        counts = ends - starts
        which = np.repeat(np.arange(len(rows)), counts)
        index = face_of[np.repeat(starts - np.cumsum(counts) + counts, counts) + np.arange(counts.sum())]
        out = np.zeros((len(rows), n_faces), bool)
        out[which[index >= 0], index[index >= 0]] = True
        return out

    def inputs(rows: np.ndarray, t: int, driven_xy: np.ndarray, driven_yaw: np.ndarray, agents: Any = None) -> dict:
        centre, yaw = driven_xy[rows, t], driven_yaw[rows, t]
        cos, sin = np.cos(yaw), np.sin(yaw)
        out, chosen = vector(centre, cos, sin, lit(rows, t), place[rows])
        out["lanes_mid_on_route"] = on_route[rows[:, None], chosen]  # chosen -1 reads the empty slot's False
        gap = goal_xy[rows] - centre
        out["goal_position"] = np.stack([cos * gap[:, 0] + sin * gap[:, 1], cos * gap[:, 1] - sin * gap[:, 0]],
                                        axis=1).astype(np.float32)
        out["goal_yaw"] = (np.angle(np.exp(1j * (goal_yaw[rows] - yaw)))[:, None]).astype(np.float32)
        return {key: torch.from_numpy(value) for key, value in out.items()}

    return inputs
