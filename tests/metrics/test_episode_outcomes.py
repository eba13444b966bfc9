"""Episode outcomes of the policy benchmark, each from constructed arrays."""
from __future__ import annotations

import numpy as np
import pytest

from pytest_driveeval.metrics.episode_outcomes import (
    COLLISION,
    GOAL,
    OFF_ROAD,
    RUNNING,
    STEP_LIMIT,
    cells_contain,
    classify,
    ego_collides,
    in_goal,
    off_road,
    step_reward,
    traffic_overlaps,
)

# a fast reader / score / report check: CI runs these at the lowest declared versions (-m smoke)
pytestmark = pytest.mark.smoke

SIZE = np.array([4.5, 1.8])


def test_goal_needs_position_heading_and_speed_within_bounds():
    # Goal: centred (100, 0), heading pi/2 (north), 40 m long, 2 m wide, +-0.15 rad, 5-15 m/s.
    xy = np.array([[100.0, 19.9], [100.0, 20.1], [100.99, 0.0], [101.01, 0.0],
                   [100.0, 0.0], [100.0, 0.0], [100.0, 0.0], [100.0, 0.0], [100.0, 0.0]])
    yaw = np.array([np.pi / 2] * 4 + [np.pi / 2 + 0.15, np.pi / 2 - 0.16, np.pi / 2, np.pi / 2, np.pi / 2])
    speed = np.array([10.0] * 6 + [5.0, 15.0, 15.01])
    n = len(xy)
    got = in_goal(xy, yaw, speed, np.tile([100.0, 0.0], (n, 1)), np.full(n, np.pi / 2), [40.0, 2.0],
                  np.full(n, 0.15), [5.0, 15.0])
    assert got.tolist() == [True, False, True, False, True, False, True, True, False]


def test_goal_heading_wraps_around_pi():
    got = in_goal(np.zeros((2, 2)), np.array([-np.pi + 0.05, np.pi - 0.3]), np.full(2, 10.0), np.zeros((2, 2)),
                  np.full(2, np.pi - 0.05), [10.0, 2.0], 0.15, [0.0, 20.0])
    assert got.tolist() == [True, False]


def test_ego_collisions_count_valid_agents_only_and_touching_counts():
    # Episode 0: an agent 4.5 m ahead, bumpers touching; 1: overlapping but invalid; 2: rotated, just clear.
    xy = np.array([[[0.0, 0.0], [4.5, 0.0]], [[0.0, 0.0], [2.0, 0.5]], [[0.0, 0.0], [0.0, 1.8 / 2 + 2.25 + 0.01]]])
    yaw = np.array([[0.0, 0.0], [0.0, 0.3], [0.0, np.pi / 2]])
    valid = np.array([[True, True], [True, False], [True, True]])
    assert ego_collides(xy, yaw, SIZE, valid).tolist() == [True, False, False]
    valid[1, 1] = True
    assert ego_collides(xy, yaw, SIZE, valid).tolist() == [True, True, False]


def test_traffic_overlaps_count_pairs_without_the_ego():
    xy = np.array([[[0.0, 0.0], [0.0, 0.0], [20.0, 0.0], [22.0, 0.0], [23.0, 0.5]]])
    yaw = np.zeros((1, 5))
    valid = np.ones((1, 5), bool)
    assert traffic_overlaps(xy, yaw, SIZE, valid).tolist() == [3]  # (2, 3), (2, 4), (3, 4); ego-1 not counted
    valid[0, 4] = False
    assert traffic_overlaps(xy, yaw, SIZE, valid).tolist() == [1]


def test_off_road_is_any_corner_outside_the_raster():
    mask = np.zeros((100, 20), bool)  # 10 m x 2 m at 0.1 m from (0, 0)
    mask[:, 5:15] = True  # drivable: 0.5 <= y < 1.5
    origin = np.zeros(2)
    assert cells_contain(np.array([[5.0, 1.0], [5.0, 0.45], [-0.01, 1.0], [10.01, 1.0]]), mask, origin,
                         0.1).tolist() == [True, False, False, False]
    box = np.array([[1.0, 0.6], [2.0, 0.6], [2.0, 1.4], [1.0, 1.4]])
    corners = np.stack([box, box + [0.0, 0.2], box + [8.5, 0.0]])
    assert off_road(corners, mask, origin, 0.1).tolist() == [False, True, True]


def test_outcomes_take_precedence_in_order():
    goal = np.array([1, 1, 1, 0, 0, 0], bool)
    collision = np.array([1, 0, 0, 0, 0, 0], bool)
    left = np.array([1, 1, 0, 0, 1, 0], bool)
    limit = np.array([1, 1, 1, 1, 0, 0], bool)
    outcome = classify(goal, collision, left, limit)
    assert outcome.tolist() == [COLLISION, OFF_ROAD, GOAL, STEP_LIMIT, OFF_ROAD, RUNNING]
    assert outcome.dtype == np.int8


def test_the_seed_reward():
    outcome = np.array([GOAL, COLLISION, OFF_ROAD, STEP_LIMIT, RUNNING, GOAL])
    active = np.array([True] * 5 + [False])
    assert step_reward(outcome, active).tolist() == [1.0, -1.0, -1.0, 0.01, 0.01, 0.0]
    assert step_reward(outcome, active, step=0.0, crash=-2.0).tolist() == [1.0, -2.0, -2.0, 0.0, 0.0, 0.0]


def test_nan_poses_are_never_in_the_goal():
    assert not in_goal(np.array([[np.nan, 0.0]]), np.zeros(1), np.full(1, 10.0), np.zeros((1, 2)), np.zeros(1),
                       [10.0, 2.0], 0.1, [0.0, 20.0]).any()
