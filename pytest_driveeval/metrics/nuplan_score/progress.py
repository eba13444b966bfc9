"""``ego_progress_along_expert_route`` as nuplan-devkit computes it (docs/nuplan_score.md §3.4;
``ego_progress_along_expert_route.py``, ``route_extractor.py``): the expert's route is the lanes its
centre is assigned frame by frame (route.centre_route), consecutive repeats dropped; each change of
roadblock along it adds a (roadblock, baseline of the first lane there) pair.  The ego and the expert
then each make progress along those baselines: inside the current roadblock, the change of the
position projected on its baseline; on entering a later roadblock of the route, the rest of the
current baseline, the way into the new one, and the stretches of the roadblocks skipped between;
outside every later roadblock, nothing.  The ratio of the two sums is the term.

A lane's roadblock is ``ScoreMap.roadblock`` (nuPlan's maps group parallel lanes in one; a map
without roadblocks gives each lane its own, as the oracle's cases do).
"""
from __future__ import annotations

import numpy as np

from .inputs import ScoreInputs
from .lanes import ScoreMap, project
from .term import Term

PROGRESS_THRESHOLD = 2.0


def simplified(route: list[list[int]]) -> list[list[int]]:
    """nuPlan's ``get_route_simplified``: from the first frame on a lane, each frame that is on a lane and
    shares none of its lanes with the last one kept."""
    out: list[list[int]] = []
    last = None
    for lanes in route:
        # a frame's lanes are often the very list of the frame before (centre_route keeps it): nothing to test
        if lanes is last:
            continue
        if lanes and (not out or not any(n in lanes for n in out[-1])):
            out.append(lanes)
        last = lanes
    return out


def route_pairs(score_map: ScoreMap, route: list[list[int]]) -> list[tuple[int, int]]:
    """nuPlan's ``get_route_baseline_roadblock_linkedlist``: (roadblock, lane) at each change of roadblock
    of the simplified route's first lanes."""
    pairs: list[tuple[int, int]] = []
    for lanes in route:
        block = int(score_map.roadblock[lanes[0]])
        if not pairs or block != pairs[-1][0]:
            pairs.append((block, lanes[0]))
    return pairs


class _Progress:
    """nuPlan's ``PerFrameProgressAlongRouteComputer`` over one run of poses."""

    def __init__(self, score_map: ScoreMap, pairs: list[tuple[int, int]], points: np.ndarray,
                 here: list[tuple[int, ...]], projected: dict | None = None):
        """``here``: per pose, the lanes holding it (route.lanes_lists' tuples).  ``projected``: the memo of
        :meth:`_project`, shared by the ego's and the expert's runs along the same route."""
        self.map, self.pairs = score_map, pairs
        self.frames = len(points)
        # a roadblock holds a pose where one of its lanes does: a run's poses repeat a few sets of lanes, so
        # each distinct set is looked at once and the (frames x roadblocks) table taken from those rows
        blocks = sorted({block for block, _ in pairs})
        column = {b: i for i, b in enumerate(blocks)}
        block_of = score_map.roadblock
        # the distinct sets numbered in order of first appearance, by loops that run in C (dict.fromkeys keeps
        # that order), not a Python loop over the frames
        index = {lanes: i for i, lanes in enumerate(dict.fromkeys(here))}
        rows = list(map(index.__getitem__, here))
        table = np.zeros((len(index), len(blocks)), dtype=bool)
        for lanes, row in index.items():
            for b in {int(block_of[n]) for n in lanes}:
                if b in column:
                    table[row, column[b]] = True
        inside = table[np.asarray(rows, dtype=np.int64)].T if rows else np.zeros((len(blocks), 0), dtype=bool)
        self.inside = {b: inside[column[b]] for b in blocks}
        # per pair, its roadblock's frames; from pair j on, the frames some pair j.. holds (where the loop
        # below can move on)
        held = np.array([self.inside[b] for b, _ in pairs])
        self.ahead = np.logical_or.accumulate(held[::-1], axis=0)[::-1]
        # a baseline's positions are read only where its roadblock holds the pose (and at the first pose
        # for the first pair): only those are projected, each as before, point by point
        wanted: dict = {}
        for b, lane in pairs:
            wanted[lane] = wanted[lane] | self.inside[b] if lane in wanted else self.inside[b].copy()
        wanted[pairs[0][1]][0] = True
        lanes = list(wanted)
        chosen = [np.flatnonzero(wanted[lane]) for lane in lanes]
        flat = np.concatenate(chosen)
        values = score_map.along(points[flat], np.repeat(lanes, [len(c) for c in chosen]))
        self.along = {}
        at = 0
        for lane, frames in zip(lanes, chosen):
            column_values = np.zeros(len(points))
            column_values[frames] = values[at:at + len(frames)]
            at += len(frames)
            self.along[lane] = column_values
        self._projected = {} if projected is None else projected

    def _project(self, lane: int, source: int, end: int) -> float:
        """Where the first (``end`` 0) or last (-1) point of lane ``source``'s baseline projects on lane
        ``lane``'s (the same few pairs recur at every crossing: each computed once)."""
        key = (lane, source, end)
        if key not in self._projected:
            point = self.map.baselines[source][end]
            self._projected[key] = float(project(point[None], self.map.baselines[lane], self.map.cumulative[lane])[0])
        return self._projected[key]

    def __call__(self) -> np.ndarray:
        """Per frame, the progress made since the frame before (0 at the first)."""
        pairs, along, inside, ahead = self.pairs, self.along, self.inside, self.ahead
        frames = self.frames
        current = 0
        block, lane = pairs[0]
        previous = float(along[lane][0])
        progress = np.zeros(frames)
        k = 1
        while k < frames:
            held = inside[block]
            if held[k]:
                # a run of frames in the current roadblock: each the change of its position (as one by one)
                stop = k + 1 + int(np.argmin(held[k + 1:])) if k + 1 < frames and not held[k + 1:].all() else frames
                positions = along[lane][k:stop]
                progress[k] = positions[0] - previous
                progress[k + 1:stop] = positions[1:] - positions[:-1]
                previous = float(positions[-1])
                k = stop
                continue
            if current + 1 < len(pairs):
                # frames no later roadblock of the route holds make no progress: skipped to the next one
                movable = ahead[current + 1][k:]
                if not movable[0]:
                    nxt = np.flatnonzero(movable | held[k:])
                    k = k + int(nxt[0]) if len(nxt) else frames
                    continue
            else:
                nxt = np.flatnonzero(held[k:])
                k = k + int(nxt[0]) if len(nxt) else frames
                continue
            step, skipped_total, later, skipped = 0.0, 0.0, current + 1, None
            while later < len(pairs):
                if inside[pairs[later][0]][k]:
                    rest = float(self.map.cumulative[lane][-1]) - previous
                    last_of = lane
                    current = later
                    block, lane = pairs[later]
                    s = float(along[lane][k])
                    step = rest + (s - self._project(lane, last_of, -1)) + skipped_total
                    previous = s
                    break
                if later == len(pairs) - 1:
                    break
                last_of = pairs[current if skipped is None else skipped][1]
                skipped = later
                later += 1
                skipped_lane = pairs[skipped][1]
                skipped_total += (self._project(skipped_lane, pairs[later][1], 0)
                                  - self._project(skipped_lane, last_of, -1))
            progress[k] = step
            k += 1
        return progress


def expert_progress(inputs: ScoreInputs, expert_route: list[list[int]] | None = None,
                    ego_here: list[list[int]] | None = None, expert_here: list[list[int]] | None = None) -> Term:
    """The term, from the expert's route (route.centre_route of its centres) and the lanes holding the
    ego's and the expert's centres (route.lanes_lists), where the caller has them."""
    name = "ego_progress_along_expert_route"
    score_map = inputs.map
    if score_map is None:
        return _along_expert_path(inputs)
    from .route import centre_route, lanes_lists

    expert = inputs.expert[:, :2]
    if expert_here is None:
        expert_here = lanes_lists(score_map.lanes_at(expert))
    if expert_route is None:
        expert_route = centre_route(score_map, expert, inputs.expert[:, 2], here=expert_here)
    route = simplified(expert_route)
    if not route:
        return Term(name, 1.0, reason="the expert is never on a lane: 1, as nuPlan scores it",
                    detail={"expert_progress": 0.0})
    pairs = route_pairs(score_map, route)
    ego_xy = inputs.ego.center[:, :2]
    if ego_here is None:
        ego_here = lanes_lists(score_map.lanes_at(ego_xy))
    projected: dict = {}  # the baselines' ends on one another: the ego and the expert cross the same roadblocks
    ego_along = float(np.sum(_Progress(score_map, pairs, ego_xy, ego_here, projected)()))
    expert_along = float(np.sum(_Progress(score_map, pairs, expert, expert_here, projected)()))
    return _ratio_term(ego_along, expert_along, f" along {len(pairs)} roadblock(s) of the expert's route")


def _ratio_term(ego_along: float, expert_along: float, where: str) -> Term:
    name = "ego_progress_along_expert_route"
    if ego_along < -PROGRESS_THRESHOLD:
        ratio = 0.0
    else:
        ratio = min(1.0, max(ego_along, PROGRESS_THRESHOLD) / max(expert_along, PROGRESS_THRESHOLD))
    term = Term(name, ratio, detail={"ego_progress": ego_along, "expert_progress": expert_along})
    if ratio < 1.0:
        term.message = f"{ego_along:.1f} m against the expert's {expert_along:.1f} m{where}"
    return term


def _along_expert_path(inputs: ScoreInputs) -> Term:
    """Without a map (an L5 scene): progress along the expert's own path, the projections of the ego's
    first and last positions on it (the sum nuPlan takes along one baseline telescopes to that)."""
    from pytest_driveeval.geometry.planar import arc_lengths

    expert = inputs.expert[:, :2]
    keep = np.concatenate([[True], np.linalg.norm(np.diff(expert, axis=0), axis=1) > 1e-9])
    path = expert[keep]
    if len(path) < 2:
        return _ratio_term(0.0, 0.0, " along the expert's path")
    cumulative = arc_lengths(path)
    s = project(inputs.ego.center[[0, -1], :2], path, cumulative)
    return _ratio_term(float(s[-1] - s[0]), float(cumulative[-1]), " along the expert's path")
