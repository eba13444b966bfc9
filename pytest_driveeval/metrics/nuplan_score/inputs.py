"""What nuPlan's closed-loop score reads of one scene: the ego's states, the expert's path, the other
agents, the collisions already classified, and the map (None: the scene has none)."""
from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from pytest_driveeval.geometry.planar import wrap_angle

from .lanes import ScoreMap

#: nuPlan's ego (a Chrysler Pacifica): its box centre lies this fraction of its length ahead of the rear axle
REAR_AXLE_SHARE = 1.461 / 5.176
#: nuPlan's collision groups; a collision with a static object of group "object" costs half
GROUPS = ("vehicle", "vru", "object")
#: whose rules find and blame the collisions the score counts (ScoreInputs.blame)
BLAMES = ("nuplan", "engine")


@dataclass
class EgoStates:
    """Per frame: the box centre's pose (T, 3) x, y, heading; the rear axle's velocity and acceleration
    (T, 2) in the ego's frame (x forward, y left); the heading's rate and its rate of change (T,)."""

    center: np.ndarray
    length: float
    width: float
    rear_axle_to_center: float
    velocity: np.ndarray
    acceleration: np.ndarray
    angular_velocity: np.ndarray
    angular_acceleration: np.ndarray
    #: the comfort signals (comfort.signals_of), where made with the states for several scenes at once
    comfort: dict | None = None

    # Computed once a scene (several terms read them); the states are not changed once built.  States made
    # for several scenes at once compute them for all, and each scene's share takes its rows.
    @cached_property
    def heading_unit(self) -> np.ndarray:
        """(2, T) the cosine and the sine of the box's heading."""
        h = self.center[..., 2]
        return np.stack([np.cos(h), np.sin(h)])

    @cached_property
    def rear_axle(self) -> np.ndarray:
        back = self.rear_axle_to_center * np.moveaxis(self.heading_unit, 0, -1)
        return self.center[..., :2] - back

    @cached_property
    def speed(self) -> np.ndarray:
        return np.hypot(self.velocity[..., 0], self.velocity[..., 1])

    @cached_property
    def corners(self) -> np.ndarray:
        """(T, 4, 2) corners FL, FR, RR, RL of the ego's box."""
        from pytest_driveeval.geometry.boxes import box_corners

        return box_corners(self.center[..., :2], self.center[..., 2], np.array([self.length, self.width]))

    def scene(self, i: int) -> "EgoStates":
        """Scene ``i`` of states made for several scenes at once (views of their arrays, and of what was
        computed from them for all)."""
        one = EgoStates(self.center[i], self.length, self.width, self.rear_axle_to_center, self.velocity[i],
                        self.acceleration[i], self.angular_velocity[i], self.angular_acceleration[i],
                        None if self.comfort is None else {k: v[i] for k, v in self.comfort.items()})
        for name in ("rear_axle", "speed", "corners"):
            if name in self.__dict__:
                one.__dict__[name] = self.__dict__[name][i]
        if "heading_unit" in self.__dict__:
            one.__dict__["heading_unit"] = self.heading_unit[:, i]
        return one


def ego_from_poses(center_xy: np.ndarray, heading: np.ndarray, times: np.ndarray, length: float, width: float,
                   rear_axle_to_center: float | None = None) -> EgoStates:
    """Ego states from driven poses alone: the rear axle's velocity and acceleration by central
    differences over the frames' times (a simulator's controller would report them; a log replay has
    only poses), rotated into the ego's frame.  ``center_xy`` (..., T, 2) and ``heading`` (..., T):
    leading axes (scenes driven at the same times) stay leading axes of every state
    (:meth:`EgoStates.scene` takes one); each scene's numbers are those it gets alone."""
    d = REAR_AXLE_SHARE * length if rear_axle_to_center is None else rear_axle_to_center
    heading = np.asarray(heading, dtype=np.float64)
    c, s = np.cos(heading)[..., None], np.sin(heading)[..., None]
    rear = center_xy - d * np.concatenate([c, s], axis=-1)
    unwrapped = np.unwrap(heading)
    if len(times) >= 2:
        # the position's and the heading's derivatives in one call each (a gradient is column by column)
        rate = np.gradient(np.concatenate([rear, unwrapped[..., None]], axis=-1), times, axis=-2)
        accel = np.gradient(rate, times, axis=-2)
        world_v, world_a = rate[..., :2], accel[..., :2]
        yaw_rate, yaw_accel = rate[..., 2], accel[..., 2]
    else:
        world_v = world_a = np.zeros((*heading.shape, 2))
        yaw_rate = yaw_accel = np.zeros(heading.shape)

    def body(v):
        return np.concatenate([c * v[..., :1] + s * v[..., 1:], -s * v[..., :1] + c * v[..., 1:]], axis=-1)

    center = np.concatenate([center_xy, wrap_angle(heading)[..., None]], axis=-1)
    return EgoStates(center, float(length), float(width), float(d), body(world_v), body(world_a), yaw_rate, yaw_accel)


@dataclass
class AgentCells:
    """The other agents, (T, A) cells: A columns, a column may hold different agents over time (``token``
    says whose state a cell holds, -1 where empty).  ``xy`` (T, A, 2) and ``yaw`` (T, A) the box centre's
    pose; ``length``/``width`` (T, A); ``velocity`` (T, A, 2) world frame; ``group`` (T, A) index into
    :data:`GROUPS`; ``static`` (T, A): a static object (nuPlan builds no velocity for it).

    The float arrays may be float32 (a log's own, as views: no copy per scene): the score widens to
    float64 what it reads, before any arithmetic of its own, so its numbers are those of float64 inputs."""

    xy: np.ndarray
    yaw: np.ndarray
    length: np.ndarray
    width: np.ndarray
    velocity: np.ndarray
    available: np.ndarray
    token: np.ndarray
    group: np.ndarray
    static: np.ndarray

    @property
    def center(self) -> np.ndarray:
        """(T, A, 3) x, y, heading in float64 (a copy)."""
        return np.concatenate([self.xy, self.yaw[..., None]], axis=-1, dtype=np.float64)

    @classmethod
    def empty(cls, frames: int) -> "AgentCells":
        z = np.zeros((frames, 0))
        return cls(np.zeros((frames, 0, 2)), z, z, z, np.zeros((frames, 0, 2)), z.astype(bool), z.astype(np.int64),
                   z.astype(np.int8), z.astype(bool))


@dataclass(frozen=True)
class Collision:
    """The ego's first contact with one agent: at frame row ``frame``, blamed on the ego or not;
    ``kind``: nuPlan's collision type where nuPlan's rules classified it (collisions.py), else None."""

    frame: int
    token: int
    group: str
    at_fault: bool
    kind: str | None = None


@dataclass
class ScoreInputs:
    """One scene.  ``times`` (T,) seconds; ``frame_numbers`` (T,) how findings name the frames (the
    log's numbering); ``expert`` (Te, 3) the logged ego's centre poses.  ``blame``: whose rules find and
    blame the collisions the score counts: "nuplan" (nuplan-devkit's, from the ego's and the agents'
    boxes: collisions.py) or "engine" (``collisions`` as the engine recorded and blamed them)."""

    times: np.ndarray
    ego: EgoStates
    expert: np.ndarray
    agents: AgentCells
    collisions: list[Collision]
    map: ScoreMap | None
    frame_numbers: np.ndarray = field(default=None)
    blame: str = "nuplan"

    def __post_init__(self):
        if self.blame not in BLAMES:
            raise ValueError(f"blame {self.blame!r}: one of {', '.join(BLAMES)}")
        if self.frame_numbers is None:
            self.frame_numbers = np.arange(len(self.times))

    @property
    def num_frames(self) -> int:
        return len(self.times)

    @cached_property
    def spacing(self) -> float:
        """The frames' mean time step, s (NaN with one frame)."""
        return float(np.mean(np.diff(self.times))) if len(self.times) > 1 else float("nan")


def first_collisions(frames: np.ndarray, tokens: np.ndarray, at_fault: np.ndarray, groups: dict[int, str]
                     ) -> list[Collision]:
    """Per agent, its first collision (nuPlan never counts an agent twice), from per-frame records:
    ``frames`` row index, ``tokens`` the agent hit, ``at_fault`` the blame of that frame."""
    seen: dict[int, Collision] = {}
    for f, t, a in zip(np.asarray(frames).tolist(), np.asarray(tokens).tolist(), np.asarray(at_fault).tolist()):
        if t not in seen:
            seen[t] = Collision(int(f), int(t), groups.get(int(t), "object"), bool(a))
    return sorted(seen.values(), key=lambda c: (c.frame, c.token))
