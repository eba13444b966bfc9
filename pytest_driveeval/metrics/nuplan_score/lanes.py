"""The map as nuPlan's closed-loop score reads it: lanes (surface polygon, baseline, speed limit,
successors), the drivable area (extra drivable polygons, outlines taken even-odd, road edges) and
intersections, with the point queries the terms ask.

Lookups are vectorised over points: a bounding-box test of every point against every polygon, then the
exact crossing-number test only for the polygons some point's box test admitted; the compiled paths
(:mod:`.kernels`) find a point's candidate polygons through a grid of cells instead.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from pytest_driveeval.geometry.planar import arc_lengths
from pytest_driveeval.geometry.polygons import odd_crossings, outline_distance, polygon_edges, segment_projections

from . import kernels
from .road_edges import RoadEdges


def _bounds(polygons: list[np.ndarray]) -> np.ndarray:
    if not polygons:
        return np.zeros((0, 4))
    vertices = np.concatenate(polygons)
    starts = np.concatenate([[0], np.cumsum([len(p) for p in polygons[:-1]])]).astype(np.int64)
    return np.concatenate([np.minimum.reduceat(vertices, starts), np.maximum.reduceat(vertices, starts)], axis=1)


#: metres: the side of a :func:`_grid` cell, at least (a lane is a few metres wide, tens long)
GRID_CELL = 10.0
#: cells along the grid's longer side, at most
GRID_SIDE = 512


def _grid(bounds: np.ndarray) -> tuple:
    """Which polygons' bounds meet each cell of a square grid over them: (origin, cell side, cells along x,
    cells along y, cell_starts, polygons), cell (i, j) = i * ny + j listing ``polygons[cell_starts[c]:
    cell_starts[c + 1]]``.  A point's cell, found as the polygons' are, lists every polygon whose bounds
    hold the point (floor and the float operations before it keep the order of their arguments)."""
    if not len(bounds):
        return np.zeros(2), GRID_CELL, 0, 0, np.zeros(1, dtype=np.int64), np.zeros(0, dtype=np.int64)
    origin = bounds[:, :2].min(axis=0)
    size = max(GRID_CELL, float((bounds[:, 2:] - origin).max()) / GRID_SIDE)
    first = np.floor((bounds[:, :2] - origin) / size).astype(np.int64)
    last = np.floor((bounds[:, 2:] - origin) / size).astype(np.int64)
    nx, ny = int(last[:, 0].max()) + 1, int(last[:, 1].max()) + 1
    spans = (last - first + 1)
    count = spans[:, 0] * spans[:, 1]
    polygon = np.repeat(np.arange(len(bounds)), count)
    k = np.arange(len(polygon)) - np.repeat(np.cumsum(count) - count, count)  # each entry's place in its box
    cell = (first[polygon, 0] + k // spans[polygon, 1]) * ny + first[polygon, 1] + k % spans[polygon, 1]
    order = np.argsort(cell, kind="stable")
    starts = np.searchsorted(cell[order], np.arange(nx * ny + 1)).astype(np.int64)
    return origin, size, float(nx), float(ny), starts, polygon[order].astype(np.int64)


#: edges per horizontal band of a polygon, about (a lane's outline has a few dozen edges)
EDGES_PER_BAND = 4
#: bands of one polygon, at most
MOST_BANDS = 64
#: bands of one drivable-area outline, at most (one outline may hold thousands of edges)
OUTLINE_BANDS = 2048
#: metres: a stand-in lane whose centre line lies this far off the map's own drivable area leaves it
LEAVING = 1.0


def _bands(table: np.ndarray, starts: np.ndarray, bounds: np.ndarray, most: int = MOST_BANDS) -> tuple:
    """Each polygon's edges by horizontal band, for the compiled crossing test: polygon n's y range cut into
    ``count[n]`` bands of height ``height[n]``, band b listing ``edges[band_starts[first[n] + b]:
    band_starts[first[n] + b + 1]]``, every edge whose y range meets it.  An edge counts a crossing at y
    only if y lies in its y range, so a point need only test its band's edges; floor and the float
    operations before it are monotonic, so the point's band is one its crossing edges list.
    Returns (first, count, height, band_starts, edges)."""
    n = len(starts) - 1
    count = np.clip(np.diff(starts) // EDGES_PER_BAND, 1, most).astype(np.int64)
    first = np.concatenate([[0], np.cumsum(count)[:-1]]).astype(np.int64) if n else np.zeros(0, np.int64)
    height = (bounds[:, 3] - bounds[:, 1]) / count if n else np.zeros(0)
    owner = np.repeat(np.arange(n), np.diff(starts))
    low, high = np.minimum(table[:, 1], table[:, 2]), np.maximum(table[:, 1], table[:, 2])
    band_of = [_band(y, bounds[owner, 1], height[owner], count[owner]) for y in (low, high)]
    spans = band_of[1] - band_of[0] + 1
    edge = np.repeat(np.arange(len(table)), spans)
    band = np.repeat(band_of[0], spans) + np.arange(len(edge)) - np.repeat(np.cumsum(spans) - spans, spans)
    slot = first[owner[edge]] + band
    order = np.argsort(slot, kind="stable")
    band_starts = np.searchsorted(slot[order], np.arange(int(count.sum()) + 1)).astype(np.int64)
    return first, count, height, band_starts, edge[order].astype(np.int64)


def _band(y: np.ndarray, y0: np.ndarray, height: np.ndarray, count: np.ndarray) -> np.ndarray:
    """The band holding y (the kernel's expression; a polygon of no height has one band)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        band = np.where(height > 0, np.floor((y - y0) / np.where(height > 0, height, 1.0)), 0.0)
    return np.clip(band, 0, count - 1).astype(np.int64)


class PolygonSet:
    """Polygons as flat tables: the (xi, yi, yj, slope) columns of their non-horizontal edges
    (geometry.polygons.polygon_edges' table), polygon n's edges at ``edge_starts[n]:edge_starts[n + 1]``;
    their vertices, polygon n's at ``vertex_starts[n]:vertex_starts[n + 1]``; and their bounds.
    ``edges=False``: no edge table (a set only measured distances to, which read the vertices);
    ``most_bands``: bands per polygon at most (a drivable area's outline has thousands of edges)."""

    def __init__(self, polygons: list[np.ndarray], edges: bool = True, most_bands: int = MOST_BANDS):
        self.polygons = polygons
        self.most_bands = most_bands
        self.bounds = _bounds(polygons)
        lengths = np.array([len(p) for p in polygons], dtype=np.int64)
        self.vertex_starts = np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64)
        self.vertices = np.concatenate(polygons) if polygons else np.zeros((0, 2))
        self.grid = _grid(self.bounds)
        if edges:
            self.edge_starts, self.xi, self.yi, self.yj, self.slope = self._edge_table(lengths)

    def _edge_table(self, lengths: np.ndarray) -> tuple[np.ndarray, ...]:
        polygons = self.polygons
        table = polygon_edges(*polygons)[0] if polygons else np.zeros((0, 4))
        keep = table[:, 1] != table[:, 2]
        counts = np.bincount(np.repeat(np.arange(len(polygons)), lengths)[keep], minlength=len(polygons))
        table = table[keep]
        starts = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
        self.bands = _bands(table, starts, self.bounds, self.most_bands)
        return (starts, *(np.ascontiguousarray(table[:, i]) for i in range(4)))

    def __len__(self) -> int:
        return len(self.polygons)

    def edges(self, n: int) -> tuple[np.ndarray, ...]:
        s, e = self.edge_starts[n], self.edge_starts[n + 1]
        return self.xi[s:e], self.yi[s:e], self.yj[s:e], self.slope[s:e]


def _containing(points: np.ndarray, polygons: PolygonSet) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(P, N) bool: point p lies in polygon n (the crossing-number rule of geometry.polygons); with its
    rows' any (P,), some polygon holds the point, and its columns' any (N,), the polygon holds some point."""
    out = np.zeros((len(points), len(polygons)), dtype=bool)
    if not len(polygons) or not len(points):
        return out, np.zeros(len(points), dtype=bool), np.zeros(len(polygons), dtype=bool)
    if kernels.wanted():
        held, touched = np.zeros(len(points), dtype=bool), np.zeros(len(polygons), dtype=bool)
        kernels.kernels().containing_in_grid(np.ascontiguousarray(points, dtype=np.float64), polygons.xi, polygons.yi,
                                             polygons.yj, polygons.slope, *polygons.bands, polygons.bounds,
                                             *polygons.grid, out, held, touched)
        return out, held, touched
    bounds = polygons.bounds
    x, y = points[:, 0:1], points[:, 1:2]
    near = (x >= bounds[:, 0]) & (x <= bounds[:, 2]) & (y >= bounds[:, 1]) & (y <= bounds[:, 3])
    with np.errstate(over="ignore"):  # a nearly horizontal edge's slope: see geometry.polygons
        for n in np.flatnonzero(near.any(axis=0)):
            rows = np.flatnonzero(near[:, n])
            out[rows, n] = odd_crossings(points[rows, 0:1], points[rows, 1:2], *polygons.edges(n))
    return out, out.any(axis=1), out.any(axis=0)


def _nearest_outlines(points: np.ndarray, polygons: PolygonSet, pair_point: np.ndarray, pair_polygon: np.ndarray
                      ) -> np.ndarray:
    """(P,) per point, its least distance to the outlines of the polygons paired with it (inf: none)."""
    out = np.full(len(points), np.inf)
    if not len(pair_point):
        return out
    if kernels.wanted():
        kernels.kernels().outline_distances(np.ascontiguousarray(points, dtype=np.float64), polygons.vertices,
                                            polygons.vertex_starts, pair_point.astype(np.int64),
                                            pair_polygon.astype(np.int64), out)
        return out
    order = np.argsort(pair_polygon, kind="stable")
    pair_point, pair_polygon = pair_point[order], pair_polygon[order]
    cuts = np.flatnonzero(np.diff(pair_polygon)) + 1
    for rows, n in zip(np.split(pair_point, cuts), pair_polygon[np.concatenate([[0], cuts])]):
        out[rows] = np.minimum(out[rows], outline_distance(points[rows], polygons.polygons[n]))
    return out


def _segments(rings: list[np.ndarray]) -> list[np.ndarray]:
    """Each ring's segments as outlines of two points, for distances: a point near an outline of thousands
    of vertices measures only the few segments in the grid cells near it, not the whole ring."""
    if not rings:
        return []
    return list(np.concatenate([np.stack([ring[:-1], ring[1:]], axis=1) for ring in rings]))


def _distance_within(points: np.ndarray, surfaces: PolygonSet, within: float) -> np.ndarray:
    """(P,) distance to the nearest outline of ``surfaces``, inf beyond ``within`` (m)."""
    if not len(surfaces) or not len(points):
        return np.full(len(points), np.inf)
    if kernels.wanted():
        out = np.empty(len(points))
        kernels.kernels().nearest_outlines_within(np.ascontiguousarray(points, dtype=np.float64), surfaces.vertices,
                                                  surfaces.vertex_starts, surfaces.bounds, float(within),
                                                  *surfaces.grid, out)
        return np.where(out < within, out, np.inf)
    bounds, x, y = surfaces.bounds, points[:, 0:1], points[:, 1:2]
    near = ((x >= bounds[:, 0] - within) & (x <= bounds[:, 2] + within)
            & (y >= bounds[:, 1] - within) & (y <= bounds[:, 3] + within))
    out = _nearest_outlines(points, surfaces, *np.nonzero(near))
    return np.where(out < within, out, np.inf)


def project(points: np.ndarray, line: np.ndarray, cumulative: np.ndarray) -> np.ndarray:
    """(P,) arc length along ``line`` of each point's nearest point on it (shapely's ``project``)."""
    if kernels.wanted():
        out = np.empty(len(points))
        kernels.kernels().project(np.ascontiguousarray(points, dtype=np.float64), np.zeros(len(points), np.int64),
                                  np.ascontiguousarray(line, dtype=np.float64), np.array([0, len(line)], np.int64),
                                  np.ascontiguousarray(cumulative, dtype=np.float64), out)
        return out
    t, distance2, length2 = segment_projections(points, line[:-1], np.diff(line, axis=0))
    nearest = np.argmin(distance2, axis=1)  # the first of equally near segments, as shapely
    rows = np.arange(len(points))
    return cumulative[nearest] + t[rows, nearest] * np.sqrt(length2[nearest])


@dataclass
class ScoreMap:
    """Lanes and areas in the scene's world frame.  ``speed_limits``: m/s, NaN where the map has none.
    ``outgoing[i]``: indices of the lanes lane i leads into (empty where the map does not say)."""

    lane_ids: list[str]
    polygons: list[np.ndarray]
    baselines: list[np.ndarray]
    speed_limits: np.ndarray
    connector: np.ndarray
    outgoing: list[list[int]]
    drivable: list[np.ndarray] = field(default_factory=list)
    intersections: list[np.ndarray] = field(default_factory=list)
    #: why the map has no speed limits, where its source says (said in the term's reason)
    no_limits_reason: str | None = None
    #: closed rings of one drivable area taken even-odd, its outer outlines and its holes alike (a point
    #: inside an odd number of them is on it): ScenarioNet writes nuScenes', nuPlan's and Argoverse 2's
    #: drivable area as the outline of their union
    drivable_outlines: list[np.ndarray] = field(default_factory=list)
    #: lines with the road on their left (Waymo's road edges): a point off every surface is on the road
    #: when the nearest edge has it on its left
    road_edges: list[np.ndarray] = field(default_factory=list)
    #: (N,) which lanes' surfaces are part of the drivable area (None: all); a lane whose surface is a
    #: stand-in (its centre line widened) is left out where the map gives the area itself
    lane_drivable: np.ndarray | None = None
    #: what the drivable area is made of, where the map's maker says (the term's reason)
    drivable_reason: str | None = None
    #: the drivable area is partly a stand-in (lanes widened by an assumed width): a failure says so
    drivable_stand_in: bool = False
    #: (N,) each lane's roadblock (nuPlan's group of parallel lanes, which the progress term walks); None:
    #: each lane its own (a map without them; ScenarioNet's: io.scenarionet.scenarionet_lane_graph)
    roadblock: np.ndarray | None = None

    def __post_init__(self):
        self.polygons = [np.asarray(p, dtype=np.float64)[:, :2] for p in self.polygons]
        self.baselines = [np.asarray(b, dtype=np.float64)[:, :2] for b in self.baselines]
        self.drivable = [np.asarray(p, dtype=np.float64)[:, :2] for p in self.drivable]
        self.intersections = [np.asarray(p, dtype=np.float64)[:, :2] for p in self.intersections]
        self.speed_limits = np.asarray(self.speed_limits, dtype=np.float64)
        self.connector = np.asarray(self.connector, dtype=bool)
        self.roadblock = (np.arange(len(self.lane_ids)) if self.roadblock is None
                          else np.asarray(self.roadblock, dtype=np.int64))
        self.lane_set = PolygonSet(self.polygons)
        # A drivable polygon that is also a lane surface (ScenarioNet's maps list every lane among the drivable
        # area) is left out of the drivable queries: they ask of points off every lane, and a nearest outline
        # found twice is found once as well.  Half the polygons tested, the same answers.
        surfaces = {(p.shape, p.tobytes()) for p in self.polygons}
        #: the drivable polygons that are not lane surfaces (driveways, car parks)
        self.drivable_beyond_lanes = [p for p in self.drivable if (p.shape, p.tobytes()) not in surfaces]
        extra = self.drivable_beyond_lanes   # rebound below, never changed in place
        self.drivable_outlines = [np.asarray(p, dtype=np.float64)[:, :2] for p in self.drivable_outlines]
        self.outline_set = PolygonSet(self.drivable_outlines, most_bands=OUTLINE_BANDS)
        self.edges = RoadEdges(self.road_edges)
        if self.lane_drivable is not None:
            self.lane_drivable = np.asarray(self.lane_drivable, dtype=bool).reshape(len(self.polygons))
            self._count_lanes_leaving(extra)
            # Some lanes do not count: the drivable queries are asked of every point, not only those off every
            # lane, so the counted lanes' surfaces join the drivable polygons.
            extra = [p for p, counted in zip(self.polygons, self.lane_drivable) if counted] + extra
        self.drivable_set = PolygonSet(extra)
        self.intersection_set = PolygonSet(self.intersections)
        self.cumulative = [arc_lengths(b) for b in self.baselines]
        self.headings = [np.arctan2(np.diff(b[:, 1]), np.diff(b[:, 0])) for b in self.baselines]
        # Every table the queries read is made here, with the map (its loading), rather than on a first
        # query (inside the first scene's score): the lane surfaces and the drivable polygons for
        # distances to any of them (vertices only), the baselines as one flat table.
        counted = extra if self.lane_drivable is not None else self.polygons + extra
        self.surface_set = PolygonSet(counted + _segments(self.drivable_outlines), edges=False)
        self.baseline_table = self._baseline_table()
        self.heading_table = np.concatenate(self.headings) if self.headings else np.zeros(0)
        #: incoming[n]: the lanes leading into lane n, ascending
        self.incoming: list[list[int]] = [[] for _ in self.lane_ids]
        for m, ahead in enumerate(self.outgoing):
            for n in dict.fromkeys(ahead):
                self.incoming[n].append(m)
        counts = np.array([len(ahead) for ahead in self.outgoing], dtype=np.int64)
        self.outgoing_table = (np.concatenate([[0], np.cumsum(counts)]).astype(np.int64),
                               np.array([m for ahead in self.outgoing for m in ahead], dtype=np.int64))

    def _count_lanes_leaving(self, extra: list[np.ndarray]) -> None:
        """A lane left out (its surface a stand-in) whose centre line leaves the map's own area counts after all:
        the map leaves out where it goes (nuPlan's car parks, which ScenarioNet does not write; the ways into
        them in nuScenes), and nuPlan counts a corner on any lane.  Said in the reason."""
        left_out = np.flatnonzero(~self.lane_drivable)
        if not len(left_out):
            return
        self.drivable_set = PolygonSet(extra)
        points = np.concatenate([self.baselines[n] for n in left_out])
        owner = np.repeat(left_out, [len(self.baselines[n]) for n in left_out])
        off = np.flatnonzero(~self.in_drivable(points))
        near = PolygonSet(_segments(self.drivable_outlines) + extra, edges=False)
        leaving = np.unique(owner[off[~(_distance_within(points[off], near, LEAVING) < LEAVING)]])
        if len(leaving):
            self.lane_drivable[leaving] = True
            self.drivable_reason = (f"{self.drivable_reason or 'drivable area: the map'}; {len(leaving)} lane(s) "
                                    "leaving it (where the map gives no surface), as lane centre lines widened "
                                    "by half their width")

    @property
    def num_lanes(self) -> int:
        return len(self.lane_ids)

    @property
    def has_speed_limits(self) -> bool:
        return bool(np.any(np.isfinite(self.speed_limits) & (self.speed_limits > 0)))

    def lanes_at(self, points: np.ndarray) -> np.ndarray:
        """(P, N) bool: which lane surfaces hold each point."""
        return _containing(points, self.lane_set)[0]

    def lanes_holding(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`lanes_at`, with (P,) some lane holds the point and (N,) the lane holds some point."""
        return _containing(points, self.lane_set)

    @property
    def every_lane_drivable(self) -> bool:
        """Every lane's surface is part of the drivable area (a point on any lane is on it)."""
        return self.lane_drivable is None or bool(self.lane_drivable.all())

    def in_outlines(self, points: np.ndarray) -> np.ndarray:
        """(P,) bool: inside an odd number of the drivable area's outlines."""
        if not len(self.outline_set):
            return np.zeros(len(points), dtype=bool)
        return (np.count_nonzero(_containing(points, self.outline_set)[0], axis=1) & 1).astype(bool)

    def in_drivable(self, points: np.ndarray) -> np.ndarray:
        """(P,) bool: on the drivable area besides the lane surfaces that every_lane_drivable counts (asked of
        points off every lane, or of all when not every lane counts): inside an odd number of its outlines,
        in one of its polygons, or on the road side of the nearest road edge."""
        out = self.in_outlines(points)
        rest = np.flatnonzero(~out)
        if len(rest) and len(self.drivable_set):
            out[rest] = _containing(points[rest], self.drivable_set)[1]
            rest = rest[~out[rest]]
        if len(rest) and len(self.edges):
            out[rest] = self.edges.signed_distances(points[rest]) < 0
        return out

    def in_intersection(self, points: np.ndarray) -> np.ndarray:
        return _containing(points, self.intersection_set)[1]

    def distance_to_drivable(self, points: np.ndarray, within: float) -> np.ndarray:
        """(P,) distance to the nearest lane surface or drivable polygon or outline, inf beyond ``within`` (m);
        of a point off the road, to the nearest road edge as well."""
        out = _distance_within(points, self.surface_set, within)
        if len(self.edges) and len(points):
            edge = self.edges.signed_distances(points)
            out = np.minimum(out, np.where((edge >= 0) & (edge < within), edge, np.inf))
        return out

    def distance_to_lanes(self, points: np.ndarray, lanes: list[list[int]], within: float) -> np.ndarray:
        """(P,) distance from point p to the nearest of the lanes ``lanes[p]``, inf beyond ``within``."""
        pair_point = np.repeat(np.arange(len(points)), [len(chosen) for chosen in lanes])
        pair_polygon = np.array([n for chosen in lanes for n in chosen], dtype=np.int64)
        out = _nearest_outlines(points, self.lane_set, pair_point, pair_polygon)
        return np.where(out < within, out, np.inf)

    def _baseline_table(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        lengths = [len(b) for b in self.baselines]
        starts = np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64)
        vertices = np.concatenate(self.baselines) if self.baselines else np.zeros((0, 2))
        cumulative = np.concatenate(self.cumulative) if self.cumulative else np.zeros(0)
        return vertices, starts, cumulative

    def along(self, points: np.ndarray, lane_of: np.ndarray) -> np.ndarray:
        """(P,) :func:`project` of point p onto lane ``lane_of[p]``'s baseline."""
        lane_of = np.asarray(lane_of, dtype=np.int64)
        out = np.zeros(len(points))
        if not len(points):
            return out
        if kernels.wanted():
            kernels.kernels().project(np.ascontiguousarray(points, dtype=np.float64), lane_of, *self.baseline_table,
                                      out)
            return out
        for lane in np.unique(lane_of):
            rows = np.flatnonzero(lane_of == lane)
            out[rows] = project(points[rows], self.baselines[lane], self.cumulative[lane])
        return out

    def directions(self, points: np.ndarray, lane_of: np.ndarray) -> np.ndarray:
        """(P,) heading of lane ``lane_of[p]``'s baseline at point p's projection."""
        lane_of = np.asarray(lane_of, dtype=np.int64)
        out = np.zeros(len(points))
        if kernels.wanted() and len(points):
            kernels.kernels().directions(np.ascontiguousarray(points, dtype=np.float64), lane_of, *self.baseline_table,
                                         self.heading_table, out)
            return out
        s = self.along(points, lane_of)
        for lane in np.unique(lane_of):
            rows = np.flatnonzero(lane_of == lane)
            segment = np.clip(np.searchsorted(self.cumulative[lane], s[rows], side="right") - 1, 0,
                              len(self.headings[lane]) - 1)
            out[rows] = self.headings[lane][segment]
        return out
