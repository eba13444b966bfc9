"""What a CommonRoad scenario holds, as plain numpy arrays: lanelets, obstacles, planning problems.

The reader is ``pytest_driveeval.io.commonroad.commonroad``; the goal test ``commonroad_geometry``.  Values the file
leaves out are ``nan`` (floats) or ``None`` (intervals, neighbours, speed limits).  Classes that hold
arrays compare by identity (``eq=False``): an array's ``==`` has no single truth value.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Union

import numpy as np

from ...core.errors import DataError

__all__ = ["CommonRoadError", "Rectangle", "Circle", "Polygon", "Shape", "Neighbour", "Lanelet", "State", "StateSet",
           "Trajectory", "Occupancy", "Obstacle", "Interval", "GoalState", "PlanningProblem", "ReadNote",
           "CommonRoadScenario"]


class CommonRoadError(DataError, ValueError):
    """A file that is not a CommonRoad scenario this reader can use, or an inconsistent element in one."""


@dataclass(frozen=True, eq=False)
class Rectangle:
    length: float
    width: float
    center: np.ndarray  # (2,); an obstacle's shape is relative to its state (usually 0, 0)
    orientation: float = 0.0


@dataclass(frozen=True, eq=False)
class Circle:
    radius: float
    center: np.ndarray  # (2,)


@dataclass(frozen=True, eq=False)
class Polygon:
    vertices: np.ndarray  # (K, 2), not closed (the first vertex is not repeated)


Shape = Union[Rectangle, Circle, Polygon]


@dataclass(frozen=True)
class Neighbour:
    id: int
    same_direction: bool


@dataclass(frozen=True, eq=False)
class Lanelet:
    id: int
    left: np.ndarray   # (N, 2) left bound, in driving direction
    right: np.ndarray  # (N, 2) right bound, same point count
    predecessors: tuple[int, ...] = ()
    successors: tuple[int, ...] = ()
    adjacent_left: Neighbour | None = None
    adjacent_right: Neighbour | None = None
    speed_limit: float | None = None  # m/s; 2018b <speedLimit>, 2020a a referenced speed-limit sign (274)
    traffic_signs: tuple[int, ...] = ()

    @property
    def center(self) -> np.ndarray:
        return 0.5 * (self.left + self.right)

    @property
    def polygon(self) -> np.ndarray:
        """(2N, 2) outline: the left bound, then the right bound backwards (not closed)."""
        return np.concatenate([self.left, self.right[::-1]])


@dataclass(frozen=True)
class Interval:
    start: float
    end: float

    def contains(self, value):
        return (self.start <= value) & (value <= self.end)

    @property
    def middle(self) -> float:
        return 0.5 * (self.start + self.end)


@dataclass(frozen=True, eq=False)
class StateSet:
    """What a set-valued state gives beyond the one value it is replayed at: the position as shapes
    (world frame; a lanelet named as position is its outline, a Polygon) and the fields given as
    intervals, by State field name.  Checks that must be conservative (collisions) use these."""

    position: tuple[Shape, ...] = ()
    intervals: tuple[tuple[str, Interval], ...] = ()

    def interval(self, name: str) -> Interval | None:
        return dict(self.intervals).get(name)


@dataclass(frozen=True)
class State:
    """One state; fields the file does not give are nan.  A set-valued state (a shape as position, an
    interval as a value) is its middle here (a shape's centre, an interval's middle) and keeps the
    sets in ``set``."""

    time_step: int
    x: float
    y: float
    orientation: float = float("nan")
    velocity: float = float("nan")
    acceleration: float = float("nan")
    yaw_rate: float = float("nan")
    slip_angle: float = float("nan")
    set: StateSet | None = None


@dataclass(frozen=True, eq=False)
class Trajectory:
    """An obstacle's states over consecutive time steps ``t`` (initial state first); absent values are nan."""

    t: np.ndarray  # (T,) int64, t[i] = t[0] + i
    x: np.ndarray
    y: np.ndarray
    orientation: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray
    sets: dict[int, StateSet] = field(default_factory=dict)  # time step -> the sets of a set-valued state

    def __len__(self) -> int:
        return len(self.t)

    def at(self, time_step: int) -> State:
        i = int(time_step) - int(self.t[0])
        if not 0 <= i < len(self.t):
            raise IndexError(f"time step {time_step} outside {int(self.t[0])}..{int(self.t[-1])}")
        return State(int(self.t[i]), float(self.x[i]), float(self.y[i]), float(self.orientation[i]),
                     float(self.velocity[i]), float(self.acceleration[i]), set=self.sets.get(int(self.t[i])))


@dataclass(frozen=True, eq=False)
class Occupancy:
    """The region an obstacle given by an occupancy set occupies at time steps ``start`` to ``end``
    (both included; one step when the file gives an exact time): the union of ``shapes``, world frame."""

    start: int
    end: int
    shapes: tuple[Shape, ...]


@dataclass(frozen=True, eq=False)
class Obstacle:
    id: int
    role: str  # "dynamic" or "static"
    type: str  # car, truck, pedestrian, parkedVehicle, ... as written
    shape: Shape
    initial: State
    trajectory: Trajectory  # a static obstacle's, and an occupancy-set obstacle's, holds its initial state
    occupancy: tuple[Occupancy, ...] = ()  # an obstacle given by <occupancySet>: where it is, step by step

    @property
    def set_based(self) -> bool:
        return bool(self.occupancy)


@dataclass(frozen=True, eq=False)
class GoalState:
    """One goal state: reached when every constraint given holds (``commonroad_geometry.goal_reached``).

    ``shapes`` and ``lanelets`` are the alternatives of the position (any one suffices);
    ``lanelet_polygons`` are the referenced lanelets' outlines, resolved when reading.
    """

    shapes: tuple[Shape, ...] = ()
    lanelets: tuple[int, ...] = ()
    lanelet_polygons: tuple[np.ndarray, ...] = field(default=(), repr=False)
    orientation: Interval | None = None
    velocity: Interval | None = None
    time: Interval | None = None

    @property
    def has_position(self) -> bool:
        return bool(self.shapes or self.lanelets)


@dataclass(frozen=True, eq=False)
class PlanningProblem:
    id: int
    initial: State
    goals: tuple[GoalState, ...]


@dataclass(frozen=True)
class ReadNote:
    """One line of what the reader did with a file: ``action`` is "read", "skipped" or "assumed"
    (a value the file leaves to the reader), ``what`` the elements (``<environmentObstacle>``),
    ``count`` how many, ``why`` the reason in words, ``line`` the first one's line."""

    action: str
    what: str
    count: int
    why: str
    line: int | None = None

    def render(self) -> str:
        at = f" (first at line {self.line})" if self.line else ""
        return f"{self.action} {self.count} {self.what}{at}: {self.why}"


@dataclass
class CommonRoadScenario:
    path: Path
    benchmark_id: str
    version: str  # "2018b" or "2020a"
    dt: float     # s per time step
    lanelets: dict[int, Lanelet]
    obstacles: dict[int, Obstacle]
    planning_problems: dict[int, PlanningProblem]
    #: what was read, skipped and assumed, and why (for a data check; see ReadNote)
    notes: list[ReadNote] = field(default_factory=list)

    def dynamic_obstacles(self) -> list[Obstacle]:
        return [o for o in self.obstacles.values() if o.role == "dynamic"]

    def static_obstacles(self) -> list[Obstacle]:
        return [o for o in self.obstacles.values() if o.role == "static"]
