"""obstacle_segmentation geometry: the vectorised kernel agrees with perception_eval's rule."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from pytest_driveeval.io.lanelet2 import Lanelet2Error, load_lanelet_map
from pytest_driveeval.metrics.pointcloud import (Area, BoxSet, box_corners_3d, box_scale, crop_reference,
                                                 evaluate_cloud, points_in_polygon, polygon_self_intersects,
                                                 polygon_signed_area)
from pytest_driveeval.usecases.obstacle_segmentation_config import polygon_problem

DLR_AREA = np.array([[10.0, 1.5], [10.0, -1.5], [0.0, -1.5], [0.0, 1.5]])


def scene(seed: int, n: int = 20000, boxes: int = 12):
    rng = np.random.default_rng(seed)
    r = rng.exponential(12, n) + 0.5
    th = rng.uniform(-np.pi, np.pi, n)
    pts = np.stack([r * np.cos(th), r * np.sin(th), rng.uniform(-0.5, 2.5, n)], axis=1)
    centers = np.c_[rng.uniform(-25, 25, boxes), rng.uniform(-25, 25, boxes), rng.uniform(0.4, 1.0, boxes)]
    centers[0] = [5.0, 0.0, 0.8]  # one box overlapping the area, one overlapping another box
    centers[1] = [6.0, 0.5, 0.8]
    sizes = np.c_[rng.uniform(1.5, 2.5, boxes), rng.uniform(3, 6, boxes), rng.uniform(1.4, 2, boxes)]
    return pts, BoxSet.from_ground_truth(centers, sizes, rng.uniform(-np.pi, np.pi, boxes), 1.0, 1.5)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_counts_nearest_and_area_match_the_reference(seed):
    pts, boxes = scene(seed)
    area = Area(DLR_AREA, 0.0, 1.5)
    got = evaluate_cloud(pts, boxes, area)
    for b, corners in enumerate(box_corners_3d(boxes)):
        inside = crop_reference(pts, corners)
        assert got.counts[b] == len(inside)
        if len(inside):
            np.testing.assert_allclose(got.nearest[b], inside[np.argmin(np.linalg.norm(inside, axis=1))])
        else:
            assert np.isnan(got.nearest[b]).all()
    rest = crop_reference(pts, [(x, y, 0.0) for x, y in DLR_AREA] + [(x, y, 1.5) for x, y in DLR_AREA])
    for corners in box_corners_3d(boxes):
        rest = crop_reference(rest, corners, inside=False)
    assert sorted(map(tuple, got.area_points)) == sorted(map(tuple, rest))


def test_structured_float32_cloud_and_lanelet_clip():
    pts, boxes = scene(3)
    cloud = np.zeros(len(pts), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "u1")])
    for i, k in enumerate("xyz"):
        cloud[k] = pts[:, i]
    f32 = np.stack([cloud["x"], cloud["y"], cloud["z"]], 1).astype(np.float64)
    half_lane = Area(DLR_AREA, 0.0, 1.5, clips=[np.array([[0, 0], [20, 0], [20, 5], [0, 5]], float)])
    got = evaluate_cloud(cloud, BoxSet(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0)), half_lane)
    want = f32[(f32[:, 0] > 0) & (f32[:, 0] < 10) & (f32[:, 1] > 0) & (f32[:, 1] < 1.5)
               & (f32[:, 2] >= 0) & (f32[:, 2] <= 1.5)]
    assert len(got.area_points) == len(want)
    assert evaluate_cloud(cloud, boxes, Area(DLR_AREA, 0.0, 1.5, clips=[])).area_points.shape == (0, 3)


def test_box_scale_is_linear_in_distance_and_xy_only():
    assert box_scale(0.0, 1.0, 2.0) == 1.0 and box_scale(50.0, 1.0, 2.0) == 1.5
    boxes = BoxSet.from_ground_truth([[50.0, 0.0, 0.0]], [[2.0, 4.0, 1.0]], [0.0], 1.0, 2.0)
    np.testing.assert_allclose(boxes.half[0], [3.0, 1.5, 0.5])  # length, width scaled; height not


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.floats(-20, 20), st.floats(-20, 20)), min_size=3, max_size=8), st.integers(0, 99))
def test_points_in_polygon_matches_reference(poly, seed):
    poly = np.array(poly)
    pts = np.random.default_rng(seed).uniform(-25, 25, (500, 3))
    area = [(x, y, -100.0) for x, y in poly] + [(x, y, 100.0) for x, y in poly]
    ref = crop_reference(pts, area)
    got = pts[points_in_polygon(pts[:, 0], pts[:, 1], poly)]
    assert sorted(map(tuple, got)) == sorted(map(tuple, ref))


def test_polygon_checks_use_the_signed_area():
    assert polygon_signed_area(DLR_AREA) < 0 and polygon_problem(DLR_AREA) is None
    assert "counter-clockwise" in polygon_problem(DLR_AREA[::-1])
    # a clockwise slanted lane: driving_log_replayer's sum((x2 - x1) * 2 * y2) rejects it, the signed area not
    slanted = np.array([[0.0, 0.0], [10.0, -10.0], [10.0, -11.0], [0.0, -1.0]])
    dlr = sum((b[0] - a[0]) * (b[1] + b[1]) for a, b in zip(slanted, np.roll(slanted, -1, axis=0)))
    assert polygon_signed_area(slanted) < 0 and polygon_problem(slanted) is None and dlr <= 0
    bowtie = np.array([[0.0, 0.0], [10.0, 2.0], [10.0, 0.0], [0.0, 2.0]])
    assert polygon_self_intersects(bowtie) and "intersects itself" in polygon_problem(bowtie)
    assert "at least 3" in polygon_problem(DLR_AREA[:2])


def test_lanelet_map_outline_and_errors(tmp_path):
    osm = tmp_path / "lanelet2_map.osm"
    nodes = "".join(f'<node id="{i}" lat="0" lon="0"><tag k="local_x" v="{x}"/><tag k="local_y" v="{y}"/></node>'
                    for i, (x, y) in enumerate([(0, 0), (10, 0), (0, -3), (10, -3)], 1))
    osm.write_text(f'<osm>{nodes}<way id="10"><nd ref="1"/><nd ref="2"/></way><way id="11"><nd ref="3"/>'
                   '<nd ref="4"/></way><relation id="20"><member type="way" role="left" ref="10"/>'
                   '<member type="way" role="right" ref="11"/><tag k="type" v="lanelet"/>'
                   '<tag k="subtype" v="road"/></relation></osm>')
    (road,) = load_lanelet_map(osm).road()
    np.testing.assert_allclose(road.polygon, [[0, 0], [10, 0], [10, -3], [0, -3]])
    osm.write_text(osm.read_text().replace('ref="11"/><tag', 'ref="99"/><tag'))
    with pytest.raises(Lanelet2Error, match="lanelet 20"):
        load_lanelet_map(osm)
