"""Driving a planner of :mod:`pytest_driveeval.policies.planner_api` through the tensor engine.

The engine calls ``extra_inputs(rows, t, driven_xy, driven_yaw, agents)`` and then ``policy(batch)`` once per
step; :class:`PlannerPolicy` answers the first by building the step's :class:`Observation` from the ego's
driven history and the agents where the loop has them (the log, or the reactive agents' moves), and the
second by calling ``planner.plan`` and handing back its trajectory as the tensors the engine reads.  So a
planner runs wherever a tensor policy does: items, chunks on Ray workers, robustness searches.
"""
from __future__ import annotations

import weakref
from typing import Any, Callable

import numpy as np
import torch

from pytest_driveeval.policies.planner_api import Goal, Observation, PlannerContext, SceneContext

#: metres: agents farther from the ego than this are not in the observation (nuPlan's observations reach ~100 m)
AGENTS_RADIUS = 80.0

#: id(score map) -> (a weak reference to it, its routes by log): ScoreMap is a dataclass (unhashable), and the
#: maps live as long as their dataset (usecases.closed_loop.score.SceneMaps)
_routes: dict[int, tuple[Any, dict]] = {}


def _route(score_map: Any, xy: np.ndarray, yaw: np.ndarray) -> Any:
    """The logged route of a scene on its map, made once per (map, log) and kept with the map."""
    from pytest_driveeval.sim.map_query import logged_route

    ref, made = _routes.get(id(score_map), (None, None))
    if ref is None or ref() is not score_map:
        made = {}
        _routes[id(score_map)] = (weakref.ref(score_map, lambda _, key=id(score_map): _routes.pop(key, None)), made)
    key = (len(xy), xy[0].tobytes(), xy[-1].tobytes())
    if key not in made:
        made[key] = logged_route(score_map, xy, yaw)
    return made[key]


def _lights(dataset: Any, scene: int, score_map: Any) -> Any:
    """A ScenarioNet scene's lights with the lanes they control as map indices; None where the data has none."""
    if dataset is None or not hasattr(dataset, "source"):
        return None
    lights = dataset.source(scene).lights
    if not lights:
        return None
    from pytest_driveeval.sim.map_query import LightStates

    index = {lane_id: n for n, lane_id in enumerate(score_map.lane_ids)}
    stops = np.array([light.stop_point[:2] if light.stop_point is not None else (np.nan, np.nan) for light in lights],
                     dtype=np.float64).reshape(-1, 2)
    return LightStates(np.array([index.get(str(light.lane), -1) for light in lights]),
                       [list(light.states) for light in lights], stops)


def planner_context(log: Any, config: Any, dataset: Any = None, maps: Any = None) -> PlannerContext:
    """Each row of the stacked ``log`` as its planner is told: map query, route and goal."""
    from pytest_driveeval.sim.map_query import MapQuery

    scenes = []
    for row, scene in enumerate(log.scene_ids.tolist()):
        n = int(log.num_frames[row])
        xy, yaw = log.ego_xy[row, :n], log.ego_yaw[row, :n]
        score_map = maps.get(int(scene)) if maps is not None else None
        query = route = None
        if score_map is not None:
            query = MapQuery(score_map, _lights(dataset, int(scene), score_map))
            route = _route(score_map, np.ascontiguousarray(xy), np.ascontiguousarray(yaw))
        goal = Goal(np.array(xy[-1], dtype=np.float64), float(yaw[-1]), n - 1)
        scenes.append(SceneContext(int(scene), query, route, goal, config.start_frame))
    return PlannerContext(scenes, config.step_time, tuple(float(v) for v in config.ego_extent), config.future_frames)


class PlannerPolicy:
    """The engine's policy for a planner object; see the module doc."""

    def __init__(self, planner: Any, context: PlannerContext, history_frames: int):
        self.planner = planner
        self.context = context
        self.history_frames = history_frames
        self._observation: Observation | None = None
        planner.initialize(context)

    def extra_inputs(self, rows: np.ndarray, t: int, driven_xy: np.ndarray, driven_yaw: np.ndarray, agents: Any
                     ) -> dict:
        self._observation = observe(rows, t, driven_xy, driven_yaw, agents, self.context, self.history_frames)
        return {}

    def __call__(self, batch: dict) -> dict:
        obs = self._observation
        if obs is None:
            raise RuntimeError("PlannerPolicy called before its observation was built (extra_inputs)")
        self._observation = None
        out = self.planner.plan(obs)
        if not isinstance(out, dict):
            return out  # the engine says what was expected
        return {key: _as_tensor(value, key, len(obs.rows)) for key, value in out.items()}


def _as_tensor(value: Any, key: str, rows: int) -> Any:
    if isinstance(value, np.ndarray) and value.dtype.kind == "f":
        value = torch.from_numpy(np.ascontiguousarray(value))
    if key == "yaws" and torch.is_tensor(value) and value.dim() == 2 and value.shape[0] == rows:
        value = value[..., None]
    return value


def observe(rows: np.ndarray, t: int, driven_xy: np.ndarray, driven_yaw: np.ndarray, log: Any,
            context: PlannerContext, history_frames: int) -> Observation:
    """The step's observation (see :class:`~pytest_driveeval.policies.planner_api.Observation`)."""
    back = np.clip(t - np.arange(history_frames + 1), 0, None)
    history_xy = driven_xy[rows][:, back]
    history_yaw = driven_yaw[rows][:, back]
    if t > 0:
        speed = np.hypot(*(driven_xy[rows, t] - driven_xy[rows, t - 1]).T) / context.step_time
    else:  # no past: the log's first step
        speed = np.hypot(*(log.ego_xy[rows, 1] - log.ego_xy[rows, 0]).T) / context.step_time
    ego = driven_xy[rows, t]
    xy = log.agent_xy[rows, t]
    distance = np.hypot(xy[..., 0] - ego[:, None, 0], xy[..., 1] - ego[:, None, 1])
    distance = np.where(log.available[rows, t], distance, np.inf)
    distance[distance > AGENTS_RADIUS] = np.inf
    count = int(np.isfinite(distance).sum(axis=1).max(initial=0))
    order = np.argsort(distance, axis=1, kind="stable")[:, :count]
    pick = (rows[:, None], t, order)
    lights = []
    for row in rows.tolist():
        query = context.scenes[row].map
        lights.append(query.lights(t) if query is not None else {})
    return Observation(
        rows=rows, frame=t, ego_xy=ego.copy(), ego_yaw=driven_yaw[rows, t].copy(), ego_speed=speed,
        history_xy=history_xy, history_yaw=history_yaw,
        agents_xy=np.asarray(log.agent_xy[pick], dtype=np.float64),
        agents_yaw=np.asarray(log.agent_yaw[pick], dtype=np.float64),
        agents_extent=np.asarray(log.agent_extent[pick], dtype=np.float64),
        agents_velocity=np.asarray(log.agent_velocity[pick], dtype=np.float64),
        agents_available=np.isfinite(np.take_along_axis(distance, order, axis=1)),
        agents_track_id=log.track_id[pick], lights=lights)


def planner_policy(planner: Any, log: Any, config: Any, dataset: Any, maps: Any) -> tuple[PlannerPolicy, Callable]:
    """The engine's policy for ``planner`` and the ``extra_inputs`` that builds its observations."""
    policy = PlannerPolicy(planner, planner_context(log, config, dataset, maps), config.history_frames)
    return policy, policy.extra_inputs
