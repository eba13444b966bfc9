"""Traffic: IDM keeps its distance, MOBIL changes lanes for a gain, merges and crossings yield by gap acceptance."""
from __future__ import annotations

import itertools

import numpy as np
import pytest

from pytest_driveeval.metrics.episode_outcomes import traffic_overlaps
from pytest_driveeval.sim.agents import Traffic, TrafficModel, idm_free, step_traffic
from pytest_driveeval.sim.blueprints import Lane, Road, make_blueprint
from pytest_driveeval.sim.episodes import reset

SIZE = (4.5, 1.8)
DT = 0.2
MODEL = TrafficModel()
FAR = -1.0e4  # where the ego is kept out of the way


def one_lane() -> Road:
    return Road((Lane(np.array([[0.0, 0.0], [3000.0, 0.0]]), 3.5),))


def two_lanes() -> Road:
    return Road((Lane(np.array([[0.0, 0.0], [3000.0, 0.0]]), 3.5), Lane(np.array([[0.0, 3.5], [3000.0, 3.5]]), 3.5)),
                left=(1, -1), right=(-1, 0))


def vehicles(lane, s, speed, desired=None) -> Traffic:
    """One episode; column 0 is the ego's slot, ``lane``/``s``/``speed`` include it."""
    lane, s, speed = (np.atleast_2d(np.asarray(x)) for x in (lane, s, speed))
    desired = speed if desired is None else np.atleast_2d(np.asarray(desired, float))
    zeros = np.zeros(s.shape)
    return Traffic(lane.astype(int), s.astype(float), zeros, speed.astype(float), desired.astype(float), zeros,
                   np.full(s.shape, 10.0), np.full(s.shape, -1), np.ones(s.shape, bool))


def run(road, traffic, steps, ego=None, model=MODEL):
    """Step traffic alone; ``ego(t) -> (xy, yaw, speed)`` of column 0 (default: far away, standing)."""
    history = []
    xy, yaw = road.pose(traffic.lane, traffic.s, traffic.d)
    for t in range(steps):
        speed = traffic.speed.copy()
        exy, eyaw, espeed = ego(t) if ego else ((FAR, FAR), 0.0, 0.0)
        xy[:, 0], yaw[:, 0], speed[:, 0] = exy, eyaw, espeed
        traffic, xy, yaw = step_traffic(road, model, traffic, xy, yaw, speed, SIZE, DT)
        history.append(traffic)
    return history


@pytest.mark.parametrize("speed", [10.0, 20.0, 30.0])
@pytest.mark.parametrize("brake", [5.0, 8.0])
def test_idm_keeps_its_distance_behind_a_braking_leader(speed, brake):
    # A platoon at IDM's equilibrium gap behind the ego, which brakes to a stop;
    # each follower stops behind the one before it, never closer than most of s0.
    road = one_lane()
    gap = MODEL.min_gap + speed * MODEL.time_headway
    s = 1000.0 - np.arange(5) * (SIZE[0] + gap)
    lead_s = [s[0]]
    lead_v = [speed]
    for _ in range(120):
        v = max(lead_v[-1] - brake * DT, 0.0)
        lead_s.append(lead_s[-1] + (0.5 * (lead_v[-1] + v) * DT if v > 0 else lead_v[-1] ** 2 / (2 * brake)))
        lead_v.append(v)
    ego = lambda t: ((lead_s[t], 0.0), 0.0, lead_v[t])
    history = run(road, vehicles(np.zeros(5), s, np.full(5, speed)), 120, ego)
    positions = np.array([np.concatenate([[lead_s[t + 1]], h.s[0, 1:]]) for t, h in enumerate(history)])
    gaps = positions[:, :-1] - positions[:, 1:] - SIZE[0]
    assert gaps.min() >= 0.9 * MODEL.min_gap
    assert history[-1].speed[0, 1:].max() < 0.05, "everyone stopped"
    assert gaps[-1].max() < MODEL.min_gap + 1.0, "and closed up to about s0, not stopping miles back"


def test_idm_reaches_its_desired_speed_on_a_free_road():
    history = run(two_lanes(), vehicles([0, 0], [0.0, 10.0], [0.0, 5.0], [1.0, 25.0]), 300)
    assert history[-1].speed[0, 1] == pytest.approx(25.0, abs=0.1)
    assert np.all(np.diff([h.speed[0, 1] for h in history]) >= -1e-12)
    assert idm_free(MODEL, np.array(25.0), np.array(25.0)) == 0.0


def test_mobil_overtakes_a_slow_leader_when_the_next_lane_is_free():
    # Vehicle 1 (wants 30 m/s) is stuck 20 m behind vehicle 2 (10 m/s).
    history = run(two_lanes(), vehicles([0, 0, 0], [0.0, 100.0, 124.5], [0.0, 12.0, 10.0], [1.0, 30.0, 10.0]), 40)
    lanes = np.array([h.lane[0, 1] for h in history])
    assert lanes[0] == 1, "changes at once: the gain is large and nobody is on the left"
    assert history[-1].s[0, 1] > history[-1].s[0, 2], "and overtakes"
    assert np.all(np.array([h.lane[0, 2] for h in history]) == 0)


def test_mobil_waits_while_the_change_would_make_a_follower_brake_hard():
    # Same, but a fast vehicle is coming up on the left 10 m behind: unsafe until it has passed.
    traffic = vehicles([0, 0, 0, 1], [0.0, 100.0, 124.5, 90.0], [0.0, 12.0, 10.0, 25.0], [1.0, 30.0, 10.0, 25.0])
    history = run(two_lanes(), traffic, 40)
    lanes = np.array([h.lane[0, 1] for h in history])
    changed = int(np.argmax(lanes == 1))
    assert lanes[0] == 0 and lanes.any()
    at_change = history[changed]
    assert at_change.s[0, 3] > at_change.s[0, 1], "only after the fast one went by"


def test_mobil_ignores_a_gain_below_its_threshold():
    # A slightly slower leader far ahead costs less than 0.2 m/s^2: stay.
    history = run(two_lanes(), vehicles([0, 0, 0], [0.0, 100.0, 300.0], [0.0, 15.0, 14.0], [1.0, 15.5, 14.0]), 20)
    assert all(h.lane[0, 1] == 0 for h in history)


def test_one_lane_change_per_episode_and_step():
    # Vehicles on the outer lanes of three both want the free middle lane at the same spot.
    road = Road(tuple(Lane(np.array([[0.0, y], [3000.0, y]]), 3.5) for y in (0.0, 3.5, 7.0)),
                left=(1, 2, -1), right=(-1, 0, 1))
    traffic = vehicles([0, 0, 0, 2, 2], [0.0, 100.0, 124.5, 101.0, 125.5], [0.0, 12.0, 10.0, 12.0, 10.0],
                       [1.0, 30.0, 10.0, 30.0, 10.0])
    history = run(road, traffic, 30)
    first = history[0].lane[0, [1, 3]]
    assert sorted(first.tolist()) in ([0, 1], [1, 2]), "only one of them moves at first"
    assert traffic_overlaps(*_poses(road, history), np.ones((1, 5), bool)).sum() == 0


def _poses(road, history):
    xy = np.concatenate([road.pose(h.lane, h.s, h.d)[0] for h in history])
    xy[:, 0] = FAR
    return xy, np.zeros(xy.shape[:2]), SIZE


def test_a_lane_change_blends_over_its_duration():
    history = run(two_lanes(), vehicles([0, 0, 0], [0.0, 100.0, 124.5], [0.0, 12.0, 10.0], [1.0, 30.0, 10.0]), 20)
    d = np.array([h.d[0, 1] for h in history])
    steps = int(np.ceil(MODEL.lane_change_duration / DT))
    assert d[0] == pytest.approx(-3.5 * (1 - (3 * 0.08 ** 2 - 2 * 0.08 ** 3)))  # smoothstep after one step of 2.5 s
    assert np.all(np.diff(d[:steps]) > 0) and np.all(d[steps - 1:] == 0.0)


def test_a_vehicle_that_leaves_the_map_is_no_longer_valid():
    road = Road((Lane(np.array([[0.0, 0.0], [100.0, 0.0]]), 3.5),))
    history = run(road, vehicles([0, 0], [0.0, 90.0], [0.0, 10.0], [1.0, 10.0]), 10)
    valid = [bool(h.valid[0, 1]) for h in history]
    assert valid[0] and not valid[-1]
    gone = valid.index(False)
    assert history[gone].s[0, 1] == history[-1].s[0, 1], "frozen once gone"


def merging_case(main_s, ego_d):
    """A merging road; the ego stands 10 m before the end of its lane, ``ego_d`` to the left of its centre;
    one main-lane vehicle at ``main_s`` going 10 m/s wanting 12."""
    road = make_blueprint("merging").road
    ego = lambda t: ((90.0, ego_d), 0.0, 0.0)
    return run(road, vehicles([0, 1], [90.0, main_s], [0.0, 10.0], [12.0, 12.0]), 60, ego)


def test_main_lane_traffic_yields_to_an_ego_nosing_into_an_acceptable_gap():
    nosing = merging_case(50.0, 0.5)
    waiting = merging_case(50.0, 0.0)
    assert nosing[-1].s[0, 1] < 90.0 - SIZE[0] - 0.9 * MODEL.min_gap + 1e-9, "stopped behind where the ego would go"
    assert waiting[-1].s[0, 1] > 150.0, "an ego keeping to its lane is not waited for"


def test_main_lane_traffic_does_not_yield_when_the_gap_is_too_small():
    close = merging_case(80.0, 0.5)
    assert close[-1].s[0, 1] > 150.0 and min(h.speed[0, 1] for h in close) > 9.0


def test_merge_lane_traffic_waits_for_a_gap_and_merges():
    bp = make_blueprint("merging")
    episodes = reset(bp, np.arange(32), 12)
    on_merge = (episodes.traffic.lane == 0) & episodes.valid
    on_merge[:, 0] = False
    assert on_merge.sum() > 10
    history = run(bp.road, episodes.traffic, 200)
    end = history[-1]
    assert not np.any(on_merge & (end.lane == 0) & end.valid), "every merge-lane vehicle merged"
    stopped = min(h.speed[on_merge & (h.lane == 0)].min(initial=np.inf) for h in history)
    assert stopped < 1.0, "some had to wait at the lane end for a gap"


def test_crossing_traffic_stops_for_an_ego_standing_in_its_lane():
    bp = make_blueprint("intersection")
    # Eastbound vehicle 40 m before the junction; the ego stands across the eastbound lane, facing north.
    ego = lambda t: ((1.75, -1.75), np.pi / 2, 0.0)
    history = run(bp.road, vehicles([2, 0], [80.0, 60.0], [0.0, 11.0], [11.0, 11.0]), 100, ego)
    front = history[-1].s[0, 1] - 100.0 + 0.5 * SIZE[0]  # x of its front bumper
    assert history[-1].speed[0, 1] < 0.05 and (1.75 - 0.9) - front >= 0.9 * MODEL.min_gap


@pytest.mark.parametrize("name", ["highway", "merging", "intersection"])
def test_traffic_never_crashes_into_itself(name):
    bp = make_blueprint(name)
    episodes = reset(bp, np.arange(32), 12)
    start = episodes.traffic
    history = run(bp.road, start, 400)
    crashes = sum(int(traffic_overlaps(*_poses_of(bp.road, h), h.valid).sum()) for h in history)
    assert crashes == 0
    moved = history[-1].s - start.s
    assert np.median(moved[start.valid][1:]) > 100.0, "traffic actually drove"
    if name == "highway":
        assert sum(int(np.count_nonzero(a.lane != b.lane)) for a, b in itertools.pairwise(history)) > 10


def _poses_of(road, traffic):
    xy, heading = road.pose(traffic.lane, traffic.s, traffic.d)
    xy[:, 0] = FAR
    return xy, heading, SIZE
