"""Off the road in CommonRoad episodes, at and around the road's edge: a corner is off only where it lies
outside the union of lanelets (commonroad-io's lanelet polygons, shapely's union) by more than
ROAD_TOLERANCE, so that we are never stricter than commonroad-io, shapely or the drivability checker.

The issue's case: on a SUMO intersection (FRA_Anglet) a corner 0.020 m inside the edge was off the road
for us (the 0.1 m raster put it in a cell whose centre is outside) and on it for every reference."""
from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import REPO_ROOT

from pytest_driveeval.io.commonroad.commonroad_geometry import ROAD_TOLERANCE
from pytest_driveeval.metrics.episode_outcomes import cells_contain
from pytest_driveeval.sim.commonroad_road import corners_on_road
from pytest_driveeval.sim.commonroad_scene import commonroad_scene, read_cached
from pytest_driveeval.sim.episodes import reset

shapely = pytest.importorskip("shapely")
from shapely.geometry import Point, Polygon  # noqa: E402
from shapely.ops import unary_union  # noqa: E402

TUTORIAL = REPO_ROOT / "fixtures" / "commonroad" / "ZAM_Tutorial-1_2_T-1.xml"
#: signed distances outside the edge, m: inside, on it, within the tolerance, beyond it
OFFSETS = (-0.05, -0.02, -0.005, 0.0, 0.5 * ROAD_TOLERANCE, 2 * ROAD_TOLERANCE, 0.02, 0.05)


def union_of(scenario):
    return unary_union([Polygon(ll.polygon) for ll in scenario.lanelets.values()])


def edge_points(scenario, union, most: int = 150):
    """(P, 2) midpoints of lanelet bound segments on the road's outer edge, and their outward normals:
    segments at least 0.3 m long whose midpoint is on the union's boundary, inside 5 cm in and clear of it
    10 cm out."""
    points, normals = [], []
    for ll in scenario.lanelets.values():
        for bound, outward in ((ll.right, 1.0), (ll.left, -1.0)):
            seg = np.diff(bound, axis=0)
            length = np.linalg.norm(seg, axis=1)
            for a, d, n in zip(bound[:-1], seg, length):
                if n < 0.3:
                    continue
                t = d / n
                normal = outward * np.array([t[1], -t[0]])
                m = a + 0.5 * d
                if (union.distance(Point(*(m + 0.1 * normal))) > 0.09
                        and union.contains(Point(*(m - 0.05 * normal)))):
                    points.append(m)
                    normals.append(normal)
    points, normals = np.array(points).reshape(-1, 2), np.array(normals).reshape(-1, 2)
    pick = np.linspace(0, len(points) - 1, min(most, len(points))).astype(int) if len(points) else []
    return points[pick], normals[pick]


def files_with_problems(shared_data):
    out = []
    for path in sorted((shared_data / "commonroad").glob("*.xml")):
        s = read_cached(path)
        if s.planning_problems and s.lanelets:
            out.append((path, min(s.planning_problems)))
    return out


def check_edges(path, problem) -> tuple[int, int]:
    """Our corner verdict at OFFSETS from the edge against shapely's distance to the union; (points checked,
    points the raster alone would have put off the road while they are on it)."""
    scene = commonroad_scene(path, problem, max_steps=1)
    union = union_of(scene.scenario)
    points, normals = edge_points(scene.scenario, union)
    grid = scene.road.drivable
    stricter_raster = 0
    for d in OFFSETS:
        corners = (points + d * normals)[:, None, :]
        ours = corners_on_road(scene, corners)[:, 0]
        theirs = np.array([union.distance(Point(*p)) <= ROAD_TOLERANCE for p in corners[:, 0]])
        assert ours.tolist() == theirs.tolist(), (path.name, d, corners[ours != theirs, 0][:3])
        raster = cells_contain(corners, grid.mask, grid.origin, grid.resolution)[:, 0]
        stricter_raster += int(np.sum(~raster & theirs))
    return len(points), stricter_raster


def test_corners_at_and_around_the_edge_of_the_tutorial():
    checked, _ = check_edges(TUTORIAL, 100)
    assert checked > 20


def test_corners_at_and_around_the_edge_of_every_shared_file(shared_data):
    checked = stricter = 0
    for path, problem in files_with_problems(shared_data):
        n, s = check_edges(path, problem)
        checked, stricter = checked + n, stricter + s
    assert checked > 500
    # the raster alone was stricter than shapely at some of these points: the rule above is what fixed it
    assert stricter > 0


def box_at_edge(scene, d: float, length: float, width: float):
    """An ego pose whose right side runs along a straight stretch of the road's edge, d m outside it."""
    union = union_of(scene.scenario)
    points, normals = edge_points(scene.scenario, union, most=10 ** 6)
    for p, n in zip(points, normals):
        t = np.array([-n[1], n[0]])  # along the edge, the road on the left
        ahead, behind = p + 0.6 * length * t, p - 0.6 * length * t
        if all(union.distance(Point(*(q + 0.1 * n))) > 0.09 and union.contains(Point(*(q - 0.05 * n)))
               for q in (ahead, behind)):
            centre = p + (d - 0.5 * width) * n
            return centre, math.atan2(t[1], t[0])
    raise AssertionError("no straight stretch of edge")


@pytest.mark.parametrize("d, off", [(-0.02, False), (0.0, False), (0.5 * ROAD_TOLERANCE, False),
                                    (2 * ROAD_TOLERANCE, True), (0.02, True)])
def test_the_episode_is_off_the_road_only_beyond_the_edge(shared_data, d, off):
    # FRA_Anglet: the SUMO intersection of the issue
    path = shared_data / "commonroad" / "FRA_Anglet-1_1_T-1.xml"
    scene = commonroad_scene(path, 1, vehicle_length=2.0, vehicle_width=1.0)
    centre, yaw = box_at_edge(scene, d, 2.0, 1.0)
    episodes = reset(scene, np.zeros(1, np.int64), 12)
    _, _, left = episodes.judge(centre[None], np.array([yaw]), np.zeros(1), np.zeros(1, np.int64))
    assert left.tolist() == [off]
