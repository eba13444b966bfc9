"""l5kit's vectorised map keys (sim.logreplay.map_inputs) on small hand-made maps: which lanes, in what
order, in what frame, what is available, the traffic-light feature, crosswalks, places."""
from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("torch")  # sim.logreplay imports it: a Python without torch skips the file

from pytest_driveeval.io.l5.l5_semantic_map import GREEN, RED, Polylines, SemanticMap  # noqa: E402
from pytest_driveeval.sim.logreplay.map_inputs import NO_LIGHT, MapLimits, VectorMap  # noqa: E402


def straight_lane(y: float, x0: float = -20.0, x1: float = 20.0, width: float = 3.0):
    """Left and right boundaries of a lane along x at height y (K = 3 points each)."""
    xs = np.array([x0, 0.5 * (x0 + x1), x1])
    return np.stack([xs, np.full(3, y + width / 2)], 1), np.stack([xs, np.full(3, y - width / 2)], 1)


def make_map(lanes, controls=None, crosswalks=(), faces=(), lights=(), face_light=None, ids=None) -> SemanticMap:
    controls = controls or [[] for _ in lanes]
    return SemanticMap(
        lane_ids=np.array(ids or [f"l{i}" for i in range(len(lanes))]),
        lanes_left=Polylines.from_list([left for left, _ in lanes]),
        lanes_right=Polylines.from_list([right for _, right in lanes]),
        lane_control_offsets=np.r_[0, np.cumsum([len(c) for c in controls])].astype(np.int64),
        lane_control_ids=np.array([c for cs in controls for c in cs], dtype="<U16"),
        crosswalk_ids=np.array([f"c{i}" for i in range(len(crosswalks))], dtype="<U16"),
        crosswalks=Polylines.from_list(list(crosswalks)),
        face_ids=np.array([f for f, _ in faces], dtype="<U16"),
        face_colours=np.array([c for _, c in faces], np.int8),
        world_to_ecef=np.eye(4),
        traffic_light_ids=np.array(list(lights), dtype="<U16"),
        face_light_index=np.array(face_light if face_light is not None else [-1] * len(faces), np.int64))


def at(vector, x=0.0, y=0.0, yaw=0.0, lit=None, place=None):
    return vector(np.array([[x, y]], float), np.cos([yaw]), np.sin([yaw]), lit, place)


def test_shapes_dtypes_order_and_frame():
    lanes = [straight_lane(y) for y in (12.0, -3.0, 6.0, 0.5)]
    vector = VectorMap(make_map(lanes), MapLimits(max_lanes=3, max_points_per_lane=5))
    out, chosen = at(vector, x=1.0, y=0.0, yaw=np.pi / 2)
    assert out["lanes"].shape == (1, 6, 5, 3) and out["lanes_mid"].shape == (1, 3, 5, 3)
    assert out["crosswalks"].shape == (1, 20, 20, 3)
    assert out["lanes"].dtype == np.float32 and out["lanes_availabilities"].dtype == bool
    # nearest first by the centre line's closest point: y = 0.5, -3, 6; the fourth (12) is over the limit
    assert chosen[0].tolist() == [3, 1, 2]
    # agent frame of an ego at (1, 0) heading +y: a world point (x, y) is at (y, 1 - x)
    mid = out["lanes_mid"][0, 0, :, :2]
    np.testing.assert_allclose(mid[:, 0], 0.5, atol=1e-6)
    np.testing.assert_allclose(mid[:, 1], 1.0 - np.linspace(-20, 20, 5), atol=1e-5)
    np.testing.assert_allclose(out["lanes"][0, 0, :, 0], 2.0, atol=1e-6)  # the left boundary, y = 2
    np.testing.assert_allclose(out["lanes"][0, 1, :, 0], -1.0, atol=1e-6)  # the right one, y = -1
    assert (out["lanes_mid"][0, :, :, 2] == NO_LIGHT).all()


def test_points_beyond_the_distance_are_not_available_and_far_lanes_are_not_candidates():
    lanes = [straight_lane(0.0, -100.0, 100.0), straight_lane(200.0)]
    vector = VectorMap(make_map(lanes), MapLimits(max_points_per_lane=21, max_distance=35.0))
    out, chosen = at(vector)
    assert chosen[0, 0] == 0 and (chosen[0, 1:] == -1).all()
    xs = np.linspace(-100, 100, 21)
    np.testing.assert_array_equal(out["lanes_mid_availabilities"][0, 0], np.abs(xs) < 35.0)
    assert not out["lanes_mid_availabilities"][0, 1:].any() and not out["lanes_availabilities"][0, 2:].any()


def test_traffic_light_feature():
    lanes = [straight_lane(y) for y in (0.0, 4.0, 8.0)]
    faces = [("red", RED), ("green", GREEN), ("loose", RED)]
    # lane 0: a light and its two faces; lane 1: a face of no light (no light, as l5kit reads it); lane 2: none
    smap = make_map(lanes, controls=[["tl", "red", "green"], ["loose"], []], faces=faces, lights=["tl"],
                    face_light=[0, 0, -1])
    vector = VectorMap(smap)
    lit = np.zeros((1, 3), bool)
    light = lambda out: out[0]["lanes_mid"][0, :3, 0, 2].tolist()  # noqa: E731
    assert light(at(vector, lit=lit)) == [0.0, NO_LIGHT, NO_LIGHT]  # a light, no face lit: unknown
    lit[0, 1] = True
    assert light(at(vector, lit=lit)) == [1.0, NO_LIGHT, NO_LIGHT]  # green
    lit[0, [0, 2]] = True
    assert light(at(vector, lit=lit)) == [3.0, NO_LIGHT, NO_LIGHT]  # red beats green
    # A face whose light the map knows counts though the lane lists the face alone (ScenarioNet's lights)
    smap = make_map(lanes[:1], controls=[["red"]], faces=faces[:1], lights=["tl"], face_light=[0])
    assert at(VectorMap(smap), lit=np.ones((1, 1), bool))[0]["lanes_mid"][0, 0, 0, 2] == 3.0


def test_crosswalks_in_map_order_first_points_only():
    square = lambda cx: np.array([[cx - 1, -1], [cx + 1, -1], [cx + 1, 1], [cx - 1, 1]], float)  # noqa: E731
    smap = make_map([straight_lane(0.0)], crosswalks=[square(30.0), square(5.0), square(300.0)])
    out, _ = at(VectorMap(smap, MapLimits(max_points_per_crosswalk=3)))
    ok = out["crosswalks_availabilities"][0]
    assert ok[:2].all() and not ok[2:].any()  # the far one is not a candidate; each its first 3 points
    np.testing.assert_allclose(out["crosswalks"][0, 0, :, :2], square(30.0)[:3], atol=1e-6)  # map order, not nearest
    np.testing.assert_allclose(out["crosswalks"][0, 1, :, :2], square(5.0)[:3], atol=1e-6)


def test_each_row_sees_its_own_place_and_repeated_ids_once():
    here = make_map([straight_lane(0.0), straight_lane(0.0)], ids=["a", "a"])
    there = make_map([straight_lane(3.0)], ids=["b"])
    vector = VectorMap([here, there])
    assert vector.lane_ids.tolist() == ["a", "b"]
    out, chosen = vector(np.zeros((2, 2)), np.ones(2), np.zeros(2), None, np.array([1, 0]))
    assert chosen[:, 0].tolist() == [1, 0] and (chosen[:, 1] == -1).all()
    np.testing.assert_allclose(out["lanes_mid"][0, 0, :, 1], 3.0, atol=1e-6)


@pytest.mark.parametrize("rows", [1, 5])
def test_batched_rows_equal_rows_alone(rows):
    rng = np.random.default_rng(rows)
    lanes = [straight_lane(y, x0, x0 + 30) for y, x0 in rng.uniform(-40, 40, (40, 2))]
    vector = VectorMap(make_map(lanes), MapLimits(max_lanes=8))
    centre, yaw = rng.uniform(-30, 30, (rows, 2)), rng.uniform(-3, 3, rows)
    together, chosen = vector(centre, np.cos(yaw), np.sin(yaw))
    for b in range(rows):
        alone, alone_chosen = vector(centre[b:b + 1], np.cos(yaw[b:b + 1]), np.sin(yaw[b:b + 1]))
        np.testing.assert_array_equal(alone_chosen[0], chosen[b])
        for key, value in alone.items():
            np.testing.assert_array_equal(value[0], together[key][b], err_msg=key)
