"""examples/regression_gate_study.py at a small size: the shipped GNN against a noisy copy of itself
is flagged, a rerun of it is not, and the gate's verdict on two equally good policies is the
paired tests' of their episode outcomes."""
from __future__ import annotations

import importlib.util
import sys

import numpy as np
import pytest

pytest.importorskip("torch")
pytest.importorskip("scipy")

from pytest_driveeval.baseline.paired import paired_rate  # noqa: E402
from pytest_driveeval.metrics.episode_outcomes import COLLISION, GOAL, OFF_ROAD  # noqa: E402
from pytest_driveeval.usecases.policy_benchmark.regression import FIGURES  # noqa: E402

from conftest import REPO_ROOT  # noqa: E402

EVENTS = {"goal_rate": GOAL, "collision_rate": COLLISION, "off_road_rate": OFF_ROAD}


@pytest.fixture(scope="module")
def script():
    # The script lives in examples/, not in the package: load it by path (registered first: its
    # dataclasses look their module up).
    spec = importlib.util.spec_from_file_location("regression_gate_study", REPO_ROOT / "examples" / "regression_gate_study.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    try:
        spec.loader.exec_module(module)
        yield module
    finally:
        sys.modules.pop(spec.name, None)


@pytest.fixture(scope="module")
def small(script):
    return script.study(episodes=64, pairs=1, noise=0.4)


def expected_regression(before, now, confidence: float) -> bool:
    """What the use case's rules make of the two runs, from their outcome codes alone."""
    for name, event in EVENTS.items():
        test = paired_rate(before.outcome == event, now.outcome == event, confidence)
        if test.significant() and (test.worse > test.better) == (FIGURES[name].better == "lower"):
            return True
    return False


def test_strong_noise_on_the_gnn_is_flagged_naming_the_lost_goals(small):
    row = small.regression
    assert row.fired and row.comparison.status == "regressed"
    goal = next(c for c in row.comparison.worse if c.what == "goal_rate")
    lost = np.flatnonzero((row.before.outcome == GOAL) & (row.now.outcome != GOAL))
    assert lost.size >= 10 and row.now.goal.mean() < row.before.goal.mean()
    assert f"episodes {lost[0]}, " in goal.text and "no longer end in goal" in goal.text
    assert "McNemar exact p = " in goal.text


def test_a_rerun_of_the_deterministic_gnn_changes_no_episode(small):
    row = small.rerun
    assert np.array_equal(row.before.outcome, row.now.outcome)
    assert row.comparison.status == "unchanged" and row.comparison.changes == [] and not row.fired


def test_the_gate_on_equally_good_policies_is_the_paired_tests(small):
    assert len(small.pairs) == 1
    for row in small.pairs + [small.regression, small.rerun]:
        assert row.fired == expected_regression(row.before, row.now, small.confidence), row.what
        # the two noisy copies differ in some episodes: the comparison is not a trivial one
    assert all(not np.array_equal(row.before.outcome, row.now.outcome) for row in small.pairs)


def test_the_noise_is_the_seeds(script):
    def policy(observation):
        return np.zeros((len(observation), 2))

    sd = np.array([1.0, 0.1])
    first, again, other = (script.NoisyPolicy(policy, sd, seed)(np.zeros((5, 3))) for seed in (1, 1, 2))
    assert np.array_equal(first, again) and not np.array_equal(first, other)
    assert np.all(np.abs(first[:, 1]) < 1.0)  # the steering's own, smaller, spread


def test_the_table_prints_every_comparison(script, small):
    text = script.table(small)
    assert text.count("\n") == 2 + 2 + len(small.pairs) - 1
    assert "gnn -> gnn+noise[0]" in text and text.splitlines()[2].endswith("regressed")


def test_the_chance_of_a_false_alarm_is_the_exact_tests_worse_side(script, small):
    """At most half of each rate's two-sided alpha (only the worse side fails an item), summed."""
    for row in small.pairs:
        chance = script.chance_of_firing(row, small.confidence)
        assert 0 <= chance <= 3 * (1 - small.confidence / 100) / 2
    assert script.chance_of_firing(small.rerun, small.confidence) == 0.0
