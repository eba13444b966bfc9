"""Collision kinds against an l5kit-style shapely oracle; blame rules; drift."""
from __future__ import annotations

import importlib.util

import numpy as np
import pytest

from pytest_driveeval.metrics.collisions import (
    FRONT,
    NONE,
    REAR,
    SIDE,
    count_collisions,
    detect_collisions,
)
from pytest_driveeval.metrics.drift import (
    displacement_error,
    distance_to_reference,
    distance_to_reference_l5kit,
    driven_distance,
    speed_difference,
    speed_from_positions,
    yaw_error,
)

from conftest import REPO_ROOT

# a fast reader / score / report check: CI runs these at the lowest declared versions (-m smoke)
pytestmark = pytest.mark.smoke

EGO = np.array([4.0, 2.0])


@pytest.fixture(scope="module")
def bench():
    pytest.importorskip("shapely")
    path = REPO_ROOT / "benchmarks" / "bench_metrics.py"
    spec = importlib.util.spec_from_file_location("bench_metrics", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize("seed", range(3))
def test_kind_and_partner_match_l5kit_reference(bench, seed):
    d = bench.synthetic_scenes(2, seed=seed, near_sigma=4.0)
    res = detect_collisions(d["ego_xy"], d["ego_yaw"], bench.EGO_EXTENT, d["agent_xy"], d["agent_yaw"],
                            d["agent_extent"], d["available"])
    assert res.kind.shape == (2, bench.FRAMES)
    for s in range(2):
        for f in range(bench.FRAMES):
            kind, idx = bench.l5kit_style_collision(
                d["ego_xy"][s, f], d["ego_yaw"][s, f], bench.EGO_EXTENT, d["agent_xy"][s, f], d["agent_yaw"][s, f],
                d["agent_extent"][s, f], d["available"][s, f])
            assert (res.kind[s, f], res.agent_index[s, f]) == (kind, idx), (s, f)
    assert set(np.unique(res.kind)) == {NONE, FRONT, SIDE, REAR}


def _one(ego_xy, ego_yaw, agent_xy, agent_yaw, ego_velocity=None, agent_velocity=None, **kw):
    """A single frame with one agent of the ego's size."""
    return detect_collisions(
        np.array(ego_xy, float), np.array(ego_yaw, float), EGO, np.array([agent_xy], float),
        np.array([agent_yaw], float), EGO[None],
        ego_velocity=None if ego_velocity is None else np.array(ego_velocity, float),
        agent_velocity=None if agent_velocity is None else np.array([agent_velocity], float), **kw)


def test_rear_ender_into_stopped_ego_is_not_at_fault():
    r = _one([0, 0], 0.0, [-3.5, 0.1], 0.0, ego_velocity=[0, 0], agent_velocity=[5, 0])
    assert r.kind == REAR and not r.at_fault
    # Not even when the ego is still rolling forward, slower than the agent.
    r = _one([0, 0], 0.0, [-3.5, 0.1], 0.0, ego_velocity=[2, 0], agent_velocity=[6, 0])
    assert r.kind == REAR and not r.at_fault


def test_reversing_into_agent_behind_is_at_fault():
    r = _one([0, 0], 0.0, [-3.5, 0.1], 0.0, ego_velocity=[-2, 0], agent_velocity=[0, 0])
    assert r.kind == REAR and r.at_fault


def test_ego_into_stopped_car_ahead_is_front_at_fault():
    r = _one([0, 0], np.pi / 2, [0.1, 3.6], np.pi / 2, ego_velocity=[0, 8], agent_velocity=[0, 0])
    assert r.kind == FRONT and r.at_fault and r.agent_index == 0 and r.track_id == 0
    # Heading given as a signed speed (l5kit's ego state) gives the same answer.
    r = _one([0, 0], np.pi / 2, [0.1, 3.6], np.pi / 2, ego_speed=8.0, agent_velocity=[0, 0])
    assert r.kind == FRONT and r.at_fault
    # An agent reversing into a stopped ego's nose is excused.
    r = _one([0, 0], 0.0, [3.6, 0.1], 0.0, ego_velocity=[0, 0], agent_velocity=[-3, 0])
    assert r.kind == FRONT and not r.at_fault


def test_side_blame_follows_who_moves_sideways():
    # Agent alongside on the left, overlapping by 0.2 m, both driving at 10 m/s.
    ego_cuts_in = _one([0, 0], 0.0, [0.5, 1.8], 0.0, ego_velocity=[10, 1.0], agent_velocity=[10, 0])
    agent_cuts_in = _one([0, 0], 0.0, [0.5, 1.8], 0.0, ego_velocity=[10, 0], agent_velocity=[10, -1.0])
    assert ego_cuts_in.kind == SIDE and agent_cuts_in.kind == SIDE
    assert ego_cuts_in.at_fault and not agent_cuts_in.at_fault


def test_without_velocities_blame_falls_back_on_kind():
    assert _one([0, 0], 0.0, [3.6, 0.1], 0.0).at_fault  # front
    assert _one([0, 0], 0.0, [0.5, 1.8], 0.0).at_fault  # side
    assert not _one([0, 0], 0.0, [-3.6, 0.1], 0.0).at_fault  # rear


def test_partner_is_lowest_available_index_and_track_id():
    agents = np.array([[30.0, 0], [3.6, 0.2], [-3.6, 0.0], [0.5, 1.8]])
    kw = dict(agent_yaw=np.zeros(4), agent_extent=np.tile(EGO, (4, 1)), track_ids=np.array([7, 8, 9, 10]))
    r = detect_collisions(np.zeros(2), 0.0, EGO, agents, **kw)
    assert (r.kind, r.agent_index, r.track_id) == (FRONT, 1, 8)
    assert r.overlap.tolist() == [False, True, True, True]
    avail = np.array([True, False, True, True])
    r = detect_collisions(np.zeros(2), 0.0, EGO, agents, agent_available=avail, **kw)
    assert (r.kind, r.agent_index, r.track_id) == (REAR, 2, 9)


def test_partner_is_first_overlapping_row_when_rows_are_not_in_index_order():
    # Index order: a front hit (track 4) before a rear hit (track 9); the
    # frame's rows list track 9 first, so l5kit's first overlapping agent is 9.
    agents = np.array([[3.6, 0.1], [-3.6, 0.0], [30.0, 0.0]])
    kw = {"agent_yaw": np.zeros(3), "agent_extent": np.tile(EGO, (3, 1)), "track_ids": np.array([4, 9, 2])}
    by_index = detect_collisions(np.zeros(2), 0.0, EGO, agents, **kw)
    assert (by_index.kind, by_index.track_id) == (FRONT, 4)
    by_row = detect_collisions(np.zeros(2), 0.0, EGO, agents, agent_order=np.array([1, 0, 2]), **kw)
    assert (by_row.kind, by_row.agent_index, by_row.track_id) == (REAR, 1, 9)
    assert by_row.overlap.tolist() == by_index.overlap.tolist() == [True, True, False]
    # Batched: each frame follows its own row order.
    frames = detect_collisions(np.zeros((2, 2)), np.zeros(2), EGO, np.stack([agents, agents]),
                               agent_order=np.array([[1, 0, 2], [0, 2, 1]]), **{**kw, "agent_yaw": np.zeros((2, 3))})
    assert frames.track_id.tolist() == [9, 4] and frames.kind.tolist() == [REAR, FRONT]


def test_shapes_batching_and_counts():
    rng = np.random.default_rng(5)
    s, t, a = 3, 7, 5
    ego = rng.normal(0, 1, (s, t, 2))
    agents = ego[:, :, None] + rng.normal(0, 4, (s, t, a, 2))
    yaws = rng.uniform(-3, 3, (s, t, a))
    full = detect_collisions(ego, np.zeros((s, t)), EGO, agents, yaws, EGO)
    assert full.kind.shape == full.at_fault.shape == full.track_id.shape == (s, t)
    assert full.overlap.shape == (s, t, a)
    # Per-scene, single-frame layout (S,) gives the same per-frame answers.
    single = detect_collisions(ego[:, 2], np.zeros(s), EGO, agents[:, 2], yaws[:, 2], EGO)
    np.testing.assert_array_equal(single.kind, full.kind[:, 2])
    counts = count_collisions(full)
    assert sum(counts.values()) == int((full.kind != NONE).sum())
    assert set(counts) == {"front", "side", "rear"}
    assert sum(count_collisions(full, at_fault_only=True).values()) == int(full.at_fault.sum())
    # No agents at all.
    empty = detect_collisions(ego, np.zeros((s, t)), EGO, np.zeros((s, t, 0, 2)), np.zeros((s, t, 0)),
                              np.zeros((s, t, 0, 2)))
    assert (empty.kind == NONE).all() and (empty.agent_index == -1).all()


def test_nan_padding_is_ignored():
    agents = np.array([[np.nan, np.nan], [3.6, 0.2]])
    ext = np.array([[np.nan, np.nan], [4.0, 2.0]])
    r = detect_collisions(np.zeros(2), 0.0, EGO, agents, np.array([np.nan, 0.0]), ext,
                          agent_available=np.array([False, True]))
    assert (r.kind, r.agent_index) == (FRONT, 1)


# ---- drift -----------------------------------------------------------------

def test_displacement_and_yaw_error_by_hand():
    driven = np.array([[0.0, 0.0], [3.0, 4.0]])
    logged = np.array([[0.0, 0.0], [0.0, 0.0]])
    np.testing.assert_allclose(displacement_error(driven, logged), [0.0, 5.0])
    np.testing.assert_allclose(yaw_error(np.array([0.1, np.pi - 0.1]), np.array([-0.1, -np.pi + 0.1])),
                               [0.2, 0.2], atol=1e-12)


def test_distance_to_reference_uses_segments():
    ref = np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 10.0]]) + 1000.0  # world-sized coordinates
    driven = np.array([[5.0, 2.0], [12.0, 5.0], [-3.0, -4.0], [10.0, 0.0]]) + 1000.0
    np.testing.assert_allclose(distance_to_reference(driven, ref), [2.0, 2.0, 5.0, 0.0], atol=1e-9)
    # l5kit's variant: nearest waypoint only.
    np.testing.assert_allclose(distance_to_reference(driven, ref, waypoints_only=True),
                               [np.hypot(5, 2), np.hypot(2, 5), 5.0, 0.0], atol=1e-9)
    # Dropping the corner waypoint removes both its segments.
    avail = np.array([True, False, True])
    np.testing.assert_allclose(distance_to_reference(driven[:1], ref, avail), [np.hypot(5, 2)], atol=1e-9)


def test_distance_to_reference_l5kit_measures_the_first_80_percent_against_waypoints():
    logged = np.array([[0.0, 0.0], [10.0, 0.0], [20.0, 0.0], [30.0, 0.0], [40.0, 0.0], [99.0, 99.0]])
    driven = logged + [0.0, 3.0]
    driven[1] = [5.0, 1.0]  # between two waypoints: 5.1 m from the nearest, 1 m from the path
    unrolled = np.array([True] * 5 + [False])  # frame 5 is not unrolled: not a waypoint either
    got = distance_to_reference_l5kit(driven, logged, unrolled)
    np.testing.assert_allclose(got[:4], [3.0, np.hypot(5, 1), 3.0, 3.0])
    assert np.isnan(got[4:]).all()  # int(5 * 0.8) = 4 frames measured
    both = distance_to_reference_l5kit(np.stack([driven, driven]), logged, np.stack([unrolled, unrolled[::-1]]),
                                       scene_fraction=0.5)
    np.testing.assert_allclose(both[0], [3.0, np.hypot(5, 1)] + [np.nan] * 4)
    # Second row: frames 1..5 unrolled, 2 of them measured, against waypoints 1..5 only.
    np.testing.assert_allclose(both[1], [np.nan, np.hypot(5, 1), 3.0] + [np.nan] * 3)


def test_distance_to_reference_matches_brute_force_batched():
    rng = np.random.default_rng(3)
    ref = np.cumsum(rng.normal(0, 2, (4, 60, 2)), axis=1) + rng.uniform(-3000, 3000, (4, 1, 2))
    ref[:, 10:20] = ref[:, 10:11]  # a stop: repeated waypoints
    driven = ref[:, ::2] + rng.normal(0, 3, (4, 30, 2))
    a, e = ref[:, None, :-1], np.diff(ref, axis=1)[:, None]
    d = driven[:, :, None] - a
    u = np.clip((d * e).sum(-1) / np.maximum((e * e).sum(-1), 1e-300), 0, 1)
    brute = np.linalg.norm(d - u[..., None] * e, axis=-1).min(-1)
    np.testing.assert_allclose(distance_to_reference(driven, ref), brute, atol=1e-7)


def test_driven_distance_and_speed():
    pos = np.array([[0.0, 0.0], [3.0, 4.0], [3.0, 4.0], [6.0, 8.0]])
    np.testing.assert_allclose(driven_distance(pos), [0, 5, 5, 10])
    np.testing.assert_allclose(driven_distance(pos, np.array([True, True, False, True])), [0, 5, 5, 5])
    np.testing.assert_allclose(speed_from_positions(pos[:2], 0.5), [10.0, 10.0])
    np.testing.assert_allclose(speed_difference(np.array([5.0, 7.0]), np.array([6.0, 6.0])), [-1.0, 1.0])
