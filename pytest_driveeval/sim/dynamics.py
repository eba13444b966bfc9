"""How agents move over one step: a :class:`Dynamics` turns an
:class:`~pytest_driveeval.sim.state.AgentState` and an action into the next state.

Three models, all vectorised over the state's leading dimensions:

* :class:`PoseTarget`: the action is the next pose and the agent simply takes
  it.  That is l5kit's closed loop, where the policy fully controls the ego.
* :class:`Unicycle`: the action is still the next pose, but a planning model
  may ask for any pose (a sideways jump, a spin on the spot, a 0 -> 100 km/h
  leap), so it is projected onto a unicycle with bounded acceleration, yaw
  rate and curvature: the requested speed and heading change are clipped to
  the limits and the pose is re-integrated (midpoint heading).  Whatever the
  model says, the ego moves like a vehicle.
* :class:`KinematicBicycle`: the action is a control, (acceleration, steering
  angle), for policies that drive rather than place the car.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from pytest_driveeval.geometry import wrap_angle
from pytest_driveeval.sim.state import AgentState

__all__ = ["Dynamics", "KinematicBicycle", "KinematicLimits", "PoseTarget", "Unicycle"]


class Dynamics(Protocol):
    """One step of ``dt`` seconds: ``step(state, action) -> next state``.

    ``action`` is a pair of arrays broadcasting with the state's leading
    dimensions; what they mean depends on the model (a pose, or controls).
    """

    @property
    def dt(self) -> float: ...

    def step(self, state: AgentState, action: tuple[np.ndarray, np.ndarray]) -> AgentState: ...


@dataclass(frozen=True)
class PoseTarget:
    """Move to the requested pose, action = (xy (..., 2), yaw (...)) in world coordinates.

    The returned arrays are the action's own (not copies).  The speed is the
    displacement along the mean heading over ``dt``, what the pose implies.
    """

    dt: float = 0.1

    def step(self, state: AgentState, action: tuple[np.ndarray, np.ndarray]) -> AgentState:
        target_xy, target_yaw = action
        mid = state.yaw + 0.5 * wrap_angle(target_yaw - state.yaw)
        d = target_xy - state.xy
        return AgentState(target_xy, target_yaw, (d[..., 0] * np.cos(mid) + d[..., 1] * np.sin(mid)) / self.dt)


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


@dataclass(frozen=True)
class Unicycle:
    """The reachable pose closest in intent to the requested one, action = (xy (..., 2), yaw (...)).

    The requested speed is the displacement projected on the mean heading
    (so sideways jumps do not count as progress); the heading change is
    limited by both the yaw rate and the curvature at the new speed, so a
    standing car cannot turn.
    """

    limits: KinematicLimits = field(default_factory=KinematicLimits)

    @property
    def dt(self) -> float:
        return self.limits.dt

    def step(self, state: AgentState, action: tuple[np.ndarray, np.ndarray]) -> AgentState:
        limits = self.limits
        xy, target_xy = np.asarray(state.xy, np.float64), np.asarray(action[0], np.float64)
        yaw, speed = np.asarray(state.yaw, np.float64), np.asarray(state.speed, np.float64)
        dt = limits.dt
        dyaw_req = wrap_angle(np.asarray(action[1], np.float64) - yaw)
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
        return AgentState(new_xy, wrap_angle(yaw + dyaw), v)


@dataclass(frozen=True)
class KinematicBicycle:
    """Controls, action = (acceleration (...) m/s^2, steering angle (...) rad, positive to the left).

    The pose is the rear axle's, which turns on a circle of radius
    ``wheelbase / tan(steer)``.  Acceleration, steering angle and speed are
    clipped to their bounds.
    """

    wheelbase: float = 2.8  # m
    dt: float = 0.1  # s
    max_accel: float = 3.0  # m/s^2
    max_decel: float = 8.0  # m/s^2, emergency braking
    max_steer: float = 0.6  # rad
    max_speed: float = 40.0  # m/s
    allow_reverse: bool = False

    def step(self, state: AgentState, action: tuple[np.ndarray, np.ndarray]) -> AgentState:
        dt = self.dt
        accel = np.clip(np.asarray(action[0], np.float64), -self.max_decel, self.max_accel)
        steer = np.clip(np.asarray(action[1], np.float64), -self.max_steer, self.max_steer)
        yaw, speed = np.asarray(state.yaw, np.float64), np.asarray(state.speed, np.float64)
        lo = -self.max_speed if self.allow_reverse else 0.0
        v = np.clip(speed + accel * dt, lo, self.max_speed)
        arc = 0.5 * (speed + v) * dt  # constant acceleration: the mean speed's distance
        dyaw = arc * np.tan(steer) / self.wheelbase
        # The chord of that arc, along the mean heading: exact however long the step.
        chord = arc * np.sinc(dyaw / (2.0 * np.pi))
        mid = yaw + 0.5 * dyaw
        new_xy = np.asarray(state.xy, np.float64) + chord[..., None] * np.stack([np.cos(mid), np.sin(mid)], axis=-1)
        return AgentState(new_xy, wrap_angle(yaw + dyaw), v)
