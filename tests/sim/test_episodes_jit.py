"""The compiled policy-benchmark step (sim.episodes_jit) against the numpy one: the same episodes bit for bit."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from pytest_driveeval.metrics.episode_outcomes import COLLISION, GOAL, OFF_ROAD, STEP_LIMIT
from pytest_driveeval.sim import episodes_jit
from pytest_driveeval.sim.blueprints import make_blueprint
from pytest_driveeval.sim.episodes import reset

pytestmark = pytest.mark.skipif(not episodes_jit.AVAILABLE, reason="numba is not installed: only the numpy path runs")

NAMES = ["highway", "merging", "intersection"]
# Wider spawns (as the step benchmark's) fill all 12 slots, so every agent row is exercised.
FILL = {"highway": {}, "merging": {"main_span": (0.0, 95.0), "merge_span": (0.0, 60.0)},
        "intersection": {"traffic_span": (-95.0, 40.0)}}
STATE = ("xy", "yaw", "speed", "valid", "steps", "outcome", "returns")
TRAFFIC = ("lane", "s", "d", "speed", "change_offset", "change_time", "yield_to", "valid")


def lane_keeper(episodes, rng):
    """Follow the nearest lane at the goal's speed, braking for what is ahead, with noise: episodes that
    last, lane changes and yields around them, now and then a crash."""
    road = episodes.blueprint.road
    ego_xy, ego_yaw, v = episodes.xy[:, 0], episodes.yaw[:, 0], episodes.speed[:, 0]
    proj = road.project(ego_xy)
    lane = np.argmin(np.abs(proj.d), axis=1)[:, None]
    d = np.take_along_axis(proj.d, lane, 1)[:, 0]
    err = (ego_yaw - np.take_along_axis(proj.heading, lane, 1)[:, 0] + np.pi) % (2 * np.pi) - np.pi
    rel = episodes.xy[:, 1:] - ego_xy[:, None]
    along = rel[..., 0] * np.cos(ego_yaw)[:, None] + rel[..., 1] * np.sin(ego_yaw)[:, None]
    across = rel[..., 1] * np.cos(ego_yaw)[:, None] - rel[..., 0] * np.sin(ego_yaw)[:, None]
    ahead = episodes.valid[:, 1:] & (along > 0) & (np.abs(across) < 2.5)
    gap = np.where(ahead, along - 4.5, np.inf).min(axis=1)
    accel = np.clip(0.5 * (episodes.goal_speed - v) + np.where(gap < 8.0, -4.0, 0.0), -5, 4)
    steer = np.clip(-0.1 * d - err, -0.5, 0.5)
    return np.stack([accel, steer], axis=1) + rng.normal(0.0, [1.0, 0.08], (len(v), 2))


def run(name, policy, seeds, steps=120, perturbation=None, **params):
    """Every array of the episodes' state after each step, and what the steps returned."""
    episodes = reset(make_blueprint(name, **{**FILL[name], **params}), seeds, 12, perturbation=perturbation)
    rng = np.random.default_rng(7)
    frames = []
    for _ in range(steps):
        actions = (lane_keeper(episodes, rng) if policy == "keeper"
                   else rng.uniform([-5.0, -0.5], [4.0, 0.5], (len(seeds), 2)))
        result = episodes.step(actions)
        frames.append({**{f: getattr(episodes, f).copy() for f in STATE},
                       **{f"traffic.{f}": getattr(episodes.traffic, f).copy() for f in TRAFFIC},
                       **{f"ego.{f}": np.array(getattr(episodes._ego, f)) for f in ("xy", "yaw", "speed")},
                       **{f"result.{f}": np.asarray(v) for f, v in result._asdict().items()}})
    return frames


def assert_same_bits(got, expected):
    assert len(got) == len(expected)
    for t, (g, e) in enumerate(zip(got, expected)):
        assert g.keys() == e.keys()
        for key in g:
            assert g[key].dtype == e[key].dtype and g[key].shape == e[key].shape, (t, key)
            assert g[key].tobytes() == e[key].tobytes(), f"step {t}: {key} differs"


CASES = [(name, policy) for name in NAMES for policy in ("keeper", "random")]


@pytest.mark.parametrize("name,policy", CASES)
def test_compiled_episodes_are_the_numpy_ones_bit_for_bit(name, policy, monkeypatch):
    seeds = np.arange(24)
    episodes_jit.start()
    compiled = run(name, policy, seeds, max_steps=100)
    monkeypatch.setattr(episodes_jit, "AVAILABLE", False)
    assert_same_bits(compiled, run(name, policy, seeds, max_steps=100))
    # What the comparison went through: crashes, the step limit, traffic changing lanes and giving way.
    outcomes = set(compiled[-1]["outcome"].tolist())
    assert OFF_ROAD in outcomes or STEP_LIMIT in outcomes
    if policy == "keeper":
        assert any((f["traffic.yield_to"] >= 0).any() for f in compiled)
        if name != "intersection":  # one lane each way there
            assert (np.diff(np.stack([f["traffic.lane"] for f in compiled]), axis=0) != 0).sum() > 5
        if name != "highway":
            assert COLLISION in outcomes


def test_compiled_goals_and_perturbed_starts_are_the_numpy_ones(monkeypatch):
    """The highway's goals (a lane keeper on the goal lane from the start) and perturbed starts."""
    rows = np.random.default_rng(3).uniform([-1.5, -3, -0.2, 0.5, 0.6, 0.5], [1.5, 3, 0.2, 1.5, 1.4, 2.0], (24, 6))
    rows[::4] = [0.0, 0.0, 0.0, 1.0, 1.0, 1.0]
    rows[1::4, 0], rows[2::4, 0] = -3.5, 3.5  # on a neighbouring lane, where the goals are
    episodes_jit.start()
    compiled = run("highway", "keeper", np.arange(24), steps=150, perturbation=rows)
    assert {GOAL, COLLISION, OFF_ROAD} <= set(compiled[-1]["outcome"].tolist())
    monkeypatch.setattr(episodes_jit, "AVAILABLE", False)
    assert_same_bits(compiled, run("highway", "keeper", np.arange(24), steps=150, perturbation=rows))


def test_switching_paths_mid_episode_changes_nothing(monkeypatch):
    """The process takes the compiled path once numba pays for itself, episodes already in flight."""
    seeds = np.arange(8)
    monkeypatch.setattr(episodes_jit, "AVAILABLE", False)
    plain = run("merging", "keeper", seeds, steps=60)
    monkeypatch.setattr(episodes_jit, "AVAILABLE", True)
    episodes_jit.start()
    calls = []
    original = episodes_jit.step
    monkeypatch.setattr(episodes_jit, "step", lambda *a: calls.append(1) or original(*a))
    switched = []
    episodes = reset(make_blueprint("merging", **FILL["merging"]), seeds, 12)
    rng = np.random.default_rng(7)
    for t in range(60):
        monkeypatch.setattr(episodes_jit, "AVAILABLE", t % 3 == 0)
        episodes.step(lane_keeper(episodes, rng))
        switched.append(episodes.xy.copy())
    assert len(calls) == 20
    for a, b in zip(switched, plain):
        assert a.tobytes() == b["xy"].tobytes()


def test_the_numpy_path_runs_where_numba_is_not_wanted(monkeypatch):
    monkeypatch.setattr(episodes_jit, "AVAILABLE", False)
    monkeypatch.setattr(episodes_jit, "step", lambda *a: pytest.fail("the compiled step ran"))
    episodes = reset("highway", [0, 1], 12)
    episodes.step(np.zeros((2, 2)))
    assert not episodes_jit.start() and not episodes_jit.wanted(10.0)


def test_numba_starts_once_the_savings_forgone_pay_for_it(monkeypatch):
    monkeypatch.delitem(sys.modules, "numba", raising=False)
    monkeypatch.setattr(episodes_jit, "_forgone", 0.0)
    assert not episodes_jit.wanted(0.01)  # a few steps of a few episodes: numpy
    assert not episodes_jit.wanted(episodes_jit.START_SECONDS - 0.02)
    assert episodes_jit.wanted(0.01)  # now it has paid for itself


WITHOUT_NUMBA = """
import sys
sys.modules["numba"] = None  # import numba fails: the numpy path
sys.path.insert(0, sys.argv[2])
import numpy as np
import test_episodes_jit as t
from pytest_driveeval.sim import episodes_jit
assert not episodes_jit.AVAILABLE and not episodes_jit.start()
frames = t.run("merging", "keeper", np.arange(6), steps=40)
np.savez(sys.argv[1], **{f"{i}:{k}": v for i, f in enumerate(frames) for k, v in f.items()})
"""


def test_without_numba_the_episodes_are_the_same(tmp_path):
    out = tmp_path / "plain.npz"
    subprocess.run([sys.executable, "-c", WITHOUT_NUMBA, str(out), str(Path(__file__).parent)], check=True,
                   timeout=600)
    episodes_jit.start()
    compiled = run("merging", "keeper", np.arange(6), steps=40)
    with np.load(out) as plain:
        frames = [{k: plain[f"{i}:{k}"] for k in f} for i, f in enumerate(compiled)]
    assert_same_bits(compiled, frames)
