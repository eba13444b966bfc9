"""idm_expert on a hand-made lanelet network (tests/sim/commonroad_network.py): the route changes lanes
only where the goal needs it, the expert changes into a gap and not into a car, and a goal no route
reaches is an error naming the file, the problem and why."""
from __future__ import annotations

import numpy as np
import pytest
from commonroad_network import LANE_WIDTH, write_network

from pytest_driveeval.metrics.episode_outcomes import GOAL
from pytest_driveeval.policies.idm_expert import IDMExpert
from pytest_driveeval.sim.commonroad_fault import FaultRecorder
from pytest_driveeval.sim.commonroad_route import RouteError, plan_route
from pytest_driveeval.sim.commonroad_scene import commonroad_scene

pytest.importorskip("torch")  # run_policy's no-grad context

SEEDS = np.arange(8)


def drive(path, seeds=SEEDS):
    """(run, ego xy (steps, E, 2), car xy (steps, E, N, 2), faults) of idm_expert on the file's problem 100."""
    from pytest_driveeval.usecases.policy_benchmark.evaluate import run_policy

    scene = commonroad_scene(path, 100)
    ego, cars = [], []
    faults = FaultRecorder()

    def record(episodes):
        ego.append(episodes.xy[:, 0].copy())
        cars.append(np.where(episodes.valid[:, 1:, None], episodes.xy[:, 1:], np.nan))
        faults(episodes)

    run = run_policy(scene, seeds, IDMExpert(), "idm_expert", on_step=record)
    return run, np.array(ego), np.array(cars), faults


def test_the_route_changes_lanes_only_where_the_goal_needs_it(tmp_path):
    left = commonroad_scene(write_network(tmp_path / "left.xml"), 100)
    ahead = commonroad_scene(write_network(tmp_path / "ahead.xml", goal='<lanelet ref="3"/>'), 100)
    route = plan_route(left.scenario, left.problem)
    assert route.lanelets[:route.goal_index + 1] == (1, 2, 4)
    assert route.entered[:route.goal_index + 1] == ("start", "left", "successor")
    route = plan_route(ahead.scenario, ahead.problem)
    assert route.lanelets[:route.goal_index + 1] == (1, 3)
    assert "left" not in route.entered and "right" not in route.entered


def test_the_expert_changes_lanes_to_a_goal_on_the_left_lane(tmp_path):
    run, ego, _, faults = drive(write_network(tmp_path / "net.xml"))
    assert np.all(run.outcome == GOAL), run.outcome_names()
    assert ego[-1, :, 1].min() > 0.5 * LANE_WIDTH  # every ego ended on the left lane
    assert not any(faults.kind)


def test_without_a_lane_change_on_the_route_the_expert_keeps_its_lane(tmp_path):
    run, ego, _, _ = drive(write_network(tmp_path / "net.xml", goal='<lanelet ref="3"/>'))
    assert np.all(run.outcome == GOAL)
    assert np.abs(ego[..., 1]).max() < 0.5  # the seeds' lateral start offsets are 0.3 m at most


@pytest.mark.parametrize("cars", [((12.0, LANE_WIDTH, 10.0),),
                                  ((5.0, LANE_WIDTH, 12.0), (20.0, LANE_WIDTH, 12.0), (35.0, LANE_WIDTH, 12.0))],
                         ids=["one car alongside", "a platoon"])
def test_the_lane_change_waits_for_a_gap(tmp_path, cars):
    run, ego, car_xy, faults = drive(write_network(tmp_path / "net.xml", cars=cars))
    assert np.all(run.outcome == GOAL), run.outcome_names()
    assert not faults.kind
    # Whenever the ego's centre has crossed into the left lane, no car is within a car length and a bit
    # beside it along the lane (bumper to bumper at least 1 m).
    over = ego[..., 1] > 0.5 * LANE_WIDTH
    along = np.abs(car_xy[..., 0] - ego[..., None, 0])
    assert over.any()
    assert np.nanmin(np.where(over[..., None], along, np.inf)) > 4.5 + 1.0


def test_a_goal_on_a_lanelet_of_the_other_direction_has_no_route(tmp_path):
    path = write_network(tmp_path / "net.xml", goal='<lanelet ref="5"/>', opposite=True)
    scene = commonroad_scene(path, 100)
    with pytest.raises(RouteError, match=r"net\.xml: planning problem 100: the goal's lanelets \[5\] are not "
                                         r"reached from the start lanelet\(s\) \[1\] by successors and lane changes"):
        plan_route(scene.scenario, scene.problem)


def test_a_goal_off_the_lanelets_has_no_route(tmp_path):
    off = ("<rectangle><length>4.0</length><width>2.0</width><center><x>50.0</x><y>20.0</y></center>"
           "<orientation>0.0</orientation></rectangle>")
    scene = commonroad_scene(write_network(tmp_path / "net.xml", goal=off), 100)
    with pytest.raises(RouteError, match=r"planning problem 100: the goal \(rectangle at \(50\.00, 20\.00\)\): it "
                                         r"lies off every lanelet"):
        plan_route(scene.scenario, scene.problem)


def test_the_expert_is_deterministic_per_seed(tmp_path):
    path = write_network(tmp_path / "net.xml", cars=((12.0, LANE_WIDTH, 10.0),))
    together, ego, _, _ = drive(path, np.array([3, 5, 7]))
    alone, ego_alone, _, _ = drive(path, np.array([5]))
    assert together.steps[1] == alone.steps[0]
    np.testing.assert_array_equal(ego[:len(ego_alone), 1], ego_alone[:, 0])
