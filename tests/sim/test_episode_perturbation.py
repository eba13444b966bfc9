"""Per-episode start perturbations: exact when unchanged, batch-independent, and spawns that stay valid."""
from __future__ import annotations

import numpy as np
import pytest

from pytest_driveeval.metrics.episode_outcomes import ego_collides, traffic_overlaps
from pytest_driveeval.sim.blueprints import make_blueprint
from pytest_driveeval.sim.episodes import NO_PERTURBATION, PERTURBATION_COLUMNS, reset

NAMES = ["highway", "merging", "intersection"]
COLUMN = {name: i for i, name in enumerate(PERTURBATION_COLUMNS)}


def row(**changes) -> np.ndarray:
    out = NO_PERTURBATION.copy()
    for name, value in changes.items():
        out[COLUMN[name]] = value
    return out


def rows_for(seeds, rng_seed=0) -> np.ndarray:
    """A different perturbation per episode, every column changed."""
    rng = np.random.default_rng(rng_seed)
    n = len(seeds)
    return np.stack([rng.uniform(-0.6, 0.6, n), rng.uniform(-1.5, 1.5, n), rng.uniform(-0.05, 0.05, n),
                     rng.uniform(0.7, 1.3, n), rng.uniform(0.7, 1.3, n), rng.uniform(0.5, 1.8, n)], axis=1)


def trajectory(name, seeds, perturbation, steps=50):
    episodes = reset(name, seeds, 12, perturbation=perturbation)
    actions = [np.stack([np.random.default_rng([int(s), t]).uniform([-3, -0.03], [3, 0.03]) for s in seeds])
               for t in range(steps)]
    frames = [(episodes.xy.copy(), episodes.yaw.copy(), episodes.speed.copy(), episodes.valid.copy())]
    for t in range(steps):
        result = episodes.step(actions[t])
        frames.append((episodes.xy.copy(), episodes.yaw.copy(), episodes.speed.copy(), episodes.valid.copy(),
                       result.reward, episodes.outcome.copy()))
    return frames


@pytest.mark.parametrize("name", NAMES)
def test_a_no_change_row_is_the_unperturbed_episode_bit_for_bit(name):
    seeds = np.arange(12)
    plain = trajectory(name, seeds, None)
    unchanged = trajectory(name, seeds, np.tile(NO_PERTURBATION, (len(seeds), 1)))
    for a, b in zip(plain, unchanged):
        for x, y in zip(a, b):
            np.testing.assert_array_equal(x, y)


@pytest.mark.parametrize("name", NAMES)
def test_a_perturbed_episode_depends_on_its_seed_and_row_only(name):
    seeds = np.array([13, 77, 9, 5, 1])
    rows = rows_for(seeds)
    mixed = trajectory(name, seeds, rows)
    alone = trajectory(name, seeds[2:3], rows[2:3])
    # The same seed under another row beside it must not matter either.
    other = trajectory(name, np.array([9, 9]), np.stack([rows[0], rows[2]]))
    for a, m, o in zip(alone, mixed, other):
        for x, y, z in zip(a, m, o):
            np.testing.assert_array_equal(x[0], y[2])
            np.testing.assert_array_equal(x[0], z[1])
    plain = trajectory(name, seeds[2:3], None)
    assert not np.array_equal(plain[-1][0], alone[-1][0]), "the perturbation changed the episode"


def test_the_ego_moves_in_its_own_frame_and_speeds_scale():
    seeds = np.arange(6)
    base = reset("intersection", seeds)  # the ego heads north (+y): its left is -x
    moved = reset("intersection", seeds, perturbation=np.tile(
        row(lateral=0.4, longitudinal=-2.0, heading=0.1, speed_scale=0.5, agents_speed_scale=1.2), (6, 1)))
    np.testing.assert_allclose(base.yaw[:, 0], np.pi / 2)
    np.testing.assert_allclose(moved.xy[:, 0] - base.xy[:, 0], np.tile([-0.4, -2.0], (6, 1)), atol=1e-12)
    np.testing.assert_allclose(moved.yaw[:, 0], base.yaw[:, 0] + 0.1)
    np.testing.assert_allclose(moved.speed[:, 0], 0.5 * base.speed[:, 0])
    traffic = base.valid[:, 1:]
    np.testing.assert_allclose(moved.speed[:, 1:][traffic], 1.2 * base.speed[:, 1:][traffic])
    np.testing.assert_allclose(moved.traffic.desired_speed[:, 1:][traffic],
                               1.2 * base.traffic.desired_speed[:, 1:][traffic])
    np.testing.assert_array_equal(moved.goal_centre, base.goal_centre)


def test_agents_keep_their_scaled_speed_rather_than_drifting_back():
    seeds = np.arange(8)
    slow = reset("highway", seeds, perturbation=np.tile(row(agents_speed_scale=0.6), (8, 1)))
    base = reset("highway", seeds)
    for _ in range(50):
        slow.step(np.zeros((8, 2)))
        base.step(np.zeros((8, 2)))
    both = slow.valid[:, 1:] & base.valid[:, 1:]
    assert slow.speed[:, 1:][both].mean() < 0.75 * base.speed[:, 1:][both].mean()


def spacing(episodes, lane_y):
    """Gaps between consecutive valid vehicles on the highway lane at ``lane_y``."""
    out = []
    for e in range(episodes.num_episodes):
        on = episodes.valid[e, 1:] & (np.abs(episodes.xy[e, 1:, 1] - lane_y) < 0.1)
        out.extend(np.diff(np.sort(episodes.xy[e, 1:, 0][on])))
    return np.array(out)


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("scale", [0.05, 0.3, 0.6, 2.5])
def test_scaled_gaps_keep_spawns_valid(name, scale):
    seeds = np.arange(16)
    episodes = reset(name, seeds, 24, perturbation=np.tile(row(gap_scale=scale), (16, 1)))
    assert not traffic_overlaps(episodes.xy, episodes.yaw, episodes.size, episodes.valid).any()
    assert not ego_collides(episodes.xy, episodes.yaw, episodes.size, episodes.valid).any()
    base = reset(name, seeds, 24)
    # Only the traffic's placement moves: the ego's start and goal are the same draws.
    np.testing.assert_array_equal(episodes.xy[:, 0], base.xy[:, 0])
    np.testing.assert_array_equal(episodes.goal_centre, base.goal_centre)


def test_denser_traffic_is_closer_together_and_sparser_further_apart():
    seeds = np.arange(16)
    params = make_blueprint("highway").params
    base = reset("highway", seeds, 40)
    dense = reset("highway", seeds, 40, perturbation=np.tile(row(gap_scale=0.5), (16, 1)))
    sparse = reset("highway", seeds, 40, perturbation=np.tile(row(gap_scale=2.0), (16, 1)))
    gaps = {k: spacing(e, 0.0) for k, e in (("base", base), ("dense", dense), ("sparse", sparse))}
    assert gaps["base"].min() >= params.gap[0] - 1e-9
    np.testing.assert_allclose(np.median(gaps["dense"]) / np.median(gaps["base"]), 0.5, rtol=0.2)
    np.testing.assert_allclose(np.median(gaps["sparse"]) / np.median(gaps["base"]), 2.0, rtol=0.2)
    assert gaps["dense"].min() >= params.vehicle_length


def test_a_vehicle_the_moved_ego_would_start_inside_is_left_out():
    base = reset("highway", [4])
    same_lane = base.valid[0, 1:] & (np.abs(base.xy[0, 1:, 1] - base.xy[0, 0, 1]) < 0.1)
    ahead = np.where(same_lane & (base.xy[0, 1:, 0] > base.xy[0, 0, 0]), base.xy[0, 1:, 0], np.inf)
    nearest = int(np.argmin(ahead))
    shifted = reset("highway", [4], perturbation=row(longitudinal=ahead[nearest] - base.xy[0, 0, 0])[None])
    assert not shifted.valid[0, 1 + nearest] and base.valid[0, 1 + nearest]
    assert not ego_collides(shifted.xy, shifted.yaw, shifted.size, shifted.valid).any()
    assert shifted.valid.sum() == base.valid.sum() - 1


@pytest.mark.parametrize("rows, message", [
    (np.zeros((2, 5)), "perturbation must be (2, 6) rows of (lateral, longitudinal"),
    (np.tile(row(gap_scale=0.0), (2, 1)), "perturbation row 0"),
    (np.stack([NO_PERTURBATION, row(speed_scale=np.nan)]), "perturbation row 1"),
    (np.stack([NO_PERTURBATION, row(agents_speed_scale=-1.0)]), "speed scales >= 0"),
])
def test_bad_perturbation_rows_are_refused(rows, message):
    with pytest.raises(ValueError) as error:
        reset("merging", [0, 1], perturbation=rows)
    assert message in str(error.value)
