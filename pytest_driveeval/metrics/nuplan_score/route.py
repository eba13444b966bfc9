"""Which lanes the ego is on, frame by frame, as nuPlan's route extractor assigns them
(``nuplan/planning/metrics/utils/route_extractor.py``).

A frame keeps the previous frame's lanes that still hold the point, else the lanes that the
previous single lane leads into, else it looks again: one lane (nuPlan's maps never overlap lanes;
ScenarioNet's may, so the one whose baseline points most nearly along the ego's heading), or else
every lane connector holding the point.  An empty list: off every lane.
"""
from __future__ import annotations

import numpy as np

from pytest_driveeval.geometry.planar import wrap_angle

from . import kernels
from .lanes import ScoreMap


def _aligned_first(score_map: ScoreMap, lanes: list[int], point: np.ndarray, heading: float) -> list[int]:
    if len(lanes) < 2:
        return lanes
    directions = score_map.directions(np.repeat(point[None], len(lanes), axis=0), lanes)
    off = [abs(float(wrap_angle(d - heading))) for d in directions]
    return [lanes[i] for i in np.argsort(off, kind="stable")]


def centre_route(score_map: ScoreMap, points: np.ndarray, headings: np.ndarray,
                 holding: np.ndarray | None = None) -> list[list[int]]:
    """Per frame, the lanes assigned to the point (first: the one the terms use).
    ``holding``: ``score_map.lanes_at(points)`` when the caller has it."""
    holding = score_map.lanes_at(points) if holding is None else holding
    if kernels.wanted():
        return _centre_route_compiled(score_map, points, headings, holding)
    rows, cols = np.nonzero(holding)
    here: list[list[int]] = [[] for _ in range(len(points))]
    for r, c in zip(rows.tolist(), cols.tolist()):
        here[r].append(c)
    outgoing = score_map.outgoing
    route: list[list[int]] = []
    previous: list[int] = []
    for k, lanes in enumerate(here):
        kept = [n for n in previous if n in lanes]
        if not kept and len(previous) == 1:
            kept = [n for n in outgoing[previous[0]] if n in lanes]
        if not kept and lanes:
            kept = _look_again(score_map, lanes, points[k], headings[k])
        route.append(kept)
        previous = kept
    return route


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


def _look_again(score_map: ScoreMap, lanes: list[int], point: np.ndarray, heading: float) -> list[int]:
    plain = [n for n in lanes if not score_map.connector[n]]
    if plain:
        return _aligned_first(score_map, plain, point, heading)[:1]
    return _aligned_first(score_map, lanes, point, heading)


def _centre_route_compiled(score_map: ScoreMap, points: np.ndarray, headings: np.ndarray, holding: np.ndarray
                           ) -> list[list[int]]:
    """:func:`centre_route`'s loop in a kernel (kernels' ``follow_lanes``), but for the frames that look
    again among several lanes, which :func:`_look_again` decides here as there."""
    t = len(points)
    out_starts, out_lanes = score_map.outgoing_table
    # a frame keeps lanes that hold its point, or the previous lane's successors: no more than either count
    widest = max(1, holding.shape[1], int(np.diff(out_starts).max()) if len(out_starts) > 1 else 1)
    starts = np.zeros(t + 1, dtype=np.int64)
    lanes = np.empty(t * widest, dtype=np.int64)
    follow = kernels.kernels().follow_lanes
    holding = np.ascontiguousarray(holding)
    k, m, previous = 0, 0, np.zeros(0, dtype=np.int64)
    while True:
        k, m = follow(holding, score_map.connector, out_starts, out_lanes, k, previous, starts, lanes, m)
        if k >= t:
            break
        kept = _look_again(score_map, np.flatnonzero(holding[k]).tolist(), points[k], headings[k])
        starts[k] = m
        lanes[m:m + len(kept)] = kept
        m += len(kept)
        starts[k + 1] = m
        previous = np.array(kept, dtype=np.int64)
        k += 1
    flat, bounds = lanes[:m].tolist(), starts.tolist()
    route = Route(flat[bounds[j]:bounds[j + 1]] for j in range(t))
    route.first = np.where(starts[1:] > starts[:-1], lanes[np.minimum(starts[:-1], max(m - 1, 0))], -1) if m else \
        np.full(t, -1, dtype=np.int64)
    return route


def corners_in_one_lane(score_map: ScoreMap, corners: np.ndarray, holding: np.ndarray | None = None,
                        lanes: np.ndarray | None = None) -> np.ndarray:
    """(T,) bool: all four corners (FL, FR, RR, RL) on one lane, or the rear ones on a lane that leads
    into the front ones' lane (nuPlan's "common or connected" route objects); False when the ego
    straddles lanes or is partly or wholly off them.  ``lanes``: ascending, lanes among which are all
    those holding a corner (the others are left out of the comparisons), when the caller knows them."""
    t = len(corners)
    holding = score_map.lanes_at(corners.reshape(-1, 2)) if holding is None else holding
    if lanes is None:
        lanes = np.flatnonzero(holding.any(axis=0))
    holding = holding[:, lanes].reshape(t, 4, -1)
    front = holding[:, 0] & holding[:, 1]
    rear = holding[:, 2] & holding[:, 3]
    out = (front & rear).any(axis=1)
    straddling = np.flatnonzero(~out & front.any(axis=1) & rear.any(axis=1))
    if len(straddling):
        # over the map's links n -> m between those lanes at once: a rear corners' lane n leading into a
        # front corners' lane m
        starts, ahead = score_map.outgoing_table
        behind = np.repeat(np.arange(len(starts) - 1), np.diff(starts))
        local = np.full(len(starts) - 1, -1)
        local[lanes] = np.arange(len(lanes))
        link = (local[behind] >= 0) & (local[ahead] >= 0)
        out[straddling] = (rear[straddling][:, local[behind[link]]] & front[straddling][:, local[ahead[link]]]).any(axis=1)
    return out
