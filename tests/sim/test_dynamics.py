"""Dynamics models: pose target, unicycle with limits, kinematic bicycle; the batched state."""
from __future__ import annotations

import numpy as np
import pytest

from pytest_driveeval.sim.dynamics import KinematicBicycle, KinematicLimits, PoseTarget, Unicycle
from pytest_driveeval.sim.state import AgentState


def state(xy, yaw, speed) -> AgentState:
    return AgentState(np.asarray(xy, float), np.asarray(yaw, float), np.asarray(speed, float))


def test_agent_state_take_and_replace():
    s = state(np.arange(12.0).reshape(3, 2, 2), np.arange(6.0).reshape(3, 2), np.ones((3, 2)))
    assert s.shape == (3, 2)
    row = s.take(np.array([2, 0]))
    assert row.xy.tolist() == [[[8.0, 9.0], [10.0, 11.0]], [[0.0, 1.0], [2.0, 3.0]]]
    assert row.yaw.tolist() == [[4.0, 5.0], [0.0, 1.0]] and row.shape == (2, 2)
    moved = s.replace(speed=np.zeros((3, 2)))
    assert moved.speed.sum() == 0 and s.speed.sum() == 6 and moved.xy is s.xy


def test_pose_target_returns_the_target_and_the_speed_it_implies():
    here = state([[0.0, 0.0], [5.0, 5.0]], [0.0, np.pi / 2], [3.0, 3.0])
    target_xy, target_yaw = np.array([[1.0, 0.0], [5.0, 4.5]]), np.array([0.0, np.pi / 2])
    nxt = PoseTarget(dt=0.1).step(here, (target_xy, target_yaw))
    assert nxt.xy is target_xy and nxt.yaw is target_yaw
    np.testing.assert_allclose(nxt.speed, [10.0, -5.0])  # the second one backs up


# Inputs and outputs of feasible_step before it became Unicycle: the values must not move.
XY = np.array([[0.0, 0.0], [10.0, -2.0], [3.0, 4.0], [-1.0, 0.5]])
YAW = np.array([0.0, 1.0, -2.5, 3.0])
SPEED = np.array([10.0, 5.0, 0.0, 12.0])
TARGET = (np.array([[1.2, 0.1], [10.3, -1.4], [2.9, 4.2], [-2.3, 0.7]]), np.array([0.05, 1.3, -2.4, -3.1]))
PINNED = {
    KinematicLimits(): (
        [[1.0146828290198382, 0.025372356853432927], [10.256249089664239, -1.5532770388190813], [3.0, 4.0],
         [-2.2099071143149596, 0.6111295403124112]],
        [0.04999999999999982, 1.0999999999999996, -2.5, 3.0999999999999996],
        [10.3, 5.3, 0.0, 12.3]),
    KinematicLimits(allow_reverse=True, dt=0.2): (
        [[1.8394250299472927, 0.045995208483070524], [10.39294928825476, -1.257577709884679],
         [3.0202025533827412, 4.0151714332995], [-3.237200583284724, 0.6119533391663193]],
        [0.04999999999999982, 1.1680000000000001, -2.494947018497783, -3.0999999999999996],
        [8.4, 3.4, -0.25264907511085016, 10.4]),
}


@pytest.mark.parametrize("limits", list(PINNED), ids=["default", "reverse_dt0.2"])
def test_unicycle_is_bit_identical_to_the_former_feasible_step(limits):
    nxt = Unicycle(limits).step(state(XY, YAW, SPEED), TARGET)
    xy, yaw, speed = PINNED[limits]
    np.testing.assert_array_equal(nxt.xy, xy)
    np.testing.assert_array_equal(nxt.yaw, yaw)
    np.testing.assert_array_equal(nxt.speed, speed)


def test_unicycle_respects_limits():
    lim = KinematicLimits()
    here = state(np.zeros((3, 2)), np.zeros(3), [10.0, 10.0, 0.0])
    target = np.array([[5.0, 0.0], [0.9, 0.5], [0.0, 3.0]])  # too fast, too sharp, sideways from standstill
    nxt = Unicycle(lim).step(here, (target, np.array([0.0, 1.0, 1.5])))
    nxy, nyaw, v = nxt.xy, nxt.yaw, nxt.speed
    assert v[0] == pytest.approx(10.0 + lim.max_accel * lim.dt)
    assert abs(nyaw[1]) <= lim.max_yaw_rate * lim.dt + 1e-12
    # From standstill: no sliding sideways, and only as much turn as the short arc allows.
    assert abs(nyaw[2]) <= lim.max_curvature * 0.5 * v[2] * lim.dt + 1e-12
    assert abs(nxy[2, 1]) < 1e-3 and nxy[2, 0] <= 0.5 * lim.max_accel * lim.dt ** 2 + 1e-12
    same = Unicycle(lim).step(here.take(slice(0, 1)), (np.array([[1.0, 0.0]]), np.zeros(1)))
    assert np.allclose(same.xy, [[1.0, 0.0]])
    assert Unicycle(lim).dt == lim.dt


def test_bicycle_without_steering_drives_straight_at_v_dt():
    bike = KinematicBicycle(dt=0.1)
    nxt = bike.step(state([1.0, 2.0], 0.3, 5.0), (0.0, 0.0))
    np.testing.assert_allclose(nxt.xy, [1.0 + 0.5 * np.cos(0.3), 2.0 + 0.5 * np.sin(0.3)], rtol=0, atol=1e-12)
    assert nxt.yaw == pytest.approx(0.3, abs=1e-15) and nxt.speed == 5.0


@pytest.mark.parametrize("steer", [0.2, -0.45])
def test_bicycle_with_constant_steering_follows_its_circle(steer):
    bike = KinematicBicycle(wheelbase=2.5, dt=0.01)
    radius = 2.5 / np.tan(steer)  # signed: negative turns right
    s = state([0.0, 0.0], 0.0, 8.0)
    points = []
    for _ in range(1000):  # 80 m: more than a full turn of either circle
        s = bike.step(s, (0.0, steer))
        points.append(s.xy)
    points = np.array(points)
    centre = np.array([0.0, radius])
    np.testing.assert_allclose(np.hypot(*(points - centre).T), abs(radius), rtol=0, atol=1e-9)
    # And it got as far round the circle as it drove.
    heading = 80.0 / radius
    np.testing.assert_allclose(points[-1], [radius * np.sin(heading), radius * (1 - np.cos(heading))], atol=1e-9)
    assert np.cos(s.yaw - heading) == pytest.approx(1.0, abs=1e-12)


def test_bicycle_clips_acceleration_steering_and_speed():
    bike = KinematicBicycle(dt=0.1, max_accel=3.0, max_decel=8.0, max_steer=0.5, max_speed=40.0)
    here = state(np.zeros((4, 2)), np.zeros(4), [10.0, 10.0, 39.9, 0.2])
    nxt = bike.step(here, (np.array([100.0, -100.0, 3.0, -3.0]), 0.0))
    np.testing.assert_allclose(nxt.speed, [10.3, 9.2, 40.0, 0.0])  # no reverse by default
    steered = bike.step(state([0.0, 0.0], 0.0, 10.0), (0.0, 10.0))
    at_bound = bike.step(state([0.0, 0.0], 0.0, 10.0), (0.0, 0.5))
    np.testing.assert_array_equal(steered.xy, at_bound.xy)
    assert steered.yaw == at_bound.yaw == pytest.approx(10.0 * 0.1 * np.tan(0.5) / bike.wheelbase)
    backing = KinematicBicycle(allow_reverse=True).step(state([0.0, 0.0], 0.0, 0.0), (-3.0, 0.0))
    assert backing.speed == pytest.approx(-0.3) and backing.xy[0] == pytest.approx(-0.015)


def test_bicycle_broadcasts_batched_states_and_actions():
    rng = np.random.default_rng(0)
    here = state(rng.normal(size=(3, 4, 2)), rng.normal(size=(3, 4)), rng.uniform(0, 20, size=(3, 4)))
    accel, steer = rng.normal(size=4), 0.1  # one action per agent column, one steering for all
    bike = KinematicBicycle()
    nxt = bike.step(here, (accel, steer))
    assert nxt.xy.shape == (3, 4, 2) and nxt.yaw.shape == nxt.speed.shape == (3, 4)
    one = bike.step(here.take(2).take(1), (accel[1], steer))
    np.testing.assert_allclose(nxt.xy[2, 1], one.xy, rtol=1e-12)
    np.testing.assert_allclose(nxt.speed[2, 1], one.speed, rtol=1e-12)
