"""Episodes in a CommonRoad scene (sim.commonroad_scene): the ego by the kinematic bicycle, the
obstacles replayed from the recording.

The interface is :class:`~pytest_driveeval.sim.episodes.Episodes`' (``xy``, ``yaw``, ``speed``,
``valid`` (E, A) with the ego in column 0, the goal's centre and speed, ``step(actions)`` returning
a :class:`~pytest_driveeval.sim.episodes.StepResult`), so observers, baselines, the benchmark's
statistics and pictures work on it unchanged.  What differs:

* ``A`` is 1 + every obstacle of the file (no agent limit on the arrays: collisions count with every
  obstacle; the graph observation keeps the nearest ``agent_limit``), and ``size`` is (A, 2), one box
  per agent;
* at step ``k`` the obstacles are where the recording has them at time step ``t0 + k``, present or not
  (see sim.commonroad_scene), whatever the ego does: replay, not reaction; with a scene's
  ``traffic="reactive"`` the recorded cars instead drive their recorded paths by IDM
  (sim.commonroad_reactive), from the same snapshot as the ego, as blueprint traffic does;
* the goal is CommonRoad's (commonroad_geometry.goal_reached on the ego's box centre, heading, speed
  and time step); the step limit the goal's time interval's end.

Outcomes, their precedence and the reward are the blueprints' (metrics.episode_outcomes).  An
episode's course depends on its seed (and perturbation row) alone: every episode starts from the
scene's initial state moved by its own offsets and sees the same recording.

Perturbation rows (robustness search) move the start further: ``lateral``, ``longitudinal``,
``heading`` add to the seed's offsets, ``speed_scale`` multiplies the resulting speed;
``agents_speed_scale`` and ``gap_scale`` have no meaning for a recording and must be 1.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from pytest_driveeval.geometry import box_corners, oriented_boxes_overlap
from pytest_driveeval.io.commonroad.commonroad_geometry import goal_reached, outline_meets_shape
from pytest_driveeval.metrics.episode_outcomes import (COLLISION, GOAL, OFF_ROAD, RUNNING, STEP_LIMIT, classify,
                                                       step_reward)
from pytest_driveeval.sim.agents import TrafficModel
from pytest_driveeval.sim.commonroad_reactive import ReactiveObstacles
from pytest_driveeval.sim.commonroad_road import corners_on_road
from pytest_driveeval.sim.dynamics import KinematicBicycle
from pytest_driveeval.sim.episodes import PERTURBATION_COLUMNS, StepResult, checked_actions
from pytest_driveeval.sim.state import AgentState

__all__ = ["CommonRoadEpisodes", "start_offsets"]

_LAT, _LON, _HEADING, _SPEED, _AGENTS_SPEED, _GAP = range(len(PERTURBATION_COLUMNS))


def start_offsets(params: Any, seeds: np.ndarray) -> np.ndarray:
    """(E, 4) lateral, longitudinal, heading, speed offsets of each seed's start; seed 0: none."""
    ranges = (params.start_lateral, params.start_longitudinal, params.start_heading, params.start_speed)
    lo, hi = np.array(ranges).T
    out = np.zeros((len(seeds), 4))
    for i, seed in enumerate(seeds):
        if int(seed) != 0:
            out[i] = np.random.default_rng(int(seed)).uniform(lo, hi)
    return out


class CommonRoadEpisodes:
    """A batch of episodes of one CommonRoad scene; start it with ``sim.episodes.reset(scene, seeds)``."""

    traffic_model = None
    traffic = None  # no simulated traffic: the obstacles replay

    def __init__(self, scene: Any, seeds: np.ndarray, agent_limit: int,
                 perturbation: np.ndarray | None = None, traffic_model: Any = None):
        p = scene.params
        self.blueprint = scene
        self.seeds = seeds
        self.agent_limit = agent_limit
        self.perturbation = perturbation
        e_n, n = len(seeds), len(scene.obstacle_ids)
        self.size = np.concatenate([[[p.vehicle_length, p.vehicle_width]], scene.obstacle_size])
        self.map_bounds = scene.road.bounds
        self._bicycle = KinematicBicycle(wheelbase=p.ego_wheelbase, dt=p.dt, max_accel=p.ego_accel[1],
                                         max_decel=-p.ego_accel[0], max_steer=p.ego_max_steer,
                                         max_speed=p.ego_max_speed)
        offsets = start_offsets(p, seeds)
        if perturbation is not None:
            if np.any(perturbation[:, [_AGENTS_SPEED, _GAP]] != 1.0):
                raise ValueError("a CommonRoad scene replays its obstacles: agents_speed_scale and gap_scale "
                                 "must be 1")
            offsets[:, :3] += perturbation[:, [_LAT, _LON, _HEADING]]
        init = scene.problem.initial
        heading = init.orientation + offsets[:, 2]
        c, s = np.cos(init.orientation), np.sin(init.orientation)
        lat, lon = offsets[:, 0], offsets[:, 1]
        ego_xy = np.stack([init.x + lon * c - lat * s, init.y + lon * s + lat * c], axis=-1)
        ego_speed = np.maximum(init.velocity + offsets[:, 3], 0.0)
        if perturbation is not None:
            ego_speed = ego_speed * perturbation[:, _SPEED]

        self.xy = np.empty((e_n, 1 + n, 2))
        self.yaw = np.empty((e_n, 1 + n))
        self.speed = np.empty((e_n, 1 + n))
        self._valid = np.empty((e_n, 1 + n), bool)
        self.xy[:, 0], self.yaw[:, 0], self.speed[:, 0], self._valid[:, 0] = ego_xy, heading, ego_speed, True
        self._reactive = None
        if scene.traffic == "reactive":
            self.traffic_model = traffic_model or TrafficModel()
            self._reactive = ReactiveObstacles(scene, e_n, self.traffic_model)
            self._reactive.start(np.zeros(e_n, np.int64))
        self._place_obstacles(np.zeros(e_n, np.int64))
        self._ego = AgentState(ego_xy - self._half_wheelbase(heading), heading, ego_speed)

        self.goal_centre = np.broadcast_to(scene.goal_centre, (e_n, 2)).copy()
        self.goal_heading = np.full(e_n, scene.goal_heading)
        self.goal_speed = np.full(e_n, scene.goal_speed)
        self.steps = np.zeros(e_n, np.int64)
        self.outcome = np.zeros(e_n, np.int8)
        self.returns = np.zeros(e_n)

    def _obstacles_at(self, k: np.ndarray) -> tuple[np.ndarray, ...]:
        """(xy (E, N, 2), yaw, speed, valid (E, N)) of the obstacles at steps ``k`` (E,): the recording's,
        the reacting cars' own where traffic is reactive."""
        scene = self.blueprint
        xy, yaw, speed, valid = scene.xy[k], scene.yaw[k], scene.speed[k], scene.valid[k]
        moving = self._reactive
        if moving is not None and len(moving.movers):
            cols = moving.movers
            xy[:, cols], yaw[:, cols] = moving.poses()
            speed[:, cols], valid[:, cols] = moving.v, moving.present
        return xy, yaw, speed, valid

    def _place_obstacles(self, k: np.ndarray, obstacles: tuple[np.ndarray, ...] | None = None) -> None:
        self.xy[:, 1:], self.yaw[:, 1:], self.speed[:, 1:], self._valid[:, 1:] = (
            obstacles if obstacles is not None else self._obstacles_at(k))

    def _half_wheelbase(self, yaw: np.ndarray) -> np.ndarray:
        # The bicycle's pose is the rear axle; the box (and CommonRoad's position) is its centre.
        half = 0.5 * self._bicycle.wheelbase
        return half * np.stack([np.cos(yaw), np.sin(yaw)], axis=-1)

    @property
    def valid(self) -> np.ndarray:
        """(E, A) bool: the ego, and the obstacles present at this step."""
        return self._valid

    @property
    def num_episodes(self) -> int:
        return len(self.seeds)

    @property
    def done(self) -> np.ndarray:
        return self.outcome != RUNNING

    def judge(self, xy: np.ndarray, yaw: np.ndarray, speed: np.ndarray, k: np.ndarray,
              obstacles: tuple[np.ndarray, ...] | None = None):
        """(goal, collision, off road), each (E,), of ego box centres ``xy`` (E, 2), headings and speeds
        (E,) at steps ``k`` (E,) against the ``obstacles`` (xy, yaw, speed, valid), by default the
        recording's at ``k``."""
        scene = self.blueprint
        ego_size = self.size[0]
        o_xy, o_yaw, _, o_valid = obstacles if obstacles is not None else (
            scene.xy[k], scene.yaw[k], None, scene.valid[k])
        hit = oriented_boxes_overlap(xy[:, None], yaw[:, None], ego_size, o_xy, o_yaw, self.size[1:]) & o_valid
        corners = box_corners(xy, yaw, ego_size)
        if scene.exact_shapes and hit.any():
            self._refine_hits(hit, corners, k)
        collision = np.any(hit, axis=-1)
        left = ~np.all(corners_on_road(scene, corners), axis=-1)
        goal = np.asarray(goal_reached(scene.problem, xy[:, 0], xy[:, 1], yaw, speed, scene.t0 + k), bool)
        return goal.reshape(-1), collision, left

    def _refine_hits(self, hit: np.ndarray, corners: np.ndarray, k: np.ndarray) -> None:
        """Clear the box hits (E, N) of obstacles whose box only bounds them where the ego's box (corners
        (E, 4, 2)) misses every shape they occupy at step ``k`` (sim.commonroad_occupancy).  A reacting
        car has left its recorded place: its box is all there is."""
        movers = set(self._reactive.movers.tolist()) if self._reactive is not None else set()
        for j, (index, shapes) in self.blueprint.exact_shapes.items():
            if j in movers:
                continue
            for e in np.flatnonzero(hit[:, j]):
                slot = index[k[e]]
                if slot >= 0 and not any(outline_meets_shape(corners[e], s) for s in shapes[slot]):
                    hit[e, j] = False

    def step(self, actions: np.ndarray) -> StepResult:
        """Advance every running episode by one step; ``actions`` (E, 2) = (acceleration, steering angle)."""
        actions = checked_actions(actions, self.num_episodes)
        active = self.outcome == RUNNING
        ego = self._bicycle.step(self._ego, (actions[:, 0], actions[:, 1]))
        centre = ego.xy + self._half_wheelbase(ego.yaw)
        steps = self.steps + active
        if self._reactive is not None:
            # Traffic moves from the same snapshot as the ego, as in the blueprints.
            self._reactive.advance(self.xy, self.yaw, self.speed, self._valid, self.size, self.blueprint.dt, active)
            self._reactive.start(steps)
        obstacles = self._obstacles_at(steps)
        goal, collision, left = self.judge(centre, ego.yaw, ego.speed, steps, obstacles)
        outcome = classify(goal, collision, left, steps >= self.blueprint.max_steps)
        reward = step_reward(outcome, active)

        run = active[:, None]
        self._ego = AgentState(np.where(run, ego.xy, self._ego.xy), np.where(active, ego.yaw, self._ego.yaw),
                               np.where(active, ego.speed, self._ego.speed))
        self.xy[:, 0] = np.where(run, centre, self.xy[:, 0])
        self.yaw[:, 0] = self._ego.yaw
        self.speed[:, 0] = self._ego.speed
        self._place_obstacles(steps, obstacles)
        self.steps = steps
        ended = np.where(active, outcome, RUNNING)
        self.outcome = np.where(active, outcome, self.outcome).astype(np.int8)
        self.returns = self.returns + reward
        return StepResult(reward, self.outcome != RUNNING, ended == GOAL, ended == COLLISION, ended == OFF_ROAD,
                          ended == STEP_LIMIT)
