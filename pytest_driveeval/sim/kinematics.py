"""Make a predicted next pose one a car could reach in one step.

A planning model may output any next pose: a sideways jump, a spin on the
spot, a 0 -> 100 km/h leap.  :func:`feasible_step` projects it onto a
unicycle with bounded acceleration, yaw rate and curvature: the requested
speed and heading change are clipped to the limits and the pose is
re-integrated (midpoint heading), so whatever the model says, the ego moves
like a vehicle.  Everything is vectorised over a batch of egos.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pytest_driveeval.geometry import wrap_angle

__all__ = ["KinematicLimits", "feasible_step"]


@dataclass(frozen=True)
class KinematicLimits:
    """Bounds of one step; defaults are a comfortable passenger car at 10 Hz."""

    dt: float = 0.1  # s
    max_accel: float = 3.0  # m/s^2
    max_decel: float = 8.0  # m/s^2, emergency braking
    max_speed: float = 40.0  # m/s
    max_yaw_rate: float = 1.0  # rad/s
    max_curvature: float = 0.2  # 1/m (turning radius 5 m)
    allow_reverse: bool = False


def feasible_step(xy: np.ndarray, yaw: np.ndarray, speed: np.ndarray, target_xy: np.ndarray, target_yaw: np.ndarray,
                  limits: KinematicLimits = KinematicLimits()) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Next pose closest in intent to ``target`` that respects ``limits``.

    xy (B, 2), yaw (B,), speed (B,) signed along the heading: the current
    state.  target_xy (B, 2), target_yaw (B,): the requested next pose in
    world coordinates.  Returns (xy, yaw, speed) after one ``limits.dt`` step.

    The requested speed is the displacement projected on the mean heading
    (so sideways jumps do not count as progress); the heading change is
    limited by both the yaw rate and the curvature at the new speed, so a
    standing car cannot turn.
    """
    xy, target_xy = np.asarray(xy, np.float64), np.asarray(target_xy, np.float64)
    yaw, speed = np.asarray(yaw, np.float64), np.asarray(speed, np.float64)
    dt = limits.dt
    dyaw_req = wrap_angle(np.asarray(target_yaw, np.float64) - yaw)
    mid = yaw + 0.5 * dyaw_req
    d = target_xy - xy
    v_req = (d[..., 0] * np.cos(mid) + d[..., 1] * np.sin(mid)) / dt
    lo = -limits.max_speed if limits.allow_reverse else 0.0
    v = np.clip(v_req, speed - limits.max_decel * dt, speed + limits.max_accel * dt)
    v = np.clip(v, lo, limits.max_speed)
    # Heading change allowed over the step: yaw rate bound, and curvature bound
    # on the mean speed (the arc actually driven).
    arc = 0.5 * np.abs(speed + v) * dt
    max_dyaw = np.minimum(limits.max_yaw_rate * dt, limits.max_curvature * arc)
    dyaw = np.clip(dyaw_req, -max_dyaw, max_dyaw)
    mid = yaw + 0.5 * dyaw
    step = 0.5 * (speed + v) * dt
    new_xy = xy + step[..., None] * np.stack([np.cos(mid), np.sin(mid)], axis=-1)
    return new_xy, wrap_angle(yaw + dyaw), v
