"""nuPlan's closed-loop score on the hand-checkable cases of docs/nuplan_score.md §8, each figure
worked out there from nuplan-devkit's source."""
from __future__ import annotations

import numpy as np
import pytest

from pytest_driveeval.metrics.nuplan_score import score_scene
from pytest_driveeval.metrics.nuplan_score.case import case_from_inputs, inputs_from_case
from pytest_driveeval.metrics.nuplan_score.comfort import ego_is_comfortable
from pytest_driveeval.metrics.nuplan_score.lanes import ScoreMap
from pytest_driveeval.metrics.nuplan_score.terms import driving_direction_compliance
from pytest_driveeval.metrics.nuplan_score.route import centre_route

from nuplan_cases import DT, FRAMES, agent, case, cruising

# a fast reader / score / report check: CI runs these at the lowest declared versions (-m smoke)
pytestmark = pytest.mark.smoke

T = np.arange(FRAMES) * DT


def scored(spec: dict):
    return score_scene(inputs_from_case(spec))


def term(spec: dict, name: str) -> float:
    return scored(spec).terms[name].value


def test_constant_speed_scores_one_on_every_term():
    result = scored(case("straight", cruising()))
    assert result.score == 1.0
    assert all(t.value == 1.0 for t in result.terms.values())


@pytest.mark.parametrize("expert_speed, ratio, score", [
    (10.0, 2 / 150, 0.0),            # the expert drives 150 m: not making progress
    (8 / 15, 0.25, 0.765625),        # 8 m: the ratio 0.25 passes the 0.2 bar
    (0.0, 1.0, 1.0),                 # the expert stays put too
])
def test_a_stopped_ego_against_the_expert(expert_speed, ratio, score):
    result = scored(case("stopped", np.full(FRAMES, 10.0), speed=np.zeros(FRAMES), expert_speed=expert_speed))
    assert result.terms["ego_progress_along_expert_route"].value == pytest.approx(ratio)
    assert result.terms["ego_is_making_progress"].value == (1.0 if ratio >= 0.2 else 0.0)
    assert result.score == pytest.approx(score)


def test_speeding_costs_in_proportion_to_depth_and_time():
    speed = np.full(FRAMES, 10.0)
    speed[40:70] = 15.0 + 2.23
    result = scored(case("speeding", cruising(), speed=speed))
    assert result.terms["speed_limit_compliance"].value == pytest.approx(0.8)
    assert result.score == pytest.approx(0.95)
    everywhere = scored(case("speeding", cruising(), speed=np.full(FRAMES, 15.0 + 1.115)))
    assert everywhere.terms["speed_limit_compliance"].value == pytest.approx(1 - 151 * 1.115 * 0.1 / (2.23 * 15))


def test_a_lane_exported_as_a_connector_keeps_its_own_speed_limit():
    """nuPlan gives a connector the highest limit of its edges (and raises on a connector without any);
    the export makes an edgeless lane its own edge, so the exported case scores as the lane did."""
    speed = np.full(FRAMES, 10.0)
    speed[40:70] = 15.0 + 2.23
    inputs = inputs_from_case(case("speeding", cruising(), speed=speed))
    exported = case_from_inputs(inputs, "speeding", lanes_as_connectors=True)
    (lane,) = exported["map"]["lanes"]
    assert lane["connector"] and lane["incoming"] == lane["outgoing"] == [lane["id"]]
    again = scored(exported)
    assert again.terms["speed_limit_compliance"].value == pytest.approx(0.8)
    assert again.score == pytest.approx(score_scene(inputs).score)


def test_the_exported_map_is_the_map_the_harness_scores():
    """Roadblocks of several lanes, a stand-in lane left out of the drivable area, drivable outlines and
    road edges all survive the export: the case reads back as the same map."""
    square = lambda x0, y0, w, h: np.array([[x0, y0], [x0 + w, y0], [x0 + w, y0 + h], [x0, y0 + h]], float)
    lanes = [square(0, 0, 50, 3.5), square(0, 3.5, 50, 3.5), square(50, 0, 5, 3.5)]
    score_map = ScoreMap(lane_ids=["a", "b", "c"], polygons=lanes,
                         baselines=[np.array([[0, 1.75], [50, 1.75]]), np.array([[0, 5.25], [50, 5.25]]),
                                    np.array([[50, 1.75], [55, 1.75]])],
                         speed_limits=np.array([15.0, 15.0, np.nan]), connector=[False, False, True],
                         outgoing=[[2], [], []], drivable=lanes + [square(20, -6, 5, 6)],
                         roadblock=[0, 0, 1], drivable_outlines=[square(-1, -1, 52, 9), square(10, 2, 1, 1)],
                         road_edges=[np.array([[0.0, -1.0], [50.0, -1.0]])], lane_drivable=[True, True, False])
    inputs = inputs_from_case(case("cruising", cruising()))
    inputs.map = score_map
    exported = case_from_inputs(inputs, "mapped")
    spec = exported["map"]
    assert [lane["roadblock"] for lane in spec["lanes"]] == ["rb-a", "rb-a", "rb-c"]
    assert [len(block["polygons"]) for block in spec["roadblocks"]] == [2, 1]
    assert [lane["drivable"] for lane in spec["lanes"]] == [True, True, False]
    back = inputs_from_case(exported).map
    assert back.roadblock.tolist() == [0, 0, 1] and back.connector.tolist() == [False, False, True]
    assert back.outgoing == [[2], [], []] and back.lane_drivable.tolist() == [True, True, False]
    assert all(np.array_equal(p, q) for p, q in zip(back.drivable_outlines, score_map.drivable_outlines))
    assert all(np.array_equal(p, q) for p, q in zip(back.road_edges, score_map.road_edges))
    points = np.array([[25.0, 2.0], [52.0, 2.0], [22.0, -3.0], [10.5, 2.5], [25.0, -3.0], [25.0, 20.0]])
    assert back.in_drivable(points).tolist() == score_map.in_drivable(points).tolist()
    assert score_scene(inputs_from_case(exported)).score == score_scene(inputs).score


def test_no_speed_limit_is_not_available_and_counts_one_as_nuplan_does():
    result = scored(case("unlimited", cruising(), speed=np.full(FRAMES, 30.0), speed_limit=None))
    limit = result.terms["speed_limit_compliance"]
    assert limit.value is None and limit.used == 1.0
    assert "no speed limit" in limit.reason and "as nuPlan" in limit.reason
    assert result.score == 1.0


@pytest.mark.parametrize("accel, comfortable", [(2.39, 1.0), (2.40, 0.0)])
def test_comfort_bounds_are_strict(accel, comfortable):
    result = scored(case("accelerating", cruising(), accel_x=np.full(FRAMES, accel)))
    assert result.terms["ego_is_comfortable"].value == comfortable
    assert result.score == pytest.approx(1.0 if comfortable else 0.875)


@pytest.mark.parametrize("after, comfortable, signal", [(-3.2, 0.0, "ego_lon_jerk"), (-3.0, 1.0, None)])
def test_a_braking_step_fails_on_the_filtered_jerk(after, comfortable, signal):
    accel = np.where(T < 7.5, 1.0, after)
    comfort = ego_is_comfortable(inputs_from_case(case("step", cruising(), accel_x=accel)))
    assert comfort.value == comfortable
    if signal:
        assert signal in comfort.message
        assert comfort.detail["ego_lon_jerk_max"] == pytest.approx(4.21875, abs=1e-4) or \
            comfort.detail["ego_lon_jerk_min"] == pytest.approx(-4.21875, abs=1e-4)


def test_a_step_inside_the_bounds_still_fails_where_the_filter_overshoots():
    comfort = ego_is_comfortable(inputs_from_case(case("step", cruising(), accel_x=np.where(T < 7.5, 0.0, -4.0))))
    assert comfort.value == 0.0
    assert comfort.detail["ego_lon_acceleration_min"] == pytest.approx(-4.375, abs=1e-3)


@pytest.mark.parametrize("rate, comfortable", [(0.9, 1.0), (1.0, 0.0)])
def test_yaw_rate_comes_from_the_heading(rate, comfortable):
    heading = np.angle(np.exp(1j * rate * T))
    assert ego_is_comfortable(inputs_from_case(case("turning", cruising(), heading=heading))).value == comfortable


def test_the_angular_velocity_field_shifts_the_longitudinal_acceleration():
    spec = case("shift", cruising(), accel_x=np.full(FRAMES, 1.5), angular_velocity=np.full(FRAMES, 0.9))
    comfort = ego_is_comfortable(inputs_from_case(spec))
    assert comfort.value == 0.0
    assert comfort.detail["ego_lon_acceleration_max"] == pytest.approx(1.5 + 1.461 * 0.81)


@pytest.mark.parametrize("speed, value", [(1.8, 1.0), (1.9, 0.5), (5.6, 0.0)])
def test_reversing_along_the_lane_over_eleven_steps(speed, value):
    inputs = inputs_from_case(case("reversing", 200.0 - speed * T, speed=np.full(FRAMES, speed)))
    route = centre_route(inputs.map, inputs.ego.center[:, :2], inputs.ego.center[:, 2])
    direction = driving_direction_compliance(inputs, route)
    assert direction.value == value
    assert direction.detail["max_backward_motion"] == pytest.approx(1.1 * speed)


def test_one_cone_hit_halves_the_score_and_zeroes_time_to_collision():
    result = scored(case("cone", cruising(5.0), expert_speed=5.0, agents=[agent("c1", "traffic_cone", (40.0, 0.0))]))
    assert result.terms["no_ego_at_fault_collisions"].value == 0.5
    assert result.terms["time_to_collision_within_bound"].value == 0.0
    assert result.score == pytest.approx(0.34375)


@pytest.mark.parametrize("agents", [
    [agent("c1", "traffic_cone", (40.0, 0.0)), agent("c2", "traffic_cone", (60.0, 0.0))],
    [agent("v1", "vehicle", (40.0, 0.0), length=4.5, width=2.0)],
    [agent("p1", "pedestrian", (40.0, 0.0))],
])
def test_two_objects_a_vehicle_or_a_pedestrian_hit_zero_the_score(agents):
    result = scored(case("hits", cruising(5.0), expert_speed=5.0, agents=agents))
    assert result.terms["no_ego_at_fault_collisions"].value == 0.0
    assert result.score == 0.0


def test_a_stopped_ego_hit_by_a_moving_vehicle_is_not_at_fault():
    oncoming = agent("v1", "vehicle", (40.0, 0.0), heading=np.pi, speed=5.0, length=4.5, width=2.0)
    result = scored(case("hit", np.full(FRAMES, 10.0), speed=np.zeros(FRAMES), expert_speed=0.0, agents=[oncoming]))
    inputs = inputs_from_case(case("hit", np.full(FRAMES, 10.0), speed=np.zeros(FRAMES), agents=[oncoming]))
    assert [c.at_fault for c in inputs.collisions] == [False]
    assert result.terms["no_ego_at_fault_collisions"].value == 1.0
    assert result.terms["time_to_collision_within_bound"].value == 1.0
    assert result.score == 1.0


def test_rear_ended_by_a_faster_vehicle_is_not_at_fault_and_never_ahead():
    behind = agent("v1", "vehicle", (-20.0, 0.0), speed=8.0, length=4.5, width=2.0)
    result = scored(case("rear", cruising(5.0), expert_speed=5.0, agents=[behind]))
    inputs = inputs_from_case(case("rear", cruising(5.0), agents=[behind]))
    assert len(inputs.collisions) == 1 and not inputs.collisions[0].at_fault
    assert result.terms["no_ego_at_fault_collisions"].value == 1.0
    assert result.terms["time_to_collision_within_bound"].value == 1.0


def test_time_to_collision_counts_a_slower_vehicle_ahead():
    ahead = agent("v1", "vehicle", (60.0, 0.0), speed=9.0, length=4.5, width=2.0)
    result = scored(case("closing", cruising(10.0), agents=[ahead]))
    ttc = result.terms["time_to_collision_within_bound"]
    # the gap closes at 1 m/s from 50 - 2.588 - 2.25 m: the ego catches up at t = 45.16 s, past the end
    assert ttc.value == 1.0 and ttc.detail["min_time_to_collision"] == np.inf
    close = agent("v1", "vehicle", (19.0, 0.0), speed=5.0, length=4.5, width=2.0)
    near = scored(case("closing", cruising(10.0), agents=[close])).terms["time_to_collision_within_bound"]
    # gap 9 - 2.588 - 2.25 = 4.162 m closing at 5 m/s: 0.8324 s, so the first step that meets is 0.9 s
    assert near.value == 0.0
    assert near.frames[0] == 0 and near.detail["min_time_to_collision"] == 0.0


@pytest.mark.parametrize("out, value", [(0.5, 0.0), (0.2, 1.0)])
def test_a_corner_off_the_drivable_area(out, value):
    y = np.full(FRAMES, 2.0 + out - 2.297 / 2)
    result = scored(case("edge", cruising(), y=y))
    area = result.terms["drivable_area_compliance"]
    assert area.value == value
    assert area.detail["max_corner_off_drivable_area"] == pytest.approx(out)
    if not value:
        assert area.frames == list(range(FRAMES)) and "0.50 m off the drivable area at frame 0" in area.message


def test_without_a_map_the_map_terms_are_left_out_of_the_score():
    spec = case("no map", cruising(), accel_x=np.full(FRAMES, 2.5), with_map=False)
    result = scored(spec)
    missing = result.not_available()
    assert set(missing) == {"drivable_area_compliance", "driving_direction_compliance", "speed_limit_compliance"}
    assert all("no map" in why for why in missing.values())
    assert all(result.terms[name].used is None for name in missing)
    assert result.score == pytest.approx((5 + 5 + 0) / 12)  # uncomfortable: 2 of the 12 remaining weights lost


@pytest.mark.parametrize("off_from", [0, 40])
def test_driving_off_every_lane_counts_no_step_against_one(off_from):
    y = np.where(np.arange(FRAMES) >= off_from, 500.0, 0.0)  # far beside the lane: from the start, or from frame 40
    inputs = inputs_from_case(case("off", 200.0 - 5.0 * T, y=y, speed=np.full(FRAMES, 5.0)))
    route = centre_route(inputs.map, inputs.ego.center[:, :2], inputs.ego.center[:, 2])
    direction = driving_direction_compliance(inputs, route)
    assert sum(bool(lanes) for lanes in route) == off_from
    assert direction.detail["max_backward_motion"] == pytest.approx(0.5 * min(off_from - 1, 11) if off_from else 0.0)
