"""What a planner that is code may ask of a scene's map: lanes near a point, their graph, outlines,
centre lines, speed limits and traffic lights, and the route and goal nuPlan hands its planners.

The answers come from the map the nuPlan score reads (:class:`~pytest_driveeval.metrics.nuplan_score.ScoreMap`:
ScenarioNet's lanes, or an L5 semantic map's), so a planner sees the very lanes it is scored on, and the
route is the score's own: :func:`~pytest_driveeval.metrics.nuplan_score.route.centre_route` of the logged
ego, simplified and grouped into roadblocks as the progress term walks them (nuPlan's route roadblocks are
built the same way from the expert's drive).  Lanes are the map's indices; ``lane_id`` gives the file's id.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from pytest_driveeval.metrics.nuplan_score.lanes import ScoreMap
from pytest_driveeval.metrics.nuplan_score.progress import route_pairs, simplified
from pytest_driveeval.metrics.nuplan_score.route import centre_route

__all__ = ["LightStates", "MapQuery", "Route", "logged_route"]


@dataclass(frozen=True)
class LightStates:
    """Traffic lights as the data gives them: per light, the lane it controls (a map index, -1 where the
    lane is not on the map) and its state per log frame (ScenarioNet's strings, e.g. ``LANE_STATE_STOP``)."""

    lanes: np.ndarray                   # (L,) int
    states: list[list[str]] = field(default_factory=list)  # (L, T)
    stop_points: np.ndarray | None = None  # (L, 2), NaN where not given

    def at(self, frame: int) -> dict[int, str]:
        """Lane index -> the state of its light at log frame ``frame`` (lights without a state then left out)."""
        out = {}
        for lane, states in zip(self.lanes.tolist(), self.states):
            if lane >= 0 and 0 <= frame < len(states) and states[frame]:
                out[lane] = states[frame]
        return out


class MapQuery:
    """Read-only questions about one scene's map, in the scene's world frame (metres, radians)."""

    def __init__(self, score_map: ScoreMap, lights: LightStates | None = None):
        self.map = score_map
        self._lights = lights
        self._index = {lane_id: n for n, lane_id in enumerate(score_map.lane_ids)}
        # each lane's bounding box, for the "near a point" prefilter
        self._boxes = np.array([[*p.min(axis=0), *p.max(axis=0)] for p in score_map.polygons]).reshape(-1, 4)

    @property
    def num_lanes(self) -> int:
        return self.map.num_lanes

    def lane_id(self, lane: int) -> str:
        return self.map.lane_ids[lane]

    def lane_index(self, lane_id: str) -> int:
        return self._index[lane_id]

    def lanes_at(self, point) -> list[int]:
        """The lanes whose surface holds the point."""
        return np.flatnonzero(self.map.lanes_at(np.asarray(point, dtype=np.float64).reshape(1, 2))[0]).tolist()

    def lanes_near(self, point, radius: float) -> list[int]:
        """The lanes whose surface comes within ``radius`` of the point, nearest first (0 for those holding it)."""
        p = np.asarray(point, dtype=np.float64).reshape(2)
        box = self._boxes
        gap = np.maximum(np.maximum(box[:, :2] - p, p - box[:, 2:]), 0.0)
        candidates = np.flatnonzero(np.hypot(gap[:, 0], gap[:, 1]) <= radius)
        if not len(candidates):
            return []
        points = np.repeat(p[None], len(candidates), axis=0)
        inside = self.map.lanes_at(p[None])[0][candidates]
        distance = self.map.distance_to_lanes(points, [[int(n)] for n in candidates], np.inf)
        distance = np.where(inside, 0.0, distance)
        keep = distance <= radius
        order = np.lexsort((candidates[keep], distance[keep]))
        return candidates[keep][order].tolist()

    def successors(self, lane: int) -> list[int]:
        return list(self.map.outgoing[lane])

    def predecessors(self, lane: int) -> list[int]:
        return list(self.map.incoming[lane])

    def neighbours(self, lane: int) -> list[int]:
        """The other lanes of its roadblock (nuPlan's parallel lanes a driver may change into)."""
        block = self.map.roadblock
        return [int(n) for n in np.flatnonzero(block == block[lane]) if n != lane]

    def roadblock(self, lane: int) -> int:
        return int(self.map.roadblock[lane])

    def is_connector(self, lane: int) -> bool:
        """A lane connector (through a junction) rather than a lane."""
        return bool(self.map.connector[lane])

    def polygon(self, lane: int) -> np.ndarray:
        """(N, 2) the lane's surface outline."""
        return self.map.polygons[lane]

    def centre_line(self, lane: int) -> np.ndarray:
        """(N, 2) the lane's baseline, in its direction of travel (the line the score measures progress on)."""
        return self.map.baselines[lane]

    def speed_limit(self, lane: int) -> float | None:
        """m/s, None where the map gives none (``no_limits_reason`` says why, where known)."""
        value = float(self.map.speed_limits[lane])
        return value if np.isfinite(value) and value > 0 else None

    @property
    def no_limits_reason(self) -> str | None:
        return self.map.no_limits_reason

    def lights(self, frame: int) -> dict[int, str]:
        """Lane -> its light's state at log frame ``frame``; empty where the data has no lights."""
        return {} if self._lights is None else self._lights.at(frame)

    def in_drivable_area(self, points) -> np.ndarray:
        """(P,) bool: on a lane's surface or on the map's drivable area."""
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        holding, held, _ = self.map.lanes_holding(pts)
        out = held.copy() if self.map.every_lane_drivable else np.zeros(len(pts), dtype=bool)
        rest = np.flatnonzero(~out)
        if len(rest):
            out[rest] = self.map.in_drivable(pts[rest])
        return out


@dataclass(frozen=True)
class Route:
    """nuPlan's route of a scenario, built from the logged ego's drive: ``lanes`` the lanes it drives, in order
    (the score's expert route, simplified), ``roadblocks`` their roadblocks at each change (nuPlan's
    ``route_roadblock_ids``), ``frames`` the log frame at which each lane is first driven and ``entries``
    (K, 2) where the logged ego was then (where a lane change happened, the point it changed at)."""

    lanes: tuple[int, ...]
    roadblocks: tuple[int, ...]
    frames: tuple[int, ...]
    entries: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))


def logged_route(score_map: ScoreMap, logged_xy: np.ndarray, logged_yaw: np.ndarray) -> Route:
    """The route of the logged ego's centres ``logged_xy`` (T, 2): as the progress term finds the expert's
    (route.centre_route, progress.simplified, progress.route_pairs)."""
    frames_route = centre_route(score_map, np.asarray(logged_xy, dtype=np.float64), np.asarray(logged_yaw))
    kept = simplified(frames_route)
    lanes, frames, j = [], [], 0
    for k, here in enumerate(frames_route):
        # simplified() keeps some of the very lists centre_route made: the first frame holding each is where
        # the drive enters that lane
        if j < len(kept) and here is kept[j]:
            lanes.append(int(here[0]))
            frames.append(k)
            j += 1
    blocks = tuple(b for b, _ in route_pairs(score_map, kept)) if kept else ()
    entries = np.asarray(logged_xy, dtype=np.float64)[frames].reshape(-1, 2)
    return Route(tuple(lanes), blocks, tuple(frames), entries)
