"""Geometry against closed forms and shapely as the oracle."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from pytest_driveeval.geometry import (
    agent_from_world,
    box_corners,
    boxes_overlap,
    oriented_boxes_overlap,
    points_in_boxes,
    segment_box_overlap_length,
    transform_points,
    world_from_agent,
    wrap_angle,
    yaw_as_rotation33,
    yaw_from_rotation33,
)

shapely = pytest.importorskip("shapely")
from shapely.geometry import LineString, Polygon  # noqa: E402

coord = st.floats(-20, 20, allow_nan=False, allow_subnormal=False)  # sub-1e-300 m says nothing about geometry
yaw_st = st.floats(-7, 7, allow_nan=False)
size = st.floats(0.3, 8, allow_nan=False)
box_st = st.tuples(coord, coord, yaw_st, size, size)


def _poly(box) -> Polygon:
    x, y, yaw, length, width = box
    return Polygon(box_corners(np.array([x, y]), yaw, np.array([length, width])))


def test_transforms_round_trip_and_yaw():
    rng = np.random.default_rng(0)
    c, yaw = rng.normal(0, 100, (3, 5, 2)), rng.uniform(-10, 10, (3, 5))
    pts = rng.normal(0, 10, (3, 5, 7, 2))
    back = transform_points(transform_points(pts, world_from_agent(c, yaw)), agent_from_world(c, yaw))
    np.testing.assert_allclose(back, pts, atol=1e-9)
    np.testing.assert_allclose(yaw_from_rotation33(yaw_as_rotation33(yaw)), wrap_angle(yaw), atol=1e-12)
    # The agent's own origin maps to its centroid; its x axis to its heading.
    m = world_from_agent(np.array([1.0, 2.0]), np.pi / 2)
    np.testing.assert_allclose(transform_points(np.array([[0.0, 0.0], [1.0, 0.0]]), m), [[1, 2], [1, 3]], atol=1e-12)


def test_wrap_angle_range():
    a = wrap_angle(np.array([np.pi, -np.pi, 3 * np.pi, 0.1, -7.0]))
    assert np.all(a >= -np.pi) and np.all(a < np.pi)
    np.testing.assert_allclose(np.cos(a), np.cos([np.pi, -np.pi, 3 * np.pi, 0.1, -7.0]), atol=1e-12)


def test_box_corners_order_is_l5kits():
    # Heading +y: the front edge is at y = +length/2, front-left at x < 0.
    c = box_corners(np.array([10.0, 0.0]), np.pi / 2, np.array([4.0, 2.0]))
    np.testing.assert_allclose(c, [[9, 2], [11, 2], [11, -2], [9, -2]], atol=1e-12)


@settings(max_examples=300, deadline=None)
@given(box_st, box_st)
def test_boxes_overlap_matches_shapely(a, b):
    pa, pb = _poly(a), _poly(b)
    # Near-touching pairs are decided by rounding in both implementations.
    inter = pa.intersection(pb).area
    gap = pa.distance(pb)
    assume(inter > 1e-6 or gap > 1e-6)
    expected = inter > 1e-6
    ca = box_corners(np.array(a[:2]), a[2], np.array(a[3:]))
    cb = box_corners(np.array(b[:2]), b[2], np.array(b[3:]))
    assert bool(boxes_overlap(ca, cb)) == expected
    got = oriented_boxes_overlap(np.array(a[:2]), a[2], np.array(a[3:]), np.array(b[:2]), b[2], np.array(b[3:]))
    assert bool(got) == expected


def test_boxes_overlap_broadcasts_and_counts_touching():
    rng = np.random.default_rng(1)
    ego = box_corners(rng.normal(0, 1, (4, 1, 2)), rng.uniform(-3, 3, (4, 1)), np.array([4.8, 1.9]))
    agents = box_corners(rng.normal(0, 6, (4, 9, 2)), rng.uniform(-3, 3, (4, 9)), np.array([4.0, 2.0]))
    out = boxes_overlap(ego, agents)
    assert out.shape == (4, 9)
    expected = [[Polygon(ego[s, 0]).intersects(Polygon(agents[s, a])) for a in range(9)] for s in range(4)]
    assert out.tolist() == expected
    # Edge-to-edge contact intersects, as in shapely.
    a = box_corners(np.zeros(2), 0.0, np.array([2.0, 2.0]))
    b = box_corners(np.array([2.0, 0.5]), 0.0, np.array([2.0, 2.0]))
    assert boxes_overlap(a, b) and Polygon(a).intersects(Polygon(b))
    assert not boxes_overlap(a, b, tol=-1e-3)


@settings(max_examples=200, deadline=None)
@given(box_st, coord, coord, coord, coord)
def test_segment_overlap_length_matches_shapely(box, x0, y0, x1, y1):
    got = segment_box_overlap_length(np.array([x0, y0]), np.array([x1, y1]), np.array(box[:2]), box[2],
                                     np.array(box[3:]))
    expected = _poly(box).intersection(LineString([(x0, y0), (x1, y1)])).length
    assert got == pytest.approx(expected, abs=1e-6)


def test_segment_on_box_boundary_counts_fully():
    # The edge of one box lying on the other's border: shapely gives its length.
    got = segment_box_overlap_length(np.array([1.0, -1.0]), np.array([1.0, 1.0]), np.zeros(2), 0.0,
                                     np.array([2.0, 4.0]))
    assert got == pytest.approx(2.0)


def _points_in_boxes_brute(points, centers, yaws, sizes):
    rel = points[:, None, :2] - centers[None, :, :2]
    c, s = np.cos(yaws), np.sin(yaws)
    u = rel[..., 0] * c + rel[..., 1] * s
    v = -rel[..., 0] * s + rel[..., 1] * c
    half = sizes / 2 * (1 + 1e-9)  # faces count as inside despite rounding, as documented
    inside = (np.abs(u) <= half[:, 0]) & (np.abs(v) <= half[:, 1])
    return inside & (np.abs(points[:, None, 2] - centers[None, :, 2]) <= half[:, 2])


@pytest.mark.parametrize("seed", range(5))
def test_points_in_boxes_matches_brute_force(seed):
    rng = np.random.default_rng(seed)
    points = np.column_stack([rng.uniform(-60, 60, (20000, 2)), rng.uniform(-2, 4, 20000)])
    centers = np.column_stack([rng.uniform(-50, 50, (20, 2)), rng.uniform(0, 2, 20)])
    yaws, sizes = rng.uniform(-np.pi, np.pi, 20), np.column_stack([rng.uniform(1, 12, (20, 2)), rng.uniform(1, 3, 20)])
    # A few points exactly on faces / inside known boxes.
    points[:20, :2] = centers[:, :2]
    points[:20, 2] = centers[:, 2] + sizes[:, 2] / 2
    res = points_in_boxes(points, centers, yaws, sizes)
    expected = _points_in_boxes_brute(points, centers, yaws, sizes)
    np.testing.assert_array_equal(res.mask, expected)
    np.testing.assert_array_equal(res.counts, expected.sum(axis=0))
    assert res.counts.min() >= 1


def test_points_in_boxes_2d_and_empty():
    pts = np.array([[0.0, 0.0], [1.9, 0.0], [2.1, 0.0]])
    res = points_in_boxes(pts, np.zeros((1, 2)), np.zeros(1), np.array([[4.0, 2.0]]))
    assert res.mask[:, 0].tolist() == [True, True, False]
    empty = points_in_boxes(pts, np.zeros((0, 2)), np.zeros(0), np.zeros((0, 2)))
    assert empty.counts.shape == (0,) and empty.mask.shape == (3, 0)
    assert points_in_boxes(pts, np.zeros((1, 2)), np.zeros(1), np.array([[4.0, 2.0]]), return_mask=False).mask is None
