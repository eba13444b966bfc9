"""Blueprints: parameters and their validation, seeded spawns, the road's queries."""
from __future__ import annotations

import numpy as np
import pytest

from pytest_driveeval.geometry import oriented_boxes_overlap
from pytest_driveeval.sim.agents import TrafficModel
from pytest_driveeval.sim.blueprints import (
    BLUEPRINTS,
    Lane,
    ParameterError,
    Road,
    make_blueprint,
)

NAMES = sorted(BLUEPRINTS)


def test_bark_ml_defaults():
    hw, mg, ix = (make_blueprint(n).params for n in ("highway", "merging", "intersection"))
    assert (hw.lanes, hw.gap, hw.speed, hw.dt) == (4, (15.0, 35.0), (12.5, 17.5), 0.2)
    assert (mg.gap, mg.speed, mg.merge_end) == ((7.0, 17.0), (9.0, 11.0), 100.0)
    assert ix.speed == (10.0, 12.0) and ix.ego_max_steer == 0.5 and hw.ego_max_steer == 0.2
    assert hw.ego_accel == mg.ego_accel == (-5.0, 4.0)


def test_an_unknown_blueprint_is_named_with_a_suggestion():
    with pytest.raises(ValueError, match=r"unknown blueprint 'higway' \(did you mean 'highway'\?\)"):
        make_blueprint("higway")


def test_an_unknown_parameter_is_named_with_a_suggestion():
    with pytest.raises(ParameterError, match=r"did you mean 'gap'") as info:
        make_blueprint("merging", gaps=(5, 10))
    assert (info.value.owner, info.value.parameter) == ("merging", "gaps")
    assert isinstance(info.value, ValueError)


@pytest.mark.parametrize("name, params, parameter, message", [
    ("highway", {"gap": (35, 15)}, "gap", "low 35.0 is above high 15.0"),
    ("highway", {"lanes": 1}, "lanes", ">= 2"),
    ("highway", {"lanes": True}, "lanes", "whole number"),
    ("highway", {"max_steps": 2.5}, "max_steps", "whole number"),
    ("highway", {"dt": -0.1}, "dt", "> 0"),
    ("highway", {"speed": "fast"}, "speed", r"\(low, high\) pair"),
    ("highway", {"speed": (1, float("nan"))}, "speed", "finite number"),
    ("highway", {"ego_lane": 4}, "ego_lane", "below lanes"),
    ("highway", {"goal_lanes": (1,)}, "goal_lanes", "not another lane"),
    ("highway", {"goal_lanes": ()}, "goal_lanes", "non-empty"),
    ("highway", {"ego_accel": (1.0, 4.0)}, "ego_accel", "must include 0"),
    ("highway", {"length": 200.0}, "traffic_span", "beyond the road"),
    ("merging", {"merge_end": 400.0}, "merge_end", "below the main lane"),
    ("merging", {"ego_s": (5.0, 120.0)}, "ego_s", "before the lane end"),
    ("intersection", {"ego_distance": (10.0, 200.0)}, "ego_distance", "start on its arm"),
    ("intersection", {"traffic_span": (-150.0, 0.0)}, "traffic_span", "within"),
])
def test_a_bad_value_names_its_parameter(name, params, parameter, message):
    with pytest.raises(ParameterError, match=message) as info:
        make_blueprint(name, **params)
    assert info.value.parameter == parameter and info.value.owner == name


def test_traffic_model_is_validated_too():
    with pytest.raises(ParameterError, match="max_brake") as info:
        TrafficModel(max_brake=1.0)
    assert info.value.owner == "traffic"
    with pytest.raises(ParameterError, match="min_gap"):
        TrafficModel(min_gap=0.0)


def test_yaml_lists_become_tuples():
    bp = make_blueprint("highway", gap=[20, 30], goal_lanes=[2], max_steps=50.0)
    assert bp.params.gap == (20.0, 30.0) and bp.params.goal_lanes == (2,) and bp.max_steps == 50


@pytest.mark.parametrize("name", NAMES)
def test_spawn_is_a_function_of_the_seed(name):
    bp = make_blueprint(name)
    a, b, c = (bp.spawn(np.random.default_rng(seed), 12) for seed in (7, 7, 8))
    for field in ("lane", "s", "speed", "desired_speed"):
        np.testing.assert_array_equal(getattr(a, field), getattr(b, field))
    np.testing.assert_array_equal(a.goal.centre, b.goal.centre)
    assert a.ego_s == b.ego_s and a.ego_speed == b.ego_speed
    assert a.ego_s != c.ego_s and not np.array_equal(a.s[:3], c.s[:3])


@pytest.mark.parametrize("name", NAMES)
def test_spawns_keep_their_parameters(name):
    bp = make_blueprint(name)
    p, road = bp.params, bp.road
    for seed in range(40):
        sp = bp.spawn(np.random.default_rng(seed), 12)
        assert len(sp.s) <= 11
        assert np.all((sp.speed >= p.speed[0]) & (sp.speed <= p.speed[1]))
        assert np.all((sp.desired_speed >= p.desired_speed[0]) & (sp.desired_speed <= p.desired_speed[1]))
        assert p.ego_speed[0] <= sp.ego_speed <= p.ego_speed[1]
        for lane in np.unique(sp.lane):
            s = np.sort(np.append(sp.s[sp.lane == lane], sp.ego_s if lane == sp.ego_lane else []))
            assert np.all(np.diff(s) >= p.gap[0] - 1e-9), (seed, lane, s)
        xy, yaw = road.pose(np.append(sp.ego_lane, sp.lane), np.append(sp.ego_s, sp.s), 0.0)
        dist = np.linalg.norm(xy[1:] - xy[0], axis=1)
        assert np.all(np.diff(dist) >= 0), "vehicles are listed nearest to the ego first"
        size = np.array([p.vehicle_length, p.vehicle_width])
        boxes = oriented_boxes_overlap(xy[:, None], yaw[:, None], size, xy[None], yaw[None], size)
        assert np.array_equal(boxes, np.eye(len(xy), dtype=bool)), "nothing overlaps at the start"
        assert np.all(road.drivable.contains(xy))
        goal_proj = road.project(sp.goal.centre)
        goal_lane = int(np.argmin(np.abs(goal_proj.d)))
        assert goal_lane != sp.ego_lane and sp.goal.heading == pytest.approx(goal_proj.heading[goal_lane])


def test_highway_goal_lies_ahead_on_a_candidate_lane():
    bp = make_blueprint("highway", goal_lanes=(0, 2))
    lanes = set()
    for seed in range(20):
        sp = bp.spawn(np.random.default_rng(seed), 12)
        lane = round(sp.goal.centre[1] / bp.params.lane_width)
        lanes.add(lane)
        assert 100.0 <= sp.goal.centre[0] - sp.ego_s <= 150.0
    assert lanes == {0, 2}


def test_the_agent_limit_keeps_the_nearest_vehicles():
    bp = make_blueprint("highway")
    few, many = (bp.spawn(np.random.default_rng(3), limit) for limit in (4, 60))
    assert len(few.s) == 3 and len(many.s) > 11
    np.testing.assert_array_equal(few.s, many.s[:3])
    np.testing.assert_array_equal(few.lane, many.lane[:3])


def test_projection_and_pose_invert_each_other_on_a_bent_lane():
    bent = Lane(np.array([[0.0, 0.0], [10.0, 0.0], [20.0, 10.0]]), 3.0)
    road = Road((bent, Lane(np.array([[0.0, 5.0], [30.0, 5.0]]), 3.0)))
    s = np.array([-5.0, 2.0, 9.0, 12.0, 30.0])  # before the start, on both segments, past the end
    d = np.array([0.5, -1.0, 0.2, 1.0, -0.3])
    xy, heading = road.pose(np.zeros(5, int), s, d)
    proj = road.project(xy)
    np.testing.assert_allclose(proj.s[:, 0], s, atol=1e-9)
    np.testing.assert_allclose(proj.d[:, 0], d, atol=1e-9)
    np.testing.assert_allclose(heading, [0, 0, 0, np.pi / 4, np.pi / 4])
    np.testing.assert_allclose(proj.heading[:, 0], heading)
    np.testing.assert_allclose(proj.d[:, 1], xy[:, 1] - 5.0)  # the straight lane sees the same points


def test_a_bent_lane_keeps_its_width_at_the_bend():
    lane = Lane(np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 10.0]]), 4.0)
    outline = lane.outline()
    np.testing.assert_allclose(outline[1], [8.0, 2.0])  # inner mitre of the left turn
    np.testing.assert_allclose(outline[4], [12.0, -2.0])  # outer mitre
    assert Road((lane,)).drivable.contains(np.array([[11.9, -1.9], [10.0, 5.0]])).all()
    assert not Road((lane,)).drivable.contains(np.array([[12.2, 5.0]])).any()


def test_a_lane_needs_two_distinct_points_and_a_width():
    with pytest.raises(ValueError, match="repeated"):
        Lane(np.array([[0.0, 0.0], [0.0, 0.0]]), 3.0)
    with pytest.raises(ValueError, match="width"):
        Lane(np.array([[0.0, 0.0], [1.0, 0.0]]), 0.0)


def test_drivable_area_of_the_merge_ends_with_the_lane():
    road = make_blueprint("merging").road
    inside = road.drivable.contains(np.array([[50.0, 0.0], [99.8, -1.6], [150.0, 3.5], [50.0, 5.1]]))
    outside = road.drivable.contains(np.array([[100.2, 0.0], [50.0, -1.9], [150.0, 0.0], [50.0, 5.4], [-1.0, 0.0]]))
    assert inside.all() and not outside.any()
    np.testing.assert_allclose(road.bounds, [0.0, -1.75, 300.0, 5.25])


def test_intersection_kerbs_are_rounded():
    road = make_blueprint("intersection").road  # lanes 3.5 m, kerb radius 5 m
    # Just outside the corner of the two roads: inside the fillet near the corner, outside beyond the arc.
    assert road.drivable.contains(np.array([[3.8, 3.8], [-4.0, -3.7], [0.0, 0.0], [1.75, -90.0]])).all()
    assert not road.drivable.contains(np.array([[6.0, 6.0], [-7.0, 7.0], [5.0, -20.0]])).any()
