"""A CommonRoad scenario and one of its planning problems as the policy benchmark's scene.

``commonroad_scene(path, problem_id, **params)`` reads the file
(:mod:`pytest_driveeval.io.commonroad.commonroad`) and builds what the episodes need,
once, so that a step only indexes arrays:

* the road: one :class:`~pytest_driveeval.sim.blueprints.road.Lane` per
  lanelet (its centre line, its median width; neighbours in the same
  direction are ``left`` / ``right``), and the drivable area rasterised from
  the lanelets' own outlines (not the lanes', whose single width would reach
  past a lanelet that narrows).  Off the road is a corner of the ego's box
  outside every lanelet, as in the blueprints; the raster decides away from
  its edge and the lanelets' outlines within a cell of it
  (sim.commonroad_road), so a corner is off the road only where it is off
  the union of lanelets by more than 1 mm.
* the obstacles, recorded: their box centre, heading, speed and presence at
  every step ``k`` of an episode (time step ``t0 + k``, ``t0`` the planning
  problem's initial time step).  **An obstacle is present from its first
  recorded time step to its last and absent before and after** (invalid in
  the observation, no collisions); a static obstacle is present throughout,
  an obstacle given by an occupancy set at its initial step and the steps
  its occupancies cover.
  A rectangle is its box; a circle, a polygon, a set-valued state and an
  occupancy set are boxes round their shapes, and a box hit counts only
  where the shapes are hit (sim.commonroad_occupancy).  A missing
  orientation is 0, a missing velocity 0.
* the ego's start, the planning problem's initial state (its position is the
  centre of the ego's box, as an obstacle's is of its shape), and the goal:
  reached by CommonRoad's rule (:func:`~pytest_driveeval.io.commonroad.commonroad_geometry.goal_reached`,
  including its time interval), judged on the ego's box centre.  For the
  observation the goal is one point and speed: the centre of the first goal
  position (a shape's centre, or the middle of a goal lanelet's centre line;
  the ego's start when no goal state has a position) and the middle of the
  velocity interval (else the initial speed).

The step time is the file's ``timeStepSize``; the episode's step limit is the
end of the goal's time interval (the latest over its goal states) unless
``max_steps`` is given, and :data:`DEFAULT_MAX_STEPS` when a goal has no time.  The obstacles'
arrays take :func:`scene_bytes` (the caller bounds them before they are allocated), the drivable
area's raster at most ``MAX_GRID_CELLS`` cells (a ParameterError on ``resolution`` beyond).

Each episode's start is the initial state moved by offsets drawn from its seed
(:func:`~pytest_driveeval.sim.commonroad_episodes.start_offsets`): **seed 0 is the recorded initial state itself**, seed
``s > 0`` draws lateral, longitudinal (m, in the ego's frame), heading (rad)
and speed (m/s) offsets uniformly from the ``start_*`` ranges, in that order,
from ``np.random.default_rng(s)``.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass, field, fields
from functools import lru_cache
from pathlib import Path
from typing import ClassVar

import numpy as np

from pytest_driveeval.core.errors import display_path
from pytest_driveeval.geometry.planar import arc_lengths
from pytest_driveeval.io.commonroad.commonroad import CommonRoadError, planning_problem, read_commonroad
from pytest_driveeval.io.commonroad.commonroad_geometry import shape_outline
from pytest_driveeval.io.commonroad.commonroad_types import CommonRoadScenario, Obstacle, PlanningProblem
from pytest_driveeval.sim.commonroad_occupancy import replay, shape_box
from pytest_driveeval.sim.commonroad_road import road_cells
from pytest_driveeval.sim.blueprints.base import BlueprintParams, ParameterError, positive, span
from pytest_driveeval.sim.blueprints.road import Lane, Road, RoadTooLarge

__all__ = ["CommonRoadParams", "CommonRoadScene", "DEFAULT_MAX_STEPS", "commonroad_scene", "read_cached",
           "scene_bytes", "step_limit"]

DEFAULT_MAX_STEPS = 200


@dataclass(frozen=True)
class CommonRoadParams(BlueprintParams):
    """The ego's vehicle and the seeded start offsets; the size defaults are CommonRoad's vehicle 2
    (BMW 320i: 4.508 m x 1.610 m, wheelbase 2.578 m), the action bounds the blueprints'."""

    name: ClassVar[str] = "commonroad"
    #: BlueprintParams fields that mean something here; the others (spawns, goals) are refused
    USED: ClassVar[tuple[str, ...]] = ("max_steps", "vehicle_length", "vehicle_width", "ego_wheelbase", "ego_accel",
                                       "ego_max_steer", "ego_max_speed")

    vehicle_length: float = positive(4.508, "the ego's box length, m (CommonRoad vehicle 2)")
    vehicle_width: float = positive(1.610, "the ego's box width, m (CommonRoad vehicle 2)")
    ego_wheelbase: float = positive(2.578, "m (CommonRoad vehicle 2: a + b)")
    start_lateral: tuple[float, float] = span((-0.3, 0.3), "seeded start offset to the ego's left, m")
    start_longitudinal: tuple[float, float] = span((-1.0, 1.0), "seeded start offset ahead, m")
    start_heading: tuple[float, float] = span((-0.01, 0.01), "seeded heading offset, rad")
    start_speed: tuple[float, float] = span((-0.5, 0.5), "seeded speed offset, m/s (the speed stays >= 0)")
    resolution: float = positive(0.1, "cell size of the drivable-area raster, m")


def check_params(params: dict) -> None:
    """Refuse Params that do not apply to a CommonRoad scene, and bad values (ParameterError)."""
    own = {f.name for f in fields(CommonRoadParams)} - {f.name for f in fields(BlueprintParams)}
    known = set(CommonRoadParams.USED) | own
    for key in params:
        if key == "dt":
            raise ParameterError("commonroad", key, "the step time is the scenario file's timeStepSize")
        if key not in known:
            raise ParameterError("commonroad", key, f"does not apply to a CommonRoad scene; known: "
                                                    f"{', '.join(sorted(known))}")
    CommonRoadParams(**params)


@dataclass(frozen=True, eq=False)
class CommonRoadScene:
    """What :func:`commonroad_scene` built; the arrays over steps ``k`` are (K + 1, N, ...) for the
    ``N`` obstacles and ``K = params.max_steps``."""

    name: str
    params: CommonRoadParams
    road: Road
    scenario: CommonRoadScenario
    problem: PlanningProblem
    t0: int
    lanelet_outlines: tuple[np.ndarray, ...]
    obstacle_ids: np.ndarray  # (N,)
    obstacle_size: np.ndarray  # (N, 2) length, width
    xy: np.ndarray  # (K + 1, N, 2) box centres
    yaw: np.ndarray  # (K + 1, N)
    speed: np.ndarray  # (K + 1, N)
    valid: np.ndarray  # (K + 1, N) present at that step
    goal_centre: np.ndarray  # (2,)
    goal_heading: float
    goal_speed: float
    goal_outlines: tuple[np.ndarray, ...]  # the goal positions' outlines, for pictures
    recorded_paths: tuple[np.ndarray, ...] = ()  # per obstacle, (T, 2) its box centres over its whole recording
    traffic: str = "replay"  # or "reactive" (sim.commonroad_reactive)
    #: obstacle column -> (index (K + 1,) into shapes, -1 where its box is exact; world-frame shapes per
    #: entry): what decides a box hit where the box only bounds the obstacle (sim.commonroad_occupancy)
    exact_shapes: dict = field(default_factory=dict)
    #: (like the drivable raster's mask) int8 off / on the road / within a cell of the raster's edge,
    #: where a corner is judged by the lanelets' outlines themselves (sim.commonroad_road)
    road_cells: np.ndarray | None = None

    @property
    def dt(self) -> float:
        return self.params.dt

    @property
    def max_steps(self) -> int:
        return self.params.max_steps

    def start_episodes(self, seeds: np.ndarray, agent_limit: int, traffic_model=None, perturbation=None):
        """The engine's ``reset`` for this scene (sim.commonroad_episodes)."""
        from pytest_driveeval.sim.commonroad_episodes import CommonRoadEpisodes

        return CommonRoadEpisodes(self, seeds, agent_limit, perturbation, traffic_model)


@lru_cache(maxsize=8)
def _read(path: str, stamp: tuple[int, int]) -> CommonRoadScenario:
    return read_commonroad(path)


def read_cached(path: str | os.PathLike) -> CommonRoadScenario:
    """The scenario of ``path``, read once per process while the file is unchanged (several items
    share one file: one per policy and planning problem)."""
    path = Path(path)
    st = path.stat()
    return _read(str(path), (st.st_mtime_ns, st.st_size))


def _lane(lanelet_id: int, left: np.ndarray, right: np.ndarray) -> Lane:
    centre = 0.5 * (left + right)
    keep = np.concatenate([[True], np.linalg.norm(np.diff(centre, axis=0), axis=1) > 1e-6])
    width = float(np.median(np.linalg.norm(left - right, axis=1)))
    centre = centre[keep]
    if len(centre) < 2:  # a degenerate lanelet: a stub along its bounds' direction keeps Lane valid
        centre = np.stack([centre[0], centre[0] + 1e-3 * np.array([1.0, 0.0])])
    return Lane(centre, max(width, 1e-3), str(lanelet_id))


def _quads(left: np.ndarray, right: np.ndarray) -> list[np.ndarray]:
    """A lanelet's outline as one quadrilateral per pair of bound points: the same area when its
    bounds do not cross, and rasterised far faster than one polygon of hundreds of edges."""
    return [np.stack([left[i], left[i + 1], right[i + 1], right[i]]) for i in range(len(left) - 1)]


def _road(scenario: CommonRoadScenario, resolution: float) -> Road:
    ids = list(scenario.lanelets)
    index = {ident: i for i, ident in enumerate(ids)}
    lanes, left, right, areas = [], [], [], []
    for ident in ids:
        ll = scenario.lanelets[ident]
        lanes.append(_lane(ident, ll.left, ll.right))
        left.append(index[ll.adjacent_left.id] if ll.adjacent_left and ll.adjacent_left.same_direction else -1)
        right.append(index[ll.adjacent_right.id] if ll.adjacent_right and ll.adjacent_right.same_direction else -1)
        areas += _quads(ll.left, ll.right)
    return Road(tuple(lanes), tuple(left), tuple(right), areas=tuple(areas), resolution=resolution,
                lanes_drivable=False)


def _centres(obstacle: Obstacle, i: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(xy (T, 2), yaw (T,)) of the obstacle's box at its trajectory's states ``i``."""
    traj = obstacle.trajectory
    heading = np.nan_to_num(traj.orientation[i], nan=0.0)
    _, offset, turn = shape_box(obstacle.shape)
    c, s = np.cos(heading), np.sin(heading)
    x = traj.x[i] + c * offset[0] - s * offset[1]
    y = traj.y[i] + s * offset[0] + c * offset[1]
    return np.stack([x, y], axis=-1), heading + turn


def _centre_line_middle(outline_left: np.ndarray, outline_right: np.ndarray) -> tuple[np.ndarray, float]:
    centre = 0.5 * (outline_left + outline_right)
    seg = np.diff(centre, axis=0)
    length = np.linalg.norm(seg, axis=1)
    cum = arc_lengths(centre)
    k = int(np.clip(np.searchsorted(cum, 0.5 * cum[-1]) - 1, 0, len(seg) - 1))
    t = (0.5 * cum[-1] - cum[k]) / max(length[k], 1e-12)
    return centre[k] + t * seg[k], float(math.atan2(seg[k, 1], seg[k, 0]))


def _goal(scenario: CommonRoadScenario, problem: PlanningProblem) -> tuple[np.ndarray, float, float, tuple]:
    init = problem.initial
    centre, heading = np.array([init.x, init.y]), init.orientation
    outlines: list[np.ndarray] = []
    placed = False
    for goal in problem.goals:
        outlines += [shape_outline(s, circle_vertices=24) for s in goal.shapes] + list(goal.lanelet_polygons)
        if placed or not goal.has_position:
            continue
        placed = True
        if goal.shapes:
            centre, heading = np.mean(shape_outline(goal.shapes[0], circle_vertices=24), axis=0), init.orientation
        else:
            ll = scenario.lanelets[goal.lanelets[0]]
            centre, heading = _centre_line_middle(ll.left, ll.right)
    first = problem.goals[0]
    if first.orientation is not None:
        heading = 0.5 * (first.orientation.start + first.orientation.end)
    speed = 0.5 * (first.velocity.start + first.velocity.end) if first.velocity is not None else init.velocity
    return centre, float(heading), float(speed), tuple(outlines)


def scene_bytes(max_steps: int, obstacles: int) -> float:
    """About the memory :func:`commonroad_scene` takes for ``max_steps`` steps of ``obstacles``
    obstacles: the time steps and each obstacle's box, heading, speed and presence at every step
    (33 bytes kept, as much again while they are stacked), plus one obstacle's temporaries."""
    return (max_steps + 1.0) * (128.0 + 72.0 * obstacles)


def step_limit(problem: PlanningProblem) -> int:
    """The steps of an episode of ``problem`` when no ``max_steps`` is given: to the end of its goal's
    time interval (the latest over its goal states), DEFAULT_MAX_STEPS when a goal has no time."""
    ends = [g.time.end for g in problem.goals if g.time is not None]
    if len(ends) < len(problem.goals):
        return DEFAULT_MAX_STEPS
    return max(int(math.floor(max(ends))) - problem.initial.time_step, 1)


def commonroad_scene(path: str | os.PathLike, problem_id: int | str, traffic: str = "replay",
                     **params) -> CommonRoadScene:
    """The scene of planning problem ``problem_id`` in the CommonRoad file ``path``, its obstacles
    replayed (``traffic="replay"``) or driving their recorded paths by IDM (``"reactive"``,
    sim.commonroad_reactive); ``params``: the
    fields of :class:`CommonRoadParams` (not ``dt``).  Raises CommonRoadError for a file or problem
    that does not make a scene, ParameterError for a bad parameter, OSError for an unreadable file."""
    check_params(params)
    if traffic not in ("replay", "reactive"):
        raise ValueError(f"traffic must be replay or reactive, got {traffic!r}")
    scenario = read_cached(path)
    problem = planning_problem(scenario, problem_id)
    init = problem.initial
    if not (math.isfinite(init.orientation) and math.isfinite(init.velocity)):
        raise CommonRoadError(f"{path}: planning problem {problem.id}: the initial state needs an orientation and "
                              f"a velocity (got {init.orientation}, {init.velocity})")
    if not scenario.lanelets:
        raise CommonRoadError(f"{display_path(Path(path))}: planning problem {problem.id}: the file has no <lanelet>, "
                              "so there is no road to drive on (every position would be off the road) and the "
                              "benchmark cannot drive it; name a scenario file with its lanelet network")
    max_steps = params.pop("max_steps", None) or step_limit(problem)
    p = CommonRoadParams(dt=scenario.dt, max_steps=max_steps, **params)
    try:  # first: its size check allocates nothing
        road = _road(scenario, p.resolution)
    except RoadTooLarge as exc:
        raise ParameterError(CommonRoadParams.name, "resolution", f"{display_path(Path(path))}'s lanelets: {exc}; give a coarser "
                                                                  "resolution") from None
    times = init.time_step + np.arange(p.max_steps + 1)
    obstacles = list(scenario.obstacles.values())
    replays = [replay(o, times) for o in obstacles]
    n = len(obstacles)
    xy = np.stack([r.xy for r in replays], axis=1) if n else np.zeros((len(times), 0, 2))
    yaw, speed, valid = (np.stack([getattr(r, k) for r in replays], axis=1) if n else np.zeros((len(times), 0))
                         for k in ("yaw", "speed", "valid"))
    sizes = np.array([r.size for r in replays]).reshape(n, 2)
    exact = {j: r.exact for j, r in enumerate(replays) if r.exact is not None}
    centre, heading, goal_speed, outlines = _goal(scenario, problem)
    name = f"{scenario.benchmark_id or Path(path).stem} problem {problem.id}"
    return CommonRoadScene(name, p, road, scenario, problem, init.time_step,
                           tuple(l.polygon for l in scenario.lanelets.values()),
                           np.array([o.id for o in obstacles], np.int64), sizes, xy, yaw, speed, valid.astype(bool),
                           centre, heading, goal_speed, outlines,
                           tuple(_centres(o, np.arange(len(o.trajectory)))[0] for o in obstacles), traffic,
                           exact, road_cells(road.drivable))
