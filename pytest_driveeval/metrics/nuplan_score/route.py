"""Which lanes the ego is on, frame by frame, as nuPlan's route extractor assigns them
(``nuplan/planning/metrics/utils/route_extractor.py``: ``get_route``, ``extract_corners_route`` and
``extract_common_or_connecting_route_objs``), step for step, since every map term reads the result.

A frame keeps the previous frame's lanes that still hold the point, else the lanes that the
previous single lane leads into, else it looks again: the one lane (not connector) holding the point,
or else every lane connector holding it, in the map's order.  A connector followed by other connectors
(or by nothing, inside an intersection) keeps the previous frame's connectors that are less than 5 m
away.  Last, going backwards, a frame's several connectors are cut down to those its successor frame
keeps, or to the incoming connectors of the lane it ends up in.  An empty list: off every lane.

nuPlan's maps never overlap two lanes (its lookup raises there); a map whose lanes do overlap should
mark them connectors (as the ScenarioNet maps are marked).  Where two plain lanes still hold a point,
the one whose baseline points most nearly along the heading is taken, rather than raising.
"""
from __future__ import annotations

import numpy as np

from pytest_driveeval.geometry.planar import wrap_angle

from . import kernels
from .lanes import ScoreMap

_ZERO = np.zeros(1, dtype=np.int64)

#: metres: nuPlan keeps the previous frame's connectors that are nearer than this (get_route)
NEAR_CONNECTOR = 5.0


def lanes_lists(holding: np.ndarray, touched: np.ndarray | None = None) -> list[tuple[int, ...]]:
    """Per point (row of ``holding``, (P, N) bool), the lanes holding it, ascending.  ``touched`` (N,): the
    lanes holding some point, where the caller has it (the others' columns are not read: a map's lanes are
    many, a scene's few).  Equal rows share one tuple: a scene's points repeat a few sets of lanes, and
    few objects kept means few garbage collections while the score runs."""
    columns = np.flatnonzero(holding.any(axis=0) if touched is None else touched)
    if not len(columns):
        return [()] * len(holding)
    if len(columns) <= 62:
        # each row's lanes as the bits of one integer: one np.unique, and one tuple per distinct set
        codes = holding[:, columns].astype(np.int64) @ (np.int64(1) << np.arange(len(columns), dtype=np.int64))
        distinct, inverse = np.unique(codes, return_inverse=True)
        bits = ((distinct[:, None] >> np.arange(len(columns), dtype=np.int64)) & 1).astype(bool)
        made = [tuple(columns[row].tolist()) for row in bits]
        return list(map(made.__getitem__, inverse.tolist()))
    rows, cols = np.nonzero(holding[:, columns])
    here: list[tuple[int, ...]] = [()] * len(holding)
    starts = np.searchsorted(rows, np.arange(len(holding) + 1)).tolist()
    flat = columns[cols].tolist()
    shared: dict = {}
    for r in np.unique(rows).tolist():
        lanes = tuple(flat[starts[r]:starts[r + 1]])
        here[r] = shared.setdefault(lanes, lanes)
    return here


def _aligned(score_map: ScoreMap, lanes: list[int], point: np.ndarray, heading: float) -> int:
    directions = score_map.directions(np.repeat(point[None], len(lanes), axis=0), lanes)
    off = [abs(float(wrap_angle(d - heading))) for d in directions]
    return lanes[int(np.argmin(off))]


def _look_up(score_map: ScoreMap, lanes: list[int], point: np.ndarray, heading: float | None) -> list[int]:
    """nuPlan's ``get_current_route_objects``: the one lane holding the point, else every connector."""
    plain = [n for n in lanes if not score_map.connector[n]]
    if len(plain) == 1:
        return plain
    if plain:  # nuPlan raises here (its lanes never overlap): the lane along the heading, else the first
        return plain[:1] if heading is None else [_aligned(score_map, plain, point, heading)]
    return list(lanes)


def _with_candidates(score_map: ScoreMap, lanes: list[int], candidates: list[int]) -> list[int]:
    """nuPlan's ``get_route_obj_with_candidates``: the candidates holding the point, else (one candidate)
    those it leads into that hold it.  ``lanes``: the lanes holding the point."""
    if len(candidates) == 1:  # the steady case, a frame on the lane of the one before: nothing made
        if candidates[0] in lanes:
            return candidates
    elif all(n in lanes for n in candidates):
        return candidates
    kept = [n for n in candidates if n in lanes]
    if not kept and len(candidates) == 1:
        kept = [n for n in score_map.outgoing[candidates[0]] if n in lanes]
    return kept


def centre_route(score_map: ScoreMap, points: np.ndarray, headings: np.ndarray | None = None,
                 holding: np.ndarray | None = None, here: list[list[int]] | None = None) -> list[list[int]]:
    """Per frame, the lanes assigned to the point (first: the one the terms use), as nuPlan's ``get_route``.
    ``holding``: ``score_map.lanes_at(points)``, or ``here``: its :func:`lanes_lists`, when the caller has it
    (``holding`` lets the compiled loop run)."""
    near = _Nearness(score_map, np.ascontiguousarray(points, dtype=np.float64))

    def step(k: int, lanes, current: list[int]) -> list[int]:
        return _step(score_map, near, points, headings, k, lanes, current)

    if holding is not None and kernels.wanted():
        from .route_kernel import compiled_route

        route, first, counts = compiled_route(score_map, holding, step)
        # only a frame with several lanes can be cut, and only its first lane can change
        several = np.flatnonzero(counts[:-1] > 1)[::-1].tolist()
        out = Route(remove_extra_connectors(score_map, route, several))
        out.first = first
        for k in several:
            first[k] = out[k][0] if out[k] else -1
        return out
    if here is None:
        here = lanes_lists(score_map.lanes_at(points) if holding is None else holding)
    route: list[list[int]] = []
    current: list[int] = []
    for k, lanes in enumerate(here):
        # the steady case, one lane still holding the point, without a call (most frames of most runs)
        if len(current) != 1 or current[0] not in lanes:
            current = step(k, lanes, current)
        route.append(current)
    return remove_extra_connectors(score_map, route)


def _step(score_map: ScoreMap, near: "_Nearness", points: np.ndarray, headings: np.ndarray | None, k: int, lanes,
          current: list[int]) -> list[int]:
    """Frame k's lanes, from the lanes holding its point and ``current``, those of the frame before."""
    previous = current
    if current:
        current = _with_candidates(score_map, lanes, current)
    if not current:
        current = _look_up(score_map, lanes, points[k], None if headings is None else headings[k])
        connector = score_map.connector
        if k > 1 and previous and connector[previous[0]] and (
                (current and connector[current[0]]) or (not current and near.in_intersection(k))):
            kept = [n for n in previous if near.distance(k, n) < NEAR_CONNECTOR]
            if kept:
                current = kept
    return current


class _Nearness:
    """The distance of a run's point to a lane's polygon, each pair measured once, and whether each point is
    in an intersection, for all points at once when first asked (most runs never ask)."""

    def __init__(self, score_map: ScoreMap, points: np.ndarray):
        self.map, self.points = score_map, points
        self._distances: dict = {}
        self._intersections = None
        self._out, self._lane = np.full(1, np.inf), np.zeros(1, dtype=np.int64)  # the kernel's, reused

    def distance(self, k: int, lane: int) -> float:
        """Of point k to lane ``lane``'s polygon, which does not hold it (a lane that held the point would
        have been kept): the distance to its outline."""
        key = (k, lane)
        if key not in self._distances:
            if kernels.wanted():  # the kernel of distance_to_lanes, for one pair, without its set-up
                self._out[0], self._lane[0] = np.inf, lane
                lane_set = self.map.lane_set
                kernels.kernels().outline_distances(self.points[k:k + 1], lane_set.vertices, lane_set.vertex_starts,
                                                    _ZERO, self._lane, self._out)
                self._distances[key] = float(self._out[0])
            else:
                self._distances[key] = float(self.map.distance_to_lanes(self.points[k:k + 1], [[lane]], np.inf)[0])
        return self._distances[key]

    def in_intersection(self, k: int) -> bool:
        if self._intersections is None:
            self._intersections = self.map.in_intersection(self.points)
        return bool(self._intersections[k])


def remove_extra_connectors(score_map: ScoreMap, route: list[list[int]], several: list[int] | None = None
                            ) -> list[list[int]]:
    """nuPlan's ``remove_extra_lane_connectors``, backwards from the last frame: a frame with several
    lanes takes its successor's when those are fewer and all among its own, then (if the successor frame
    is on a lane) those of its own that lead into that lane, if any.  Both tests read the frame's lanes
    as they were, and the successor as already cut.  ``several``: the frames before the last with several
    lanes, descending, where the caller has them (the others are left as they are)."""
    out = list(route)
    for k in range(len(out) - 2, -1, -1) if several is None else several:
        own = route[k]
        if len(own) <= 1:
            continue
        after = out[k + 1]
        if len(own) > len(after) and all(n in own for n in after):
            out[k] = after
        if after and not score_map.connector[after[0]]:
            keep = [n for n in own if n in score_map.incoming[after[0]]]
            if keep:
                out[k] = keep
    return out


class Route(list):
    """Per frame, the lanes assigned (a list of lists), with ``first``: (T,) each frame's first lane, -1 off
    every lane, where the maker has it at hand."""

    first: np.ndarray | None = None


def first_lanes(route: list[list[int]]) -> np.ndarray:
    """(T,) each frame's first lane (the one the terms use), -1 where off every lane."""
    first = getattr(route, "first", None)
    if first is not None:
        return first
    return np.array([lanes[0] if lanes else -1 for lanes in route], dtype=np.int64)


def _corners_connected(score_map: ScoreMap, here: list) -> list[bool]:
    """Per frame, whether its corners' lanes are :func:`_common_or_connected`, the lanes (FL, RL, RR, FR:
    nuPlan's order) as nuPlan's ``extract_corners_route`` assigns them: a corner keeps the previous
    frame's lanes of any corner (or, one such lane, those it leads into) that hold it, else looks again;
    on the second frame, what a corner finds by looking again joins the candidates of the corners after
    it.  ``here`` (4T lists): the lanes holding each corner, frame by frame in the order FL, FR, RR, RL
    (the ego's corners)."""
    out = []
    candidates: tuple[int, ...] = ()
    known: dict = {}  # a frame's answer is a function of its candidates and its corners' lanes: a steady ego repeats it
    connected_of: dict = {}  # and the connectedness of the corners' lanes, which different candidates often give alike
    for k in range(len(here) // 4):
        front_left, front_right, rear_right, rear_left = here[4 * k:4 * k + 4]
        key = (k == 1, candidates, tuple(front_left), tuple(rear_left), tuple(rear_right), tuple(front_right))
        answer = known.get(key)
        if answer is None:
            corners, found = _corners_frame(score_map, key)
            connected = connected_of.get(corners)
            if connected is None:
                connected = connected_of[corners] = _common_or_connected(score_map, corners)
            answer = known[key] = (found, connected)
        candidates, connected = answer
        out.append(connected)
    return out


def _corners_frame(score_map: ScoreMap, key: tuple) -> tuple[tuple[tuple[int, ...], ...], tuple[int, ...]]:
    second, candidates, *lanes_of = key
    candidates = list(candidates)
    found_here: list[int] = []
    corners = []
    for lanes in lanes_of:  # FL, RL, RR, FR
        found = _with_candidates(score_map, lanes, candidates) if candidates else []
        if not found:
            found = _look_up(score_map, list(lanes), None, None)
            if second:
                candidates = candidates + [n for n in found if n not in candidates]
        found_here += [n for n in found if n not in found_here]
        corners.append(tuple(found))
    return tuple(corners), tuple(found_here)


def _common_or_connected(score_map: ScoreMap, corners: tuple[tuple[int, ...], ...]) -> bool:
    """Whether nuPlan's ``extract_common_or_connecting_route_objs`` finds a non-empty set: all four corners
    on lanes, and one lane common to all, or the rear corners on one lane or on lanes one leading into
    the other, each front corner on the lane of the opposite rear corner or on a lane leading out of it."""
    if any(not c for c in corners):
        return False
    front_left, rear_left, rear_right, front_right = (set(c) for c in corners)
    if front_left & rear_left & rear_right & front_right:
        return True
    outgoing, incoming = score_map.outgoing, score_map.incoming
    rear_right_ahead = rear_right | {m for n in rear_right for m in outgoing[n]}
    rear_left_ahead = rear_left | {m for n in rear_left for m in outgoing[n]}
    if not ((rear_left & rear_right_ahead) | (rear_right & rear_left_ahead)):
        return False
    front_left_behind = front_left | {m for n in front_left for m in incoming[n]}
    front_right_behind = front_right | {m for n in front_right for m in incoming[n]}
    return bool((front_left_behind & rear_right_ahead) & (front_right_behind & rear_left_ahead))


def corners_in_one_lane(score_map: ScoreMap, corners: np.ndarray, holding: np.ndarray | None = None,
                        here: list[list[int]] | None = None) -> np.ndarray:
    """(T,) bool: the frame is among nuPlan's ``timestamps_in_common_or_connected_route_objs`` (the ego's
    corners in one lane or two connected ones); False when the ego straddles lanes or is partly or
    wholly off them.  ``holding`` (4T, N): ``score_map.lanes_at`` of the corners, or ``here``: its
    :func:`lanes_lists`, when the caller has it."""
    if here is None:
        here = lanes_lists(score_map.lanes_at(corners.reshape(-1, 2)) if holding is None else holding)
    return np.array(_corners_connected(score_map, here), dtype=bool)


class InOneLane:
    """:func:`corners_in_one_lane`, computed when first read (``frames[k]`` or ``np.asarray``): only a
    lateral collision and a time to collision with an agent beside the ego ask, and most scenes have neither."""

    def __init__(self, score_map: ScoreMap, corners: np.ndarray, here: list[list[int]]):
        self._args: tuple | None = (score_map, corners, here)
        self._frames: np.ndarray | None = None

    def frames(self) -> np.ndarray:
        if self._frames is None:
            score_map, corners, here = self._args
            self._frames, self._args = corners_in_one_lane(score_map, corners, here=here), None
        return self._frames

    def __array__(self, dtype=None, copy=None):
        return self.frames() if dtype is None else self.frames().astype(dtype)

    def __getitem__(self, index):
        return self.frames()[index]

    def __len__(self) -> int:
        return len(self._frames) if self._frames is not None else len(self._args[2]) // 4
