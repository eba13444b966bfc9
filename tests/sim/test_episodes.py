"""The episode engine: seeded, batch-independent, ends episodes on goal, collision, off-road and step limit."""
from __future__ import annotations

import numpy as np
import pytest

from pytest_driveeval.metrics.episode_outcomes import (
    COLLISION,
    GOAL,
    OFF_ROAD,
    RUNNING,
    STEP_LIMIT,
)
from pytest_driveeval.sim.blueprints import make_blueprint
from pytest_driveeval.sim.episodes import reset

NAMES = ["highway", "merging", "intersection"]


def random_actions(seeds, steps):
    """Each episode's actions from its own seed, so they do not depend on the batch either."""
    return np.stack([np.random.default_rng(1000 + int(s)).uniform([-5, -0.05], [4, 0.05], (steps, 2))
                     for s in seeds], axis=1)  # (steps, E, 2)


def trajectory(name, seeds, steps=60):
    episodes = reset(name, seeds, 12)
    actions = random_actions(seeds, steps)
    frames = []
    for t in range(steps):
        result = episodes.step(actions[t])
        frames.append((episodes.xy.copy(), episodes.yaw.copy(), episodes.speed.copy(), episodes.valid.copy(),
                       result.reward, episodes.outcome.copy()))
    return frames


@pytest.mark.parametrize("name", NAMES)
def test_an_episode_depends_on_its_seed_only(name):
    alone = trajectory(name, [9])
    mixed = trajectory(name, [13, 77, 9, 5, 1])
    again = trajectory(name, [13, 77, 9, 5, 1])
    for a, m, g in zip(alone, mixed, again):
        for x, y, z in zip(a, m, g):
            np.testing.assert_array_equal(x[0], y[2])  # bit for bit, whatever shares the batch
            np.testing.assert_array_equal(y, z)
    assert not np.array_equal(mixed[-1][0][0], mixed[-1][0][2]), "different seeds, different episodes"


def test_observation_arrays_for_the_graph_observer():
    episodes = reset("merging", np.arange(5), agent_limit=12)
    e, a = 5, 12
    assert episodes.xy.shape == (e, a, 2) and episodes.yaw.shape == episodes.speed.shape == (e, a)
    assert episodes.valid.dtype == bool and episodes.valid[:, 0].all() and not episodes.valid.all()
    assert episodes.goal_centre.shape == (e, 2) and episodes.goal_heading.shape == episodes.goal_speed.shape == (e,)
    np.testing.assert_allclose(episodes.goal_speed, 10.0)  # the middle of merging's 5-15 m/s
    xmin, ymin, xmax, ymax = episodes.map_bounds
    xy = episodes.xy[episodes.valid]
    assert np.all((xy[:, 0] >= xmin) & (xy[:, 0] <= xmax) & (xy[:, 1] >= ymin) & (xy[:, 1] <= ymax))
    np.testing.assert_array_equal(episodes.size, [4.5, 1.8])


def test_agent_limit_of_one_is_the_ego_alone():
    episodes = reset("highway", [0, 1], agent_limit=1)
    assert episodes.xy.shape == (2, 1, 2)
    for _ in range(5):
        episodes.step(np.zeros((2, 2)))
    assert (episodes.outcome == RUNNING).all()


WHEELBASE = 2.7
LANE = 3.5


def gap_seeking_lane_change(episodes):
    """Move to the goal lane beside a free stretch of it, dropping back behind whoever is in the way; keep
    1.5 s behind anything ahead; hold the goal's speed.  Straight highway along +x, so y is the lateral."""
    ego_xy, v = episodes.xy[:, 0], np.maximum(episodes.speed[:, 0], 1.0)
    rel = episodes.xy[:, 1:] - ego_xy[:, None]
    others = episodes.valid[:, 1:]
    goal_y = episodes.goal_centre[:, 1]
    beside = others & (np.abs(episodes.xy[:, 1:, 1] - goal_y[:, None]) < 1.0) & (np.abs(rel[..., 0]) < 12.0)
    blocked = beside.any(axis=1)
    target_y = np.where(blocked, np.round(ego_xy[:, 1] / LANE) * LANE, goal_y)
    lateral = 0.5 * (target_y - ego_xy[:, 1]) - 1.4 * v * np.sin(episodes.yaw[:, 0])
    steer = np.arctan(lateral * WHEELBASE / v ** 2)
    ahead = others & (rel[..., 0] > 0) & (np.abs(rel[..., 1]) < 2.5)
    gap = np.where(ahead, rel[..., 0] - 4.5, np.inf).min(axis=1)
    slowest = np.where(beside, episodes.speed[:, 1:], np.inf).min(axis=1)
    want = np.where(blocked, slowest - 3.0, episodes.goal_speed)
    accel = np.minimum(want - v, 2.0 * (gap - 2.0 - 1.5 * v) / 1.5)
    return np.stack([accel, steer], axis=1)


def test_a_scripted_lane_change_reaches_the_highway_goal():
    episodes = reset("highway", np.arange(32), 12)
    total = np.zeros(32)
    for _ in range(200):
        total += episodes.step(gap_seeking_lane_change(episodes)).reward
        if episodes.done.all():
            break
    assert (episodes.outcome == GOAL).all()
    np.testing.assert_allclose(total, 1.0 + 0.01 * (episodes.steps - 1))
    np.testing.assert_allclose(episodes.returns, total)
    lanes = np.round(episodes.xy[:, 0, 1] / LANE)
    assert set(lanes.tolist()) == {0.0, 2.0}, "both sides were asked for"


def test_full_throttle_into_the_car_ahead_is_a_collision_and_freezes_the_episode():
    episodes = reset("highway", [4], 12)
    ahead = episodes.valid[0, 1:] & (np.abs(episodes.xy[0, 1:, 1] - episodes.xy[0, 0, 1]) < 0.1) & (
        episodes.xy[0, 1:, 0] > episodes.xy[0, 0, 0])
    assert ahead.any(), "seed 4 has a vehicle ahead on the ego's lane"
    rewards = []
    for _ in range(100):
        result = episodes.step(np.array([[4.0, 0.0]]))
        rewards.append(result.reward[0])
        if result.done[0]:
            break
    assert result.collision[0] and episodes.outcome[0] == COLLISION and rewards[-1] == -1.0
    assert rewards[:-1] == [0.01] * (len(rewards) - 1)
    frozen = (episodes.xy.copy(), episodes.steps.copy(), episodes.returns.copy())
    later = episodes.step(np.array([[4.0, 0.5]]))
    assert later.reward[0] == 0.0 and later.done[0] and not later.collision[0]
    np.testing.assert_array_equal(episodes.xy, frozen[0])
    assert episodes.steps[0] == frozen[1][0] and episodes.returns[0] == frozen[2][0]


def test_steering_off_the_road_ends_the_episode():
    episodes = reset("highway", [0, 1], agent_limit=1)  # no traffic to hit on the way
    lowest = []  # y of the box's lowest corner after each step
    for _ in range(50):
        result = episodes.step(np.array([[-2.0, -0.2], [0.0, 0.0]]))
        yaw = episodes.yaw[0, 0]
        lowest.append(episodes.xy[0, 0, 1] - 2.25 * abs(np.sin(yaw)) - 0.9 * np.cos(yaw))
        if result.done[0]:
            break
    assert result.off_road[0] and episodes.outcome[0] == OFF_ROAD and result.reward[0] == -1.0
    assert lowest[-1] < -1.75 <= lowest[-2] + 0.1, "it ended as a corner crossed the right edge, no earlier"
    assert episodes.outcome[1] == RUNNING


def test_the_step_limit_ends_an_episode_without_penalty():
    episodes = reset(make_blueprint("intersection", max_steps=5), [0, 1, 2], 12)
    for t in range(5):
        result = episodes.step(np.tile([[-5.0, 0.0]], (3, 1)))  # brake where the ego starts: nothing happens
        assert result.done.all() == (t == 4)
    assert result.step_limit.all() and (episodes.outcome == STEP_LIMIT).all()
    np.testing.assert_allclose(episodes.returns, 0.05)


def test_actions_are_clipped_to_the_bounds():
    bounded, wild = reset("merging", [3], 12), reset("merging", [3], 12)
    for _ in range(5):
        bounded.step(np.array([[4.0, 0.2]]))
        wild.step(np.array([[50.0, 3.0]]))
    np.testing.assert_array_equal(bounded.xy, wild.xy)
    np.testing.assert_array_equal(bounded.yaw, wild.yaw)


def test_bad_inputs_are_refused():
    episodes = reset("highway", [0, 1], 12)
    with pytest.raises(ValueError, match=r"\(2, 2\)"):
        episodes.step(np.zeros((3, 2)))
    with pytest.raises(ValueError, match=r"episodes \[1\]"):
        episodes.step(np.array([[0.0, 0.0], [np.nan, 0.0]]))
    for seeds in ([], [-1], [0.5], [[1, 2]]):
        with pytest.raises(ValueError, match="seeds"):
            reset("highway", seeds)
    with pytest.raises(ValueError, match="agent_limit"):
        reset("highway", [0], agent_limit=0)
