"""The policy benchmark's engine: E seeded episodes of one blueprint, stepped together.

``reset(blueprint, seeds, agent_limit)`` draws episode ``i`` from
``np.random.default_rng(seeds[i])`` alone and nothing in a step mixes
episodes, so an episode's course depends on its seed (and the blueprint,
traffic model and agent limit), never on which other episodes share the batch.

``reset(..., perturbation=rows)`` perturbs each episode's start by its own row
of :data:`PERTURBATION_COLUMNS` (a robustness search's example), so the course
then depends on the seed and that row alone; a no-change row
(:data:`NO_PERTURBATION`) gives the unperturbed episode bit for bit:

* ``lateral``, ``longitudinal`` (m, in the ego's frame at the start, lateral
  positive to its left) and ``heading`` (rad) move the ego off its lane;
* ``speed_scale`` multiplies the ego's initial speed;
* ``agents_speed_scale`` multiplies the traffic's initial *and* IDM desired
  speeds: scaling the initial speeds alone would fade within seconds as IDM
  pulls every vehicle back to its desired speed;
* ``gap_scale`` multiplies the blueprint's spawn gaps from the same draws
  (traffic density is 1 / gap: below 1 denser), never closer than a length
  plus :data:`~pytest_driveeval.sim.blueprints.base.SPAWN_CLEARANCE`.

A vehicle that the moved ego would overlap at the start is left out of that
episode: a start inside another vehicle tests no policy.

Per step, all episodes at once: the ego moves by a kinematic bicycle driven
by the action (acceleration m/s^2, steering angle rad, clipped to the
blueprint's ``ego_accel`` and ``ego_max_steer``), traffic by
:func:`~pytest_driveeval.sim.agents.step_traffic` from the same snapshot, then
the outcomes of :mod:`pytest_driveeval.metrics.episode_outcomes` are judged on
the new snapshot.  An episode that has ended keeps its last state: stepping it
again changes nothing and earns nothing.

For observers (the graph observation), in world coordinates: ``xy`` (E, A, 2),
``yaw``, ``speed``, ``valid`` (E, A) with agent 0 the ego (always valid) and
invalid rows padding or vehicles that left the map; ``goal_centre`` (E, 2),
``goal_heading`` (E,), ``goal_speed`` (E,) (the middle of the goal's speed
bounds); ``map_bounds`` (xmin, ymin, xmax, ymax).  Every agent's box is
``size`` (length, width); a pose is the box centre.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import fields
from typing import NamedTuple

import numpy as np

from pytest_driveeval.geometry import box_corners, oriented_boxes_overlap
from pytest_driveeval.metrics.episode_outcomes import (
    COLLISION,
    GOAL,
    OFF_ROAD,
    RUNNING,
    STEP_LIMIT,
    classify,
    ego_collides,
    in_goal,
    off_road,
    step_reward,
)
from pytest_driveeval.sim import episodes_jit
from pytest_driveeval.sim.agents import Traffic, TrafficModel, step_traffic
from pytest_driveeval.sim.blueprints import Blueprint, make_blueprint
from pytest_driveeval.sim.dynamics import KinematicBicycle
from pytest_driveeval.sim.state import AgentState

__all__ = ["NO_PERTURBATION", "PERTURBATION_COLUMNS", "Episodes", "StepResult", "checked_actions", "reset"]

#: the columns of ``reset``'s per-episode perturbation rows (the fields of strategies.EpisodePerturbation)
PERTURBATION_COLUMNS = ("lateral", "longitudinal", "heading", "speed_scale", "agents_speed_scale", "gap_scale")
NO_PERTURBATION = np.array([0.0, 0.0, 0.0, 1.0, 1.0, 1.0])
_LAT, _LON, _HEADING, _SPEED, _AGENTS_SPEED, _GAP = range(len(PERTURBATION_COLUMNS))

# Padding rows sit far upstream on lane 0, never valid.
_PAD_S = -1.0e4
# What the compiled step saves over the numpy one, per step and per episode (2-core machine, one core).
_SAVED_PER_STEP, _SAVED_PER_EPISODE = 6.0e-4, 3.0e-5


class StepResult(NamedTuple):
    """What one step did, each (E,).  The four flags mark episodes that ended on this step and why."""

    reward: np.ndarray  # float, 0 for episodes that had already ended
    done: np.ndarray  # bool, ended on this step or before
    goal: np.ndarray
    collision: np.ndarray
    off_road: np.ndarray
    step_limit: np.ndarray


class Episodes:
    """A batch of episodes in flight; build it with :func:`reset`."""

    def __init__(self, blueprint: Blueprint, seeds: np.ndarray, agent_limit: int, traffic_model: TrafficModel,
                 perturbation: np.ndarray | None = None):
        p = blueprint.params
        self.blueprint = blueprint
        self.traffic_model = traffic_model
        self.seeds = seeds
        self.agent_limit = agent_limit
        self.size = np.array([p.vehicle_length, p.vehicle_width])
        self.map_bounds = blueprint.road.bounds
        self._bicycle = KinematicBicycle(wheelbase=p.ego_wheelbase, dt=p.dt, max_accel=p.ego_accel[1],
                                         max_decel=-p.ego_accel[0], max_steer=p.ego_max_steer,
                                         max_speed=p.ego_max_speed)
        self.perturbation = perturbation
        # A custom blueprint's spawn may not take gap_scale; it is only asked to when it changes.
        spawns = [blueprint.spawn(np.random.default_rng(int(seed)), agent_limit)
                  if perturbation is None or perturbation[i, _GAP] == 1.0
                  else blueprint.spawn(np.random.default_rng(int(seed)), agent_limit, gap_scale=perturbation[i, _GAP])
                  for i, seed in enumerate(seeds)]
        e_n, a_n = len(spawns), agent_limit
        lane = np.zeros((e_n, a_n), np.int64)
        s = np.full((e_n, a_n), _PAD_S)
        speed = np.zeros((e_n, a_n))
        desired = np.ones((e_n, a_n))
        valid = np.zeros((e_n, a_n), bool)
        for i, sp in enumerate(spawns):
            n = len(sp.s)
            lane[i, 0], s[i, 0], speed[i, 0], valid[i, 0] = sp.ego_lane, sp.ego_s, sp.ego_speed, True
            lane[i, 1:n + 1], s[i, 1:n + 1], speed[i, 1:n + 1] = sp.lane, sp.s, sp.speed
            desired[i, 1:n + 1], valid[i, 1:n + 1] = sp.desired_speed, True
        # The ego's slot: traffic judges whether it may cut in front of the ego by
        # the ego's IDM response, taken at the fastest desired speed of traffic.
        desired[:, 0] = p.desired_speed[1]
        xy, heading = blueprint.road.pose(lane, s, 0.0)
        if perturbation is not None:
            self._perturb(perturbation, xy, heading, speed, desired, valid)
        settled = traffic_model.lane_change_duration + traffic_model.lane_change_cooldown
        self._traffic = Traffic(lane, s, np.zeros((e_n, a_n)), speed, desired, np.zeros((e_n, a_n)),
                                np.full((e_n, a_n), settled), np.full((e_n, a_n), -1), valid)
        self.xy, self.yaw, self.speed = xy, heading, speed.copy()
        self._ego = AgentState(xy[:, 0] - self._half_wheelbase(heading[:, 0]), heading[:, 0], speed[:, 0])

        self.goal_centre = np.stack([sp.goal.centre for sp in spawns])
        self.goal_heading = np.array([sp.goal.heading for sp in spawns])
        self.goal_size = np.array([[sp.goal.length, sp.goal.width] for sp in spawns])
        self.goal_heading_tol = np.array([sp.goal.heading_tol for sp in spawns])
        self.goal_speed_bounds = np.array([sp.goal.speed for sp in spawns])
        self.goal_speed = self.goal_speed_bounds.mean(axis=1)

        self.steps = np.zeros(e_n, np.int64)
        self.outcome = np.zeros(e_n, np.int8)
        self.returns = np.zeros(e_n)
        self._compilable = episodes_jit.supported(blueprint.road, traffic_model, self._bicycle)
        self._jit_constants: episodes_jit.Constants | None = None

    def _perturb(self, rows: np.ndarray, xy: np.ndarray, heading: np.ndarray, speed: np.ndarray,
                 desired: np.ndarray, valid: np.ndarray) -> None:
        """Each episode's start moved by its row, in place (see the module's docstring)."""
        c, s = np.cos(heading[:, 0]), np.sin(heading[:, 0])
        lon, lat = rows[:, _LON], rows[:, _LAT]
        xy[:, 0, 0] += lon * c - lat * s
        xy[:, 0, 1] += lon * s + lat * c
        heading[:, 0] += rows[:, _HEADING]
        speed[:, 0] *= rows[:, _SPEED]
        scale = rows[:, _AGENTS_SPEED, None]
        speed[:, 1:] *= scale
        # IDM divides by the desired speed: keep it at the blueprints' smallest allowed value.
        desired *= scale
        np.maximum(desired, 0.1, out=desired)
        overlaps = oriented_boxes_overlap(xy[:, :1], heading[:, :1], self.size, xy[:, 1:], heading[:, 1:], self.size)
        valid[:, 1:] &= ~overlaps

    @property
    def valid(self) -> np.ndarray:
        """(E, A) bool: the ego, and the vehicles still on the map."""
        return self._traffic.valid

    def _half_wheelbase(self, yaw: np.ndarray) -> np.ndarray:
        # The bicycle's pose is the rear axle; boxes are centred half a wheelbase ahead of it.
        half = 0.5 * self._bicycle.wheelbase
        return half * np.stack([np.cos(yaw), np.sin(yaw)], axis=-1)

    @property
    def num_episodes(self) -> int:
        return len(self.seeds)

    @property
    def done(self) -> np.ndarray:
        return self.outcome != RUNNING

    @property
    def traffic(self) -> Traffic:
        return self._traffic

    def step(self, actions: np.ndarray) -> StepResult:
        """Advance every running episode by one step; ``actions`` (E, 2) = (acceleration, steering angle)."""
        actions = checked_actions(actions, self.num_episodes)
        if self._compilable and episodes_jit.wanted(_SAVED_PER_STEP + _SAVED_PER_EPISODE * self.num_episodes):
            return self._step_compiled(actions)
        bp, road = self.blueprint, self.blueprint.road
        active = self.outcome == RUNNING

        ego = self._bicycle.step(self._ego, (actions[:, 0], actions[:, 1]))
        traffic, xy, yaw = step_traffic(road, self.traffic_model, self._traffic, self.xy, self.yaw, self.speed,
                                        (self.size[0], self.size[1]), bp.dt)
        xy[:, 0] = ego.xy + self._half_wheelbase(ego.yaw)
        yaw[:, 0] = ego.yaw
        speed = traffic.speed.copy()
        speed[:, 0] = ego.speed
        valid = traffic.valid

        collision = ego_collides(xy, yaw, self.size, valid)
        grid = road.drivable
        left = off_road(box_corners(xy[:, 0], yaw[:, 0], self.size), grid.mask, grid.origin, grid.resolution)
        goal = in_goal(xy[:, 0], yaw[:, 0], speed[:, 0], self.goal_centre, self.goal_heading, self.goal_size,
                       self.goal_heading_tol, self.goal_speed_bounds)
        steps = self.steps + active
        outcome = classify(goal, collision, left, steps >= bp.max_steps)
        reward = step_reward(outcome, active)

        run = active[:, None]
        self._ego = AgentState(np.where(run, ego.xy, self._ego.xy), np.where(active, ego.yaw, self._ego.yaw),
                               np.where(active, ego.speed, self._ego.speed))
        old = self._traffic
        # Desired speeds are the spawn's for the whole episode: nothing to merge.
        self._traffic = Traffic(*(old.desired_speed if f.name == "desired_speed" else
                                  np.where(run, getattr(traffic, f.name), getattr(old, f.name))
                                  for f in fields(Traffic)))
        self.xy = np.where(run[..., None], xy, self.xy)
        self.yaw = np.where(run, yaw, self.yaw)
        self.speed = np.where(run, speed, self.speed)
        self.steps = steps
        ended = np.where(active, outcome, RUNNING)
        self.outcome = np.where(active, outcome, self.outcome).astype(np.int8)
        self.returns = self.returns + reward
        return StepResult(reward, self.outcome != RUNNING, ended == GOAL, ended == COLLISION, ended == OFF_ROAD,
                          ended == STEP_LIMIT)

    def _step_compiled(self, actions: np.ndarray) -> StepResult:
        """The same step by :mod:`.episodes_jit`'s kernels, bit for bit."""
        if self._jit_constants is None:
            self._jit_constants = episodes_jit.constants(self.blueprint, self.traffic_model, self._bicycle, self.size)
        traffic, ego, (xy, yaw, speed), (steps, outcome, returns), reward, flags = episodes_jit.step(
            self, self._ego, self._jit_constants, actions)
        # Traffic's frozen __init__ sets each field through object.__setattr__: a tenth of a compiled step.
        self._traffic = object.__new__(Traffic)
        self._traffic.__dict__.update(traffic)
        self._ego = AgentState(*ego)
        self.xy, self.yaw, self.speed = xy, yaw, speed
        self.steps, self.outcome, self.returns = steps, outcome, returns
        return StepResult(reward, *flags)  # done, then ended by goal, collision, off-road, step limit


def checked_actions(actions: np.ndarray, episodes: int) -> np.ndarray:
    """``actions`` as (E, 2) float64 (acceleration, steering), or a ValueError naming what is wrong
    and, for a value that is not finite, which episodes."""
    actions = np.asarray(actions, dtype=np.float64)
    if actions.shape != (episodes, 2):
        raise ValueError(f"actions must be ({episodes}, 2) (acceleration, steering), got shape {actions.shape}")
    if not np.isfinite(actions).all():
        bad = np.flatnonzero(~np.all(np.isfinite(actions), axis=1))
        raise ValueError(f"actions must be finite; episodes {bad.tolist()} got {actions[bad].tolist()}")
    return actions


def reset(blueprint: Blueprint | str, seeds: Sequence[int] | np.ndarray, agent_limit: int = 12,
          traffic_model: TrafficModel | None = None, perturbation: np.ndarray | None = None) -> Episodes:
    """Start one episode per seed; ``agent_limit`` counts the ego (rows beyond an
    episode's vehicles are padding, ``valid`` False).  ``blueprint`` may also be a
    CommonRoad scene (sim.commonroad_scene), which starts its own kind of episodes.  ``perturbation``: (E, 6)
    rows of :data:`PERTURBATION_COLUMNS`, one per seed, or None."""
    if isinstance(blueprint, str):
        blueprint = make_blueprint(blueprint)
    seeds = np.asarray(seeds)
    if seeds.ndim != 1 or len(seeds) == 0 or not np.issubdtype(seeds.dtype, np.integer) or np.any(seeds < 0):
        raise ValueError(f"seeds must be a non-empty 1-D array of non-negative integers, got {seeds!r}")
    if isinstance(agent_limit, bool) or not isinstance(agent_limit, (int, np.integer)) or agent_limit < 1:
        raise ValueError(f"agent_limit must be an integer >= 1 (the ego counts), got {agent_limit!r}")
    if perturbation is not None:
        perturbation = _checked_perturbation(perturbation, len(seeds))
    # A scene that steps its own episodes (sim.commonroad_scene: obstacles replayed from a recording).
    start = getattr(blueprint, "start_episodes", None)
    if start is not None:
        return start(seeds, int(agent_limit), traffic_model, perturbation)
    return Episodes(blueprint, seeds, int(agent_limit), traffic_model or TrafficModel(), perturbation)


def _checked_perturbation(rows, episodes: int) -> np.ndarray:
    rows = np.array(rows, dtype=np.float64)
    if rows.shape != (episodes, len(PERTURBATION_COLUMNS)):
        raise ValueError(f"perturbation must be ({episodes}, {len(PERTURBATION_COLUMNS)}) rows of "
                         f"({', '.join(PERTURBATION_COLUMNS)}), got shape {rows.shape}")
    bad = ~np.isfinite(rows).all(axis=1) | (rows[:, _SPEED] < 0) | (rows[:, _AGENTS_SPEED] < 0) | (rows[:, _GAP] <= 0)
    if bad.any():
        first = int(np.flatnonzero(bad)[0])
        raise ValueError(f"perturbation row {first} {rows[first].tolist()}: values must be finite, speed scales "
                         ">= 0 and gap_scale > 0")
    return rows
