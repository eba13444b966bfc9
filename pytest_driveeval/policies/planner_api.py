"""The closed loop's API for planners that are code rather than tensors (nuPlan's ``AbstractPlanner``, ported).

A planner is any object with two methods::

    class MyPlanner:
        def initialize(self, context: PlannerContext) -> None: ...
        def plan(self, observation: Observation) -> dict:   # {"positions": (B, F, 2), "yaws": (B, F) or (B, F, 1)}

``initialize`` is called once per unroll with every scene of the batch (its map query, route and goal);
``plan`` once per step with the batch of scenes still driving, and returns each one's trajectory in its ego
frame, as a tensor policy does (numpy or torch; the engine moves the ego to the first pose).  nuPlan's
``PlannerInitialization`` (``route_roadblock_ids``, ``mission_goal``, ``map_api``) is ``context.scenes[i]``
(``route.roadblocks``, ``goal``, ``map``), and its ``PlannerInput`` (``iteration``, ``history``,
``traffic_light_data``) is the observation (``frame``, the ego's and agents' arrays, ``lights``): one
object for the whole batch instead of one per scenario.  docs/bring-your-planner.md has the full mapping.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any, Protocol, runtime_checkable

import numpy as np

__all__ = ["Goal", "Observation", "Planner", "PlannerContext", "SceneContext", "is_planner"]


@runtime_checkable
class Planner(Protocol):
    def initialize(self, context: "PlannerContext") -> None: ...

    def plan(self, observation: "Observation") -> Any: ...


def is_planner(obj: Any) -> bool:
    """Whether ``obj`` is driven through this API rather than called with the tensor batch."""
    return callable(getattr(obj, "initialize", None)) and callable(getattr(obj, "plan", None))


@dataclass(frozen=True)
class Goal:
    """nuPlan's mission goal: the log's last ego pose (world frame) and its frame number."""

    xy: np.ndarray
    yaw: float
    frame: int


@dataclass
class SceneContext:
    """One scene of the batch as its planner is told at the start.

    ``map``: a :class:`~pytest_driveeval.sim.map_query.MapQuery`, None where the scene has no map (an L5
    zarr run without a semantic map; a ScenarioNet file without lanes).  ``route``: the lanes and roadblocks
    the logged ego drives (:func:`~pytest_driveeval.sim.map_query.logged_route`, the score's own), None
    without a map.  ``scene``: the dataset's scene index."""

    scene: int
    map: Any
    route: Any
    goal: Goal
    start_frame: int


@dataclass
class PlannerContext:
    """``scenes[row]`` for each row of the unroll's batch; the observations' ``rows`` index it."""

    scenes: list[SceneContext]
    step_time: float
    ego_extent: tuple[float, float, float]
    future_frames: int


@dataclass
class Observation:
    """What a planner sees at ``frame`` for the scenes ``rows`` (B of them), in the world frame.

    Ego: ``ego_xy`` (B, 2), ``ego_yaw`` (B,), ``ego_speed`` (B,) m/s from its last step; ``history_xy``
    (B, H, 2) and ``history_yaw`` (B, H), newest first (frame, frame - 1, ...; repeated before the log's
    start).  Agents: the A nearest within ``radius`` of the ego at this frame, nearest first, padded where
    ``agents_available`` is False: ``agents_xy`` (B, A, 2), ``agents_yaw`` (B, A), ``agents_extent``
    (B, A, 3) (length, width, height), ``agents_velocity`` (B, A, 2), ``agents_track_id`` (B, A).  With
    ``Agents: reactive`` they are where the simulation has put them.  ``lights[b]``: lane -> light state."""

    rows: np.ndarray
    frame: int
    ego_xy: np.ndarray
    ego_yaw: np.ndarray
    ego_speed: np.ndarray
    history_xy: np.ndarray
    history_yaw: np.ndarray
    agents_xy: np.ndarray
    agents_yaw: np.ndarray
    agents_extent: np.ndarray
    agents_velocity: np.ndarray
    agents_available: np.ndarray
    agents_track_id: np.ndarray
    lights: list[dict] = field(default_factory=list)

    def only_agents(self, keep: np.ndarray) -> "Observation":
        """This observation with only the agents ``keep`` (B, A) marks, kept in their order and first in
        each row, the agent axis cut to the most any row keeps (a planner's cost grows with it)."""
        count = int(keep.sum(axis=1).max(initial=0))
        order = np.argsort(~keep, axis=1, kind="stable")[:, :count]

        def pick(a: np.ndarray) -> np.ndarray:
            return np.take_along_axis(a, order.reshape(order.shape + (1,) * (a.ndim - 2)), axis=1)

        return replace(self, agents_xy=pick(self.agents_xy), agents_yaw=pick(self.agents_yaw),
                       agents_extent=pick(self.agents_extent), agents_velocity=pick(self.agents_velocity),
                       agents_available=pick(keep), agents_track_id=pick(self.agents_track_id))

    def to_ego_frame(self, xy: np.ndarray, yaw: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World poses (B, F, 2), (B, F) as the ego-frame trajectory ``plan`` returns."""
        c, s = np.cos(self.ego_yaw)[:, None], np.sin(self.ego_yaw)[:, None]
        d = xy - self.ego_xy[:, None]
        local = np.stack([c * d[..., 0] + s * d[..., 1], -s * d[..., 0] + c * d[..., 1]], axis=-1)
        return local, np.arctan2(np.sin(yaw - self.ego_yaw[:, None]), np.cos(yaw - self.ego_yaw[:, None]))
