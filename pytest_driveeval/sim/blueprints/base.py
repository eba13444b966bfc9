"""What every blueprint shares: validated parameters, the spawn of one episode, the blueprint itself.

Parameters are frozen dataclasses whose fields say how they are checked
(``metadata["check"]``); a bad value raises :class:`ParameterError` naming the
blueprint and the parameter, so the scenario layer can point at the YAML key.
"""
from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, fields
from numbers import Real
from typing import ClassVar

import numpy as np

from pytest_driveeval.sim.blueprints.road import Road

__all__ = ["Blueprint", "BlueprintParams", "Goal", "ParameterError", "Parameters", "Spawn", "count", "indices",
           "finish_spawn", "gap_floor", "nearest_first", "place_along", "positive", "scaled_gap", "span"]


class ParameterError(ValueError):
    """A parameter that does not exist or has a bad value.

    ``owner`` is what it belongs to (a blueprint's name, ``traffic``),
    ``parameter`` its name: what the scenario layer needs to locate the key.
    """

    def __init__(self, owner: str, parameter: str, message: str):
        self.owner = owner
        self.parameter = parameter
        super().__init__(f"{owner}: parameter {parameter!r}: {message}")


def positive(default: float, doc: str, *, minimum: float = 0.0, inclusive: bool = False):
    """A number above ``minimum`` (or at it, with ``inclusive``)."""
    return field(default=default, metadata={"check": "number", "min": minimum, "inclusive": inclusive, "doc": doc})


def span(default: tuple[float, float], doc: str, *, minimum: float = -math.inf):
    """A (low, high) pair, low <= high, both >= ``minimum``; YAML lists are accepted."""
    return field(default=default, metadata={"check": "span", "min": minimum, "doc": doc})


def count(default: int, doc: str, *, minimum: int = 1):
    return field(default=default, metadata={"check": "count", "min": minimum, "doc": doc})


def indices(default: tuple[int, ...], doc: str):
    """A non-empty list of lane indices."""
    return field(default=default, metadata={"check": "indices", "min": 0, "doc": doc})


def _whole(value, where: Callable[[str], ParameterError]) -> int:
    if isinstance(value, bool) or not isinstance(value, Real) or not math.isfinite(value) or value != int(value):
        raise where(f"must be a whole number, got {value!r}")
    return int(value)


def _number(value, where: Callable[[str], ParameterError]) -> float:
    if isinstance(value, bool) or not isinstance(value, Real) or not math.isfinite(value):
        raise where(f"must be a finite number, got {value!r}")
    return float(value)


@dataclass(frozen=True)
class Parameters:
    """Validated on construction from each field's ``metadata["check"]``;
    subclasses add checks across fields in :meth:`check`."""

    name: ClassVar[str] = "parameters"

    def __post_init__(self):
        for f in fields(self):
            check = f.metadata.get("check")
            if check is None:
                continue
            value = getattr(self, f.name)
            where = lambda message, name=f.name: ParameterError(self.name, name, message)
            lo = f.metadata["min"]
            if check == "number":
                value = _number(value, where)
                if value < lo or (value == lo and not f.metadata["inclusive"]):
                    raise where(f"must be {'>=' if f.metadata['inclusive'] else '>'} {lo}, got {value}")
            elif check == "count":
                value = _whole(value, where)
                if value < lo:
                    raise where(f"must be >= {lo}, got {value}")
            elif check == "indices":
                if isinstance(value, (str, bytes)) or not hasattr(value, "__len__") or len(value) == 0:
                    raise where(f"must be a non-empty list of lane indices, got {value!r}")
                value = tuple(_whole(v, where) for v in value)
                if min(value) < lo:
                    raise where(f"lane indices must be >= {lo}, got {value}")
            elif check == "span":
                if isinstance(value, (str, bytes)) or not hasattr(value, "__len__") or len(value) != 2:
                    raise where(f"must be a (low, high) pair, got {value!r}")
                value = (_number(value[0], where), _number(value[1], where))
                if value[0] > value[1]:
                    raise where(f"low {value[0]} is above high {value[1]}")
                if value[0] < lo:
                    raise where(f"must be >= {lo}, got {value}")
            object.__setattr__(self, f.name, value)
        self.check()

    def check(self) -> None:
        """Checks across parameters; raise :meth:`error` naming the one to change."""

    def error(self, parameter: str, message: str) -> ParameterError:
        return ParameterError(self.name, parameter, message)


@dataclass(frozen=True)
class BlueprintParams(Parameters):
    """Parameters every blueprint has.  Defaults follow BARK-ML where it has one
    (its blueprints' step time, its continuous action bounds)."""

    name: ClassVar[str] = "blueprint"
    EXTENT: ClassVar[tuple[str, ...]] = ("lane_width",)

    dt: float = positive(0.2, "step time, s (BARK-ML: 0.2)")
    max_steps: int = count(200, "steps before the episode ends unsolved (BARK-ML's GNN configs: MaxSteps 200)")
    lane_width: float = positive(3.5, "m")
    vehicle_length: float = positive(4.5, "every vehicle's box length, m")
    vehicle_width: float = positive(1.8, "every vehicle's box width, m")
    ego_wheelbase: float = positive(2.7, "ego's kinematic bicycle wheelbase, m (BARK's single-track model: 2.7)")
    ego_accel: tuple[float, float] = span((-5.0, 4.0), "ego acceleration bounds, m/s^2 (BARK-ML's action bounds)")
    ego_max_steer: float = positive(0.2, "ego steering angle bound, rad (BARK-ML's action bound)")
    ego_max_speed: float = positive(40.0, "ego speed cap, m/s")
    speed: tuple[float, float] = span((10.0, 15.0), "initial traffic speeds, m/s", minimum=0.0)
    desired_speed: tuple[float, float] = span((10.0, 15.0), "traffic's IDM desired speeds, m/s", minimum=0.1)
    gap: tuple[float, float] = span((15.0, 35.0), "spawn distance between consecutive vehicles (centre to centre), m",
                                    minimum=0.1)
    ego_speed: tuple[float, float] = span((10.0, 15.0), "ego's initial speed, m/s", minimum=0.0)
    goal_length: float = positive(40.0, "goal region's length along its lane, m")
    goal_lateral: float = positive(0.9, "largest lateral offset from the goal lane's centre, m")
    goal_heading_tol: float = positive(0.15, "largest heading error at the goal, rad")
    goal_speed: tuple[float, float] = span((5.0, 15.0), "speed bounds at the goal, m/s", minimum=0.0)

    def check(self):
        if self.ego_accel[0] > 0 or self.ego_accel[1] < 0:
            raise self.error("ego_accel", f"must include 0 (braking and accelerating), got {self.ego_accel}")


@dataclass(frozen=True, eq=False)
class Goal:
    """A goal region: an oriented rectangle with heading and speed bounds."""

    centre: np.ndarray  # (2,) m
    heading: float  # rad, the goal lane's direction
    length: float  # m, along the heading
    width: float  # m, across it
    heading_tol: float  # rad
    speed: tuple[float, float]  # m/s


@dataclass(frozen=True, eq=False)
class Spawn:
    """One episode's start: traffic on lanes (nearest to the ego first), the ego, its goal."""

    lane: np.ndarray  # (n,) int lane index per traffic vehicle
    s: np.ndarray  # (n,) arclength on that lane, m
    speed: np.ndarray  # (n,) m/s
    desired_speed: np.ndarray  # (n,) m/s, IDM's v0
    ego_lane: int
    ego_s: float
    ego_speed: float
    goal: Goal


@dataclass(frozen=True, eq=False)
class Blueprint:
    """A scenario family: fixed road, seeded spawns.  ``spawn(rng, agent_limit,
    gap_scale=1.0)`` draws one episode from its own generator only;
    ``gap_scale`` scales its traffic's spawn gaps (:func:`scaled_gap`) from the
    same draws."""

    name: str
    params: BlueprintParams
    road: Road
    spawn: Callable[..., Spawn]

    @property
    def dt(self) -> float:
        return self.params.dt

    @property
    def max_steps(self) -> int:
        return self.params.max_steps


#: bumper to bumper, m: how close scaled spawn gaps may bring two vehicles (centre to centre: a length more);
#: the traffic model's own standstill gap (TrafficModel.min_gap), so no spawn is closer than traffic would stand
SPAWN_CLEARANCE = 2.0


def gap_floor(params: "BlueprintParams") -> float:
    """The closest scaled spawn gaps bring two vehicles, centre to centre: denser traffic never spawns overlapping."""
    return params.vehicle_length + SPAWN_CLEARANCE


def scaled_gap(params: "BlueprintParams", scale: float) -> tuple[float, float]:
    """The blueprint's spawn gaps times ``scale``, each at least :func:`gap_floor`."""
    if scale == 1.0:
        return params.gap
    floor = gap_floor(params)
    return max(scale * params.gap[0], floor), max(scale * params.gap[1], floor)


def place_along(rng: np.random.Generator, lo: float, hi: float, gap: tuple[float, float], scale: float = 1.0,
                floor: float = 0.0) -> np.ndarray:
    """Positions from ``lo`` up to ``hi``, consecutive ones ``gap`` apart (uniform).

    ``scale`` (a perturbation of the traffic's density) multiplies every gap
    drawn, each kept at least ``floor``; the draws are the same whatever the
    scale, so a seed's other draws (speeds, goal) do not move with it, and
    denser traffic than drawn for repeats the drawn gaps to fill the span.
    """
    # Enough draws for the densest case, drawn at once so the count never depends on the values.
    n = int((hi - lo) / max(gap[0], 1e-6)) + 2
    first = rng.uniform(0.0, gap[1])
    steps = rng.uniform(gap[0], gap[1], n)
    if scale == 1.0:
        s = lo + first + np.concatenate([[0.0], np.cumsum(steps)])
        return s[s <= hi]
    steps = np.maximum(scale * steps, floor)
    repeats = int((hi - lo) / steps.sum()) + 1
    s = lo + scale * first + np.concatenate([[0.0], np.cumsum(np.tile(steps, repeats))])
    return s[s <= hi]


def nearest_first(road: Road, ego_lane: int, ego_s: float, lane: np.ndarray, s: np.ndarray,
                  keep: int) -> np.ndarray:
    """Indices of the ``keep`` vehicles nearest to the ego, nearest first (ties: lower lane, then s)."""
    ego_xy, _ = road.pose(np.array(ego_lane), np.array(ego_s), 0.0)
    xy, _ = road.pose(lane, s, np.zeros_like(s))
    dist = np.linalg.norm(xy - ego_xy, axis=-1)
    return np.lexsort((s, lane, dist))[:keep]


def finish_spawn(rng: np.random.Generator, params: "BlueprintParams", road: Road, lane: np.ndarray, s: np.ndarray,
                 ego_lane: int, ego_s: float, ego_speed: float, goal_lane: int, goal_s: float,
                 agent_limit: int) -> Spawn:
    """The part of a spawn every blueprint shares once its traffic is placed:
    the vehicles' speeds, the nearest ``agent_limit - 1`` of them, and a goal
    region centred on ``goal_lane`` at ``goal_s``.  Draws from ``rng`` in a
    fixed order, so a seed gives the same episode whichever blueprint calls it."""
    speed = rng.uniform(*params.speed, len(s))
    desired = rng.uniform(*params.desired_speed, len(s))
    keep = nearest_first(road, ego_lane, ego_s, lane, s, agent_limit - 1)
    centre, heading = road.pose(np.array(goal_lane), np.array(goal_s), 0.0)
    goal = Goal(centre, float(heading), params.goal_length, 2 * params.goal_lateral, params.goal_heading_tol,
                params.goal_speed)
    return Spawn(lane[keep], s[keep], speed[keep], desired[keep], ego_lane, ego_s, ego_speed, goal)
