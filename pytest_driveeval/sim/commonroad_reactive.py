"""``Traffic: reactive`` in a CommonRoad scene: each recorded car drives its recorded path as a lane,
at the speed the benchmark's IDM (sim.agents, highway-env's constants) gives it behind whatever is
ahead on that path, the ego included.

* A dynamic obstacle appears at its first recorded time step, at its recorded state there (arclength
  along its path and speed); it leaves when it has driven past its path's end (not at its last
  recorded time step: held up by the ego, it arrives later).  Its IDM desired speed is the fastest
  speed of its recording (at least 0.1 m/s).
* What is ahead: every present agent whose box centre lies on the path within half the two boxes'
  widths sideways, ahead of the follower's centre; the gap is bumper to bumper along the path.
* A path is the recording's box centres thinned to points about 2 m apart; positions along it are
  the recording's own arclengths (a chord shortens a curve's arc by a few millimetres per 2 m).
* Static obstacles, and dynamic ones that never move (a path shorter than a centimetre), replay
  their recording: they stand where they were recorded.

Vectorised over (episodes, agents, paths): every agent is projected onto every path once per step
(:meth:`Road.project <pytest_driveeval.sim.blueprints.road.Road.project>`, the recorded paths as lanes).
"""
from __future__ import annotations

from typing import Any

import numpy as np

from pytest_driveeval.geometry.planar import arc_lengths
from pytest_driveeval.sim.agents import TrafficModel, idm_advance, idm_free, idm_interaction
from pytest_driveeval.sim.blueprints.road import Lane, Road

__all__ = ["ReactiveObstacles"]

_MIN_PATH = 0.01  # m: a recorded path shorter than this is a standing obstacle
_SPACING = 2.0  # m between the points of a path as a lane (the arclengths are the recording's own)


def _thinned(path: np.ndarray, along: np.ndarray) -> np.ndarray:
    """The recorded path's points about :data:`_SPACING` m apart (and its ends): recordings at 10 Hz hold
    a point every few decimetres, and each step projects every agent onto every segment."""
    marks = np.arange(0.0, along[-1], _SPACING)
    keep = np.unique(np.concatenate([np.searchsorted(along, marks), [len(path) - 1]]))
    keep = keep[np.concatenate([[True], np.diff(along[keep]) > 1e-6])]
    return path[keep]


class ReactiveObstacles:
    """The moving obstacles of one batch of episodes; ``advance`` moves them one step."""

    def __init__(self, scene: Any, episodes: int, model: TrafficModel | None = None):
        self.model = model or TrafficModel()
        self.scene = scene
        times = scene.t0 + np.arange(scene.max_steps + 1)
        lanes, movers, s_rec, v0 = [], [], [], []
        for j, ident in enumerate(scene.obstacle_ids):
            obstacle = scene.scenario.obstacles[int(ident)]
            if obstacle.role != "dynamic":
                continue
            path = scene.recorded_paths[j]
            along = arc_lengths(path)  # of each recorded state
            if len(path) < 2 or along[-1] < _MIN_PATH:
                continue
            lanes.append(Lane(_thinned(path, along), float(scene.obstacle_size[j, 1]), str(ident)))
            movers.append(j)
            traj = obstacle.trajectory
            i = np.clip(times - int(traj.t[0]), 0, len(traj) - 1)
            s_rec.append(along[i])
            v0.append(max(float(np.nanmax(np.nan_to_num(traj.velocity, nan=0.0))), 0.1))
        self.movers = np.array(movers, np.int64)  # obstacle columns (0-based) that react
        self.first = np.array([int(scene.scenario.obstacles[int(scene.obstacle_ids[j])].trajectory.t[0]) - scene.t0
                               for j in movers], np.int64)
        n = len(movers)
        self.s_rec = np.stack(s_rec, axis=1) if n else np.zeros((len(times), 0))  # (K + 1, M)
        self.desired = np.array(v0)
        # Only the projection is used: a coarse raster keeps the road's drivable grid, never read, cheap.
        self.paths = Road(tuple(lanes), resolution=5.0) if n else None
        self.s = np.zeros((episodes, n))
        self.v = np.zeros((episodes, n))
        self.present = np.zeros((episodes, n), bool)
        self.appeared = np.zeros((episodes, n), bool)

    def start(self, k: np.ndarray) -> None:
        """Obstacles whose recording starts by step ``k`` (E,) and that have not appeared yet appear."""
        if not len(self.movers):
            return
        new = ~self.appeared & (self.first[None, :] <= k[:, None])
        rows = np.broadcast_to(k[:, None], new.shape)
        cols = np.broadcast_to(np.arange(len(self.movers)), new.shape)
        self.s = np.where(new, self.s_rec[rows, cols], self.s)
        self.v = np.where(new, self.scene.speed[rows, self.movers[cols]], self.v)
        self.present |= new
        self.appeared |= new

    def advance(self, xy: np.ndarray, yaw: np.ndarray, speed: np.ndarray, valid: np.ndarray, sizes: np.ndarray,
                dt: float, active: np.ndarray) -> None:
        """One IDM step of every present mover of the ``active`` episodes, from all agents' poses and
        speeds now: (E, A, 2), (E, A), (E, A), (E, A); ``sizes`` (A, 2)."""
        if not len(self.movers):
            return
        m = self.model
        proj = self.paths.project(xy)  # (E, A, M): every agent on every mover's path
        cols = 1 + self.movers
        half_w, half_l = 0.5 * sizes[:, 1], 0.5 * sizes[:, 0]
        on_path = np.abs(proj.d) <= half_w[None, :, None] + half_w[cols][None, None, :]
        ahead_by = proj.s - self.s[:, None, :]
        not_self = np.ones((valid.shape[1], len(cols)), bool)
        not_self[cols, np.arange(len(cols))] = False
        leaders = valid[:, :, None] & not_self[None] & on_path & (ahead_by > 0.0)
        gap = ahead_by - half_l[None, :, None] - half_l[cols][None, None, :]
        lead_speed = speed[:, :, None] * np.cos(yaw[:, :, None] - proj.heading)
        push = np.where(leaders, idm_interaction(m, self.v[:, None, :], lead_speed, gap), 0.0).max(axis=1)
        accel = idm_free(m, self.v, self.desired[None, :]) - m.max_accel * push
        travel, v_next = idm_advance(m, self.v, accel, dt)
        run = active[:, None] & self.present
        self.s = np.where(run, self.s + travel, self.s)
        self.v = np.where(run, v_next, self.v)
        self.present &= ~(run & (self.s > self.paths.lengths[None, :] + half_l[cols][None, :]))

    def poses(self) -> tuple[np.ndarray, np.ndarray]:
        """(xy (E, M, 2), heading (E, M)) of the movers on their paths."""
        return self.paths.pose(np.broadcast_to(np.arange(len(self.movers)), self.s.shape), self.s, 0.0)
