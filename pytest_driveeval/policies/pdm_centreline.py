"""The route's centre line as PDM-Closed follows it: the baselines of the route's lanes joined and resampled
at a fixed spacing, so that a station (metres along it) is an index and a scene's line is a row of one
padded table that every scene of a batch reads at once.

Each line is extended straight past both ends (the log's route ends where the log does; the ego may go
on a little), and carries its heading, its curvature (smoothed over a few metres, for the tracker's
feed-forward and the speed it allows through a bend) and its speed limit (the lane's, else ``default``).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pytest_driveeval.metrics.nuplan_score.lanes import project

SPACING = 0.5          # metres between the table's points
EXTENSION = 60.0       # metres added straight past the route's end (and a tenth of it before its start)
SMOOTHING = 9          # points (4 m) over which curvature is averaged
SMOOTHING_LINE = 13    # points (6 m) over which the joined line is averaged
CHANGE = 25.0          # metres over which a lane change of the route is eased
AHEAD = 60             # points (30 m) over which the sharpest bend ahead is kept


@dataclass
class Centrelines:
    """(S, N) padded table of the scenes' lines; ``length[s]`` the usable stations of row s."""

    xy: np.ndarray        # (S, N, 2)
    heading: np.ndarray   # (S, N)
    curvature: np.ndarray  # (S, N)
    limit: np.ndarray     # (S, N) m/s
    length: np.ndarray    # (S,) number of points of each row
    bend: np.ndarray      # (S, N) the largest |curvature| of the next AHEAD points (the bend a speed must allow)

    def at(self, rows: np.ndarray, s: np.ndarray) -> tuple[np.ndarray, ...]:
        """Point, heading, curvature and limit at stations ``s`` (rows broadcast against s's leading axis)."""
        n = self.length[rows].reshape(rows.shape + (1,) * (s.ndim - rows.ndim)) - 1
        f = np.clip(s / SPACING, 0.0, n - 1e-9)
        i = f.astype(np.int64)
        w = f - i
        r = rows.reshape(rows.shape + (1,) * (s.ndim - rows.ndim))
        p0, p1 = self.xy[r, i], self.xy[r, i + 1]
        xy = p0 + (p1 - p0) * w[..., None]
        return xy, self.heading[r, i], self.curvature[r, i], self.limit[r, i], self.bend[r, i]


def _line(score_map, route, default_limit: float) -> tuple[np.ndarray, np.ndarray]:
    """The route's lanes' baselines, each from where the logged ego entered it to where it entered the next
    (joined lanes overlap at their ends, and a lane change leaves one lane half-way): the line the log drove."""
    points, limits = [], []
    for k, lane in enumerate(route.lanes):
        base = score_map.baselines[lane]
        along = score_map.cumulative[lane]
        lo = float(project(route.entries[k][None], base, along)[0]) if k else 0.0
        hi = float(project(route.entries[k + 1][None], base, along)[0]) if k + 1 < len(route.lanes) else along[-1]
        inner = (along > lo) & (along < hi)
        part = np.concatenate([_point_at(base, along, lo)[None], base[inner], _point_at(base, along, hi)[None]])
        if k:
            part = _lane_change(score_map.baselines[route.lanes[k - 1]], score_map.cumulative[route.lanes[k - 1]],
                                route.entries[k], part)
        limit = float(score_map.speed_limits[lane])
        points.append(part)
        limits.append(np.full(len(part), limit if np.isfinite(limit) and limit > 0 else default_limit))
    xy, lim = np.concatenate(points), np.concatenate(limits)
    step = np.hypot(*np.diff(xy, axis=0).T)
    keep = np.concatenate([[True], step > 0.05])  # joined lanes repeat their shared point
    return xy[keep], lim[keep]


def _lane_change(previous: np.ndarray, along: np.ndarray, entry: np.ndarray, part: np.ndarray) -> np.ndarray:
    """``part`` (the next lane from where the log entered it) eased over :data:`CHANGE` metres from the lane
    before, where that lane goes on beside it (a lane change: the log moved across over some metres, not at
    once); unchanged where the lane before ends there (lanes joined end to start)."""
    cut = float(project(entry[None], previous, along)[0])
    if along[-1] - cut < 0.5 * CHANGE:
        return part
    gone = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(part, axis=0).T))])
    near = gone < CHANGE
    beside = np.array([_point_at(previous, along, float(a)) for a in project(part[near], previous, along)])
    w = gone[near] / CHANGE
    w = (w * w * (3 - 2 * w))[:, None]  # smoothstep: no kink where the easing starts or ends
    out = part.copy()
    out[near] = beside + (part[near] - beside) * w
    return out


def _point_at(line: np.ndarray, along: np.ndarray, s: float) -> np.ndarray:
    return np.array([np.interp(s, along, line[:, 0]), np.interp(s, along, line[:, 1])])


def straight(xy: np.ndarray, yaw: float, length: float) -> np.ndarray:
    return xy + np.arange(0.0, length, SPACING)[:, None] * np.array([np.cos(yaw), np.sin(yaw)])


def one_line(points: np.ndarray, limits: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``points`` (M, 2) resampled at :data:`SPACING` and extended at both ends; the limit of the nearest point."""
    if len(points) < 2:
        raise ValueError("a centre line needs two points")
    first = np.arctan2(*(points[1] - points[0])[::-1])
    last = np.arctan2(*(points[-1] - points[-2])[::-1])
    before = straight(points[0], first + np.pi, EXTENSION / 10)[:0:-1]
    after = straight(points[-1], last, EXTENSION)[1:]
    joined = np.concatenate([before, points, after])
    along = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(joined, axis=0).T))])
    stations = np.arange(max(2, int(along[-1] / SPACING) + 1)) * SPACING  # exactly SPACING apart
    xy = np.stack([np.interp(stations, along, joined[:, 0]), np.interp(stations, along, joined[:, 1])], axis=1)
    if len(xy) > SMOOTHING_LINE:
        # a lane change is a step across, and a cut lane a kink: a moving average makes both a bend to follow
        kernel = np.ones(SMOOTHING_LINE) / SMOOTHING_LINE
        half = SMOOTHING_LINE // 2
        padded = np.concatenate([np.repeat(xy[:1], half, 0), xy, np.repeat(xy[-1:], half, 0)])
        xy = np.stack([np.convolve(padded[:, i], kernel, mode="valid") for i in (0, 1)], axis=1)
    source = np.concatenate([np.full(len(before), limits[0]), limits, np.full(len(after), limits[-1])])
    at = np.searchsorted(along, stations).clip(0, len(source) - 1)
    return xy, source[at]


def centrelines(lines: list[tuple[np.ndarray, np.ndarray]]) -> Centrelines:
    """The padded table of per-scene (points, limits) from :func:`one_line`."""
    n = max(len(xy) for xy, _ in lines)
    s = len(lines)
    table = np.zeros((s, n, 2))
    limit = np.zeros((s, n))
    length = np.array([len(xy) for xy, _ in lines])
    for row, (xy, lim) in enumerate(lines):
        table[row, :len(xy)], table[row, len(xy):] = xy, xy[-1]
        limit[row, :len(xy)], limit[row, len(xy):] = lim, lim[-1]
    d = np.diff(table, axis=1)
    heading = np.arctan2(d[..., 1], d[..., 0])
    heading = np.concatenate([heading, heading[:, -1:]], axis=1)
    for row, m in enumerate(length):  # the padding keeps the last real heading
        heading[row, m - 1:] = heading[row, m - 2]
    turn = np.diff(np.unwrap(heading, axis=1), axis=1) / SPACING
    kernel = np.ones(SMOOTHING) / SMOOTHING
    curvature = np.stack([np.convolve(np.concatenate([row, row[-1:]]), kernel, mode="same") for row in turn])
    padded = np.concatenate([np.abs(curvature), np.repeat(np.abs(curvature[:, -1:]), AHEAD, axis=1)], axis=1)
    bend = np.lib.stride_tricks.sliding_window_view(padded, AHEAD, axis=1)[:, :n].max(axis=-1)
    return Centrelines(table, heading, curvature, limit, length, bend)


def route_line(score_map, route, default_limit: float) -> tuple[np.ndarray, np.ndarray] | None:
    """The route's (points, limits) for :func:`centrelines`; None where the route has no lane."""
    if score_map is None or route is None or not route.lanes:
        return None
    xy, lim = _line(score_map, route, default_limit)
    return one_line(xy, lim) if len(xy) >= 2 else None
