"""obstacle_segmentation geometry: both kernels agree with perception_eval's rule, and with each other."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from pytest_driveeval.io.t4.lanelet2 import Lanelet2Error, load_lanelet_map
from pytest_driveeval.metrics import cloud_jit
from pytest_driveeval.geometry import points_in_polygon, polygon_edges, polygon_self_intersects, polygon_signed_area
from pytest_driveeval.metrics.pointcloud import Area, BoxSet, box_corners_3d, box_scale, crop_reference, evaluate_cloud
from pytest_driveeval.usecases.obstacle_segmentation.config import polygon_problem

DLR_AREA = np.array([[10.0, 1.5], [10.0, -1.5], [0.0, -1.5], [0.0, 1.5]])
KERNELS = ["numpy", pytest.param("numba", marks=pytest.mark.skipif(not cloud_jit.AVAILABLE, reason="numba is not installed: only the numpy path runs"))]


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


@pytest.mark.parametrize("kernel", KERNELS)
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_counts_nearest_and_area_match_the_reference(seed, kernel):
    pts, boxes = scene(seed)
    area = Area(DLR_AREA, 0.0, 1.5)
    got = evaluate_cloud(pts, boxes, area, kernel=kernel)
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


@pytest.mark.parametrize("kernel", KERNELS)
def test_structured_float32_cloud_and_lanelet_clip(kernel):
    pts, boxes = scene(3)
    cloud = np.zeros(len(pts), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "u1")])
    for i, k in enumerate("xyz"):
        cloud[k] = pts[:, i]
    f32 = np.stack([cloud["x"], cloud["y"], cloud["z"]], 1).astype(np.float64)
    half_lane = Area(DLR_AREA, 0.0, 1.5, clips=[np.array([[0, 0], [20, 0], [20, 5], [0, 5]], float)])
    got = evaluate_cloud(cloud, BoxSet(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0)), half_lane, kernel=kernel)
    want = f32[(f32[:, 0] > 0) & (f32[:, 0] < 10) & (f32[:, 1] > 0) & (f32[:, 1] < 1.5)
               & (f32[:, 2] >= 0) & (f32[:, 2] <= 1.5)]
    assert len(got.area_points) == len(want)
    assert evaluate_cloud(cloud, boxes, Area(DLR_AREA, 0.0, 1.5, clips=[]), kernel=kernel).area_points.shape == (0, 3)


def adversarial_cloud(rng, boxes: BoxSet, n: int, dtype) -> np.ndarray:
    """Points on and just inside box corners, on round coordinates, far away, and NaN."""
    corners = boxes.footprints()  # (B, 4, 2)
    centre = boxes.centers[:, None, :2]
    faces = np.concatenate([corners, corners + 1e-9 * (centre - corners), corners + 1e-6 * (centre - corners)],
                           axis=1).reshape(-1, 2)
    faces = np.c_[faces, np.repeat(boxes.centers[:, 2] + boxes.half[:, 2], 12)]
    near = rng.uniform(-30, 30, (n, 3))
    near[: n // 4, :2] = np.round(near[: n // 4, :2] * 4) / 4  # on round coordinates
    far = rng.uniform(-1e4, 1e4, (16, 3))
    nan = np.array([[np.nan, 1.0, 0.5], [1.0, np.nan, 0.5], [5.0, 0.0, np.nan], [np.inf, 0.0, 0.5]])
    return np.concatenate([faces, near, far, nan]).astype(dtype)


@pytest.mark.skipif(not cloud_jit.AVAILABLE, reason="numba is not installed: only the numpy path runs")
@settings(max_examples=40, deadline=None)
@given(st.integers(0, 10_000), st.integers(0, 9), st.sampled_from([np.float32, np.float64]),
       st.sampled_from(["none", "polygon", "clipped"]))
def test_both_kernels_agree_point_for_point(seed, n_boxes, dtype, area_kind):
    rng = np.random.default_rng(seed)
    centers = np.c_[rng.uniform(-25, 25, (n_boxes, 2)), rng.uniform(0, 1.5, n_boxes)]
    sizes = rng.uniform(0.2, 8.0, (n_boxes, 3))
    yaws = rng.choice([0.0, np.pi / 2, rng.uniform(-np.pi, np.pi)], n_boxes)  # axis-aligned edges too
    boxes = BoxSet.from_ground_truth(centers, sizes, yaws, 1.0, 1.3)
    area = {"none": None, "polygon": Area(DLR_AREA, 0.0, 1.5),
            "clipped": Area(np.array([[12.0, 6.0], [12.0, -6.0], [-2.0, -6.0], [-4.0, 0.0], [-2.0, 6.0]]), 0.0, 2.0,
                            clips=[np.array([[0, 0], [20, 0], [20, 4], [0, 4]], float),
                                   np.array([[-5, -1], [3, -5], [6, -1]], float)])}[area_kind]
    cloud = adversarial_cloud(rng, boxes, 3000, dtype)
    fast, slow = (evaluate_cloud(cloud, boxes, area, kernel=k) for k in ("numba", "numpy"))
    np.testing.assert_array_equal(fast.counts, slow.counts)
    np.testing.assert_array_equal(fast.nearest, slow.nearest)
    np.testing.assert_array_equal(fast.area_points, slow.area_points)
    # Both right, too.  On the faces, against the same float64 rule applied to every point
    # (the grid must not lose a point that rounding leaves just inside) ...
    xyz = cloud.astype(np.float64)
    with np.errstate(invalid="ignore"):  # inf * 0
        assert fast.counts.tolist() == boxes.contains(*xyz.T).sum(axis=0).tolist()
    # ... and off them against perception_eval's rule, which is half-open on faces.
    on_faces = 12 * n_boxes
    if n_boxes:
        rest = evaluate_cloud(cloud[on_faces:], boxes, area, kernel="numba")
        finite = xyz[on_faces:][np.isfinite(xyz[on_faces:]).all(axis=1)]
        assert rest.counts.tolist() == [len(crop_reference(finite, c)) for c in box_corners_3d(boxes)]


def test_kernel_choice_is_checked(monkeypatch):
    pts, boxes = scene(0, n=100)
    with pytest.raises(ValueError, match="'numba' or 'numpy'"):
        evaluate_cloud(pts, boxes, kernel="cuda")
    monkeypatch.setattr(cloud_jit, "AVAILABLE", False)
    with pytest.raises(ImportError, match="pip install"):
        evaluate_cloud(pts, boxes, kernel="numba")
    assert evaluate_cloud(pts, boxes).counts.tolist() == evaluate_cloud(pts, boxes, kernel="numpy").counts.tolist()


@pytest.mark.parametrize("kernel", KERNELS)
@pytest.mark.parametrize("dtype", [">f4", "<f2", "<i2"])
def test_clouds_of_any_numeric_field_type(kernel, dtype):
    pts, boxes = scene(4, n=5000)
    cloud = np.zeros(len(pts), dtype=[("x", dtype), ("y", dtype), ("z", dtype)])
    for i, k in enumerate("xyz"):
        cloud[k] = pts[:, i]
    xyz = np.stack([cloud[k].astype(np.float64) for k in "xyz"], axis=1)
    got = evaluate_cloud(cloud, boxes, Area(DLR_AREA, -10.0, 10.0), kernel=kernel)
    assert got.counts.tolist() == boxes.contains(*xyz.T).sum(axis=0).tolist()
    assert len(got.area_points) == len(evaluate_cloud(xyz, boxes, Area(DLR_AREA, -10.0, 10.0)).area_points)


@pytest.mark.parametrize("kernel", KERNELS)
def test_a_non_finite_box_is_an_error_not_a_count(kernel):
    pts, boxes = scene(0, n=100)
    boxes.centers[3, 0] = np.nan
    with pytest.raises(ValueError, match=r"box 3 has a non-finite centre"):
        evaluate_cloud(pts, boxes, kernel=kernel)


@pytest.mark.parametrize("kernel", KERNELS)
@pytest.mark.parametrize("bad", [np.inf, -np.inf, np.nan])
def test_a_non_finite_size_or_yaw_is_found_whatever_the_other_values(kernel, bad):
    """The check sums the boxes' values first: inf and -inf in one sum make NaN, still caught."""
    pts, boxes = scene(0, n=100)
    boxes.half[4, 2] = bad
    boxes.yaws[6] = -bad
    with pytest.raises(ValueError, match=r"box 4 has a non-finite size"):
        evaluate_cloud(pts, boxes, kernel=kernel)
    boxes.half[4, 2] = 1.0
    with pytest.raises(ValueError, match=r"box 6 has a non-finite yaw"):
        evaluate_cloud(pts, boxes, kernel=kernel)


def test_polygon_edges_of_several_polygons_close_each_one():
    tri, square = np.array([[0.0, 0.0], [4.0, 0.0], [0.0, 2.0]]), DLR_AREA
    table, ends = polygon_edges(tri, np.zeros((0, 2)), square)
    assert ends.tolist() == [3, 3, 7]
    assert table[2, 2] == 0.0 and table[6, 2] == square[0, 1]  # last edges end on their first vertices
    assert table[1, 3] == -2.0  # (0 - 4) / (2 - 0)
    assert table[0, 3] == 0.0  # horizontal edge


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
