"""The compiled obstacle kernel gives each point the verdict of the float64 rule, point for point.

The rule (the formulation both kernels had before the grid classes): a point is in
box b when ``BoxSet.contains`` says so, and an area point when it is in no box, in
the z range, in the polygon (``points_in_polygon``) and, with lanelet clips, in
one of them.  The clouds hold points exactly on and a rounding step either side of
box faces, box z planes, polygon edges and vertices, in every record layout the
kernel reads differently (wide loads of 12, 16, 24, 32 byte records, gathers for
packed ones, a float64 copy for the rest).
"""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from pytest_driveeval.geometry import points_in_polygon
from pytest_driveeval.metrics import cloud_jit
from pytest_driveeval.metrics.pointcloud import Area, BoxSet, evaluate_cloud

pytestmark = pytest.mark.skipif(not cloud_jit.AVAILABLE, reason="numba is not installed: only the numpy path runs")

COPIES = 17  # a point repeated: one 16-point vector block and one point of the scalar tail
LAYOUTS = {
    "xyz f4 (12 B)": [("x", "<f4"), ("y", "<f4"), ("z", "<f4")],
    "XYZIRC (16 B)": [("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "u1"), ("return_type", "u1"),
                      ("channel", "<u2")],
    "padded XYZI (32 B)": {"names": ["x", "y", "z", "intensity"], "formats": ["<f4"] * 4, "offsets": [0, 4, 8, 16],
                           "itemsize": 32},
    "packed (13 B)": [("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("ring", "u1")],
    "xyz f8 (24 B)": [("x", "<f8"), ("y", "<f8"), ("z", "<f8")],
    "big-endian (copied)": [("x", ">f4"), ("y", ">f4"), ("z", ">f4")],
}
AREAS = {
    "polygon": lambda: Area(np.array([[10.0, 1.5], [10.0, -1.5], [0.0, -1.5], [0.0, 1.5]]), 0.0, 1.5),
    "slanted": lambda: Area(np.array([[12.0, 6.0], [12.0, -6.0], [-2.0, -6.0], [-4.0, 0.0], [-2.0, 6.0]]), -0.2, 2.0),
    "clipped": lambda: Area(np.array([[12.0, 6.0], [12.0, -6.0], [-2.0, -6.0], [-4.0, 0.0], [-2.0, 6.0]]), 0.0, 2.0,
                            clips=[np.array([[0, 0], [20, 0], [20, 4], [0, 4]], float),
                                   np.array([[-5, -1], [3, -5], [6, -1]], float)]),
    "none": lambda: None,
}


def rule(xyz: np.ndarray, boxes: BoxSet, area: Area | None) -> tuple[np.ndarray, np.ndarray]:
    """Per point: its (N, B) box verdicts and whether it is an area point, by the float64 rule."""
    with np.errstate(invalid="ignore"):
        inside = boxes.contains(*xyz.T)
        if area is None:
            return inside, np.zeros(len(xyz), bool)
        on = (~inside.any(axis=1)) & (xyz[:, 2] >= area.z_min) & (xyz[:, 2] <= area.z_max)
        on &= points_in_polygon(xyz[:, 0], xyz[:, 1], area.polygon)
        if area.clips is not None:
            on &= np.any([points_in_polygon(xyz[:, 0], xyz[:, 1], c) for c in area.clips], axis=0)
    return inside, on


def edge_points(rng, corners: np.ndarray, z: np.ndarray) -> np.ndarray:
    """Points on the closed outline ``corners`` (vertices, edge points), a rounding step and
    1e-9 / 1e-6 either side, at the heights ``z`` (exact planes and steps off them)."""
    nxt = np.roll(corners, -1, axis=0)
    t = rng.uniform(0, 1, (len(corners), 3))
    on = np.concatenate([corners, (corners[:, None] + t[..., None] * (nxt - corners)[:, None]).reshape(-1, 2)])
    centre = corners.mean(axis=0)
    out = [on, np.nextafter(on, np.inf), np.nextafter(on, -np.inf)]
    out += [on + d * (on - centre) for d in (1e-9, -1e-9, 1e-6, -1e-6)]
    xy = np.concatenate(out)
    zs = rng.choice(np.concatenate([z, np.nextafter(z, np.inf), np.nextafter(z, -np.inf)]), len(xy))
    return np.c_[xy, zs]


def cloud_of(rng, boxes: BoxSet, area: Area | None, n_random: int) -> np.ndarray:
    parts = []
    for fp, c, h in zip(boxes.footprints(), boxes.centers, boxes.half):
        parts.append(edge_points(rng, fp, np.array([c[2] - h[2], c[2] + h[2], c[2]])))
    if area is not None:
        for poly in [area.polygon] + list(area.clips or []):
            parts.append(edge_points(rng, np.asarray(poly, float), np.array([area.z_min, area.z_max, 1.0])))
    near = rng.uniform(-30, 30, (n_random, 3))
    near[: n_random // 3, :2] = np.round(near[: n_random // 3, :2] * 4) / 4  # on round coordinates (cell borders)
    parts += [near, [[np.nan, 1.0, 0.5], [1.0, np.nan, 0.5], [5.0, 0.0, np.nan], [np.inf, 0.0, 0.5], [1e30, 1e30, 0.5]]]
    return np.concatenate(parts)


def as_layout(xyz: np.ndarray, layout) -> np.ndarray:
    cloud = np.zeros(len(xyz), np.dtype(layout))
    for i, k in enumerate("xyz"):
        cloud[k] = xyz[:, i]
    return cloud


def scene(seed: int, n_boxes: int):
    rng = np.random.default_rng(seed)
    centers = np.c_[rng.uniform(-20, 20, (n_boxes, 2)), rng.uniform(0, 1.5, n_boxes)]
    centers[: n_boxes // 2, :2] = rng.uniform(-3, 10, (n_boxes // 2, 2))  # over the area, and over each other
    sizes = rng.uniform(0.3, 9.0, (n_boxes, 3))
    yaws = rng.choice([0.0, np.pi / 2, rng.uniform(-np.pi, np.pi)], n_boxes)  # axis-aligned edges too
    return rng, BoxSet.from_ground_truth(centers, sizes, yaws, 1.0, 1.3)


@settings(max_examples=12, deadline=None)
@given(st.integers(0, 10_000), st.integers(0, 8), st.sampled_from(sorted(LAYOUTS)), st.sampled_from(sorted(AREAS)))
def test_every_point_gets_the_float64_rules_verdict(seed, n_boxes, layout, area_kind):
    rng, boxes = scene(seed, n_boxes)
    area = AREAS[area_kind]()
    cloud = as_layout(cloud_of(rng, boxes, area, 200), LAYOUTS[layout])
    xyz = np.stack([cloud[k].astype(np.float64) for k in "xyz"], axis=1)
    inside, on = rule(xyz, boxes, area)
    # Point by point: each point alone (COPIES times, so both the vector and the scalar path judge it).
    for p in rng.permutation(len(cloud))[:400]:
        got = evaluate_cloud(np.repeat(cloud[p:p + 1], COPIES), boxes, area, kernel="numba")
        assert got.counts.tolist() == (COPIES * inside[p]).tolist(), f"point {xyz[p]!r}"
        assert len(got.area_points) == COPIES * on[p], f"point {xyz[p]!r}"
    # The whole cloud: counts, the area's points in cloud order, the nearest point (first on ties).
    got = evaluate_cloud(cloud, boxes, area, kernel="numba")
    assert got.counts.tolist() == inside.sum(axis=0).tolist()
    np.testing.assert_array_equal(got.area_points, xyz[on])
    slow = evaluate_cloud(cloud, boxes, area, kernel="numpy")
    np.testing.assert_array_equal(got.nearest, slow.nearest)
    np.testing.assert_array_equal(got.area_points, slow.area_points)


@pytest.mark.parametrize("layout", sorted(LAYOUTS))
def test_a_large_cloud_in_every_layout_matches_the_rule(layout):
    """Many chunks, their tails, and cells of every class, against the rule on all points."""
    rng, boxes = scene(7, 12)
    area = AREAS["slanted"]()
    xyz = np.concatenate([cloud_of(rng, boxes, area, 30_000), rng.uniform(-12, 12, (20_001, 3))])
    cloud = as_layout(xyz, LAYOUTS[layout])
    xyz = np.stack([cloud[k].astype(np.float64) for k in "xyz"], axis=1)
    inside, on = rule(xyz, boxes, area)
    got = evaluate_cloud(cloud, boxes, area, kernel="numba")
    assert got.counts.tolist() == inside.sum(axis=0).tolist()
    np.testing.assert_array_equal(got.area_points, xyz[on])
    d2 = np.where(inside, (xyz ** 2).sum(axis=1)[:, None], np.inf)
    for b in range(len(boxes)):
        if inside[:, b].any():
            np.testing.assert_array_equal(got.nearest[b], xyz[np.argmin(d2[:, b])])  # argmin: first on ties


@pytest.mark.parametrize("edge_first", [True, False])
def test_ties_for_the_nearest_point_go_to_the_first_in_cloud_order(edge_first):
    """Equal distances (17) from a point on a face (a cell on the box's edge: exact tests) and one
    deep inside (a cell inside the box: z alone), judged in different loops of the same chunk."""
    boxes = BoxSet(np.array([[5.0, 0.0, 0.5], [60.0, 40.0, 0.5]]), np.array([[2.0, 1.0, 1.0], [1.0, 1.0, 1.0]]),
                   np.zeros(2))
    on_face, inside = [4.0, 1.0, 0.0], [4.0, 0.0, 1.0]
    tied = [on_face, inside] if edge_first else [inside, on_face]
    cloud = np.array([[-20.0, -20.0, 0.0]] * 20 + tied + [[6.0, 0.0, 0.5]] * 20, np.float32)
    got = evaluate_cloud(cloud, boxes, kernel="numba")
    assert got.counts.tolist() == [22, 0]
    assert got.nearest[0].tolist() == tied[0]


def test_frames_with_and_without_an_area_share_one_compiled_kernel():
    """numba compiles a kernel for every distinct set of argument types, array flags included: a cold
    start pays tens of seconds per extra specialisation of the frame kernels.  The area's box and its
    stand-in when no area is checked must be one type (both read-only), so only the cloud's record
    type makes a new one."""
    from pytest_driveeval.metrics import cloud_jit_grid

    cloud = np.array([[1.0, 0.5, 0.3], [8.0, -1.0, 0.4], [30.0, 9.0, 0.2]] * 11, np.float32)
    boxes = BoxSet(np.array([[1.0, 0.0, 0.5]]), np.array([[1.0, 1.0, 1.0]]), np.zeros(1))
    for area in (AREAS["polygon"](), None, AREAS["clipped"]()):
        evaluate_cloud(cloud, boxes, area, kernel="numba")
    by_record_type = {}
    for signature in cloud_jit._evaluate.signatures:
        by_record_type.setdefault(signature[0], []).append(signature)
    assert all(len(signatures) == 1 for signatures in by_record_type.values()), by_record_type
    assert len(cloud_jit_grid.build.signatures) == 1, cloud_jit_grid.build.signatures
