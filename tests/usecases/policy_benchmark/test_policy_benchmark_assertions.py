"""assert_goal_rate / assert_collision_rate / assert_beats for tests written in Python."""
from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("scipy")

from pytest_driveeval import assert_beats, assert_collision_rate, assert_goal_rate  # noqa: E402
from pytest_driveeval.metrics.episode_outcomes import COLLISION, GOAL, STEP_LIMIT  # noqa: E402
from pytest_driveeval.usecases.policy_benchmark.evaluate import PolicyRun, seeds_for  # noqa: E402


def run(name: str, outcomes: list[int], returns: list[float] | None = None) -> PolicyRun:
    seeds, strata = seeds_for(0, len(outcomes), 4)
    returns = np.asarray(returns if returns is not None else [1.0 if o == GOAL else -1.0 for o in outcomes])
    return PolicyRun(name, "merging", seeds, strata, np.asarray(outcomes), returns, np.full(len(outcomes), 50))


def test_goal_rate_passes_on_the_lower_bound_and_fails_with_interval_and_count():
    good = run("good", [GOAL] * 90 + [COLLISION] * 10)
    assert_goal_rate(good, at_least=75)
    with pytest.raises(AssertionError) as failure:
        assert_goal_rate(good, at_least=88)  # the point, 90 %, clears it; the interval does not
    message = str(failure.value)
    assert message.startswith("'good' goal rate 90.0 % [")
    assert "(95 % stratified bootstrap CI, 100 episodes) is not >= 88 % (the interval includes 88 %)" in message


def test_collision_rate_is_decided_on_the_upper_bound():
    careful = run("careful", [GOAL] * 95 + [COLLISION] * 5)
    assert_collision_rate(careful, at_most=15)
    with pytest.raises(AssertionError, match=r"'careful' collision rate 5.0 % \[.*is not <= 6 %"):
        assert_collision_rate(careful, at_most=6)


def test_beats_is_paired_and_needs_confidence():
    base = [GOAL if i % 2 else STEP_LIMIT for i in range(80)]
    better = [GOAL] * 80
    assert_beats(run("better", better), run("base", base), metric="goal_rate")
    with pytest.raises(AssertionError, match=r"'base' beats 'base' on goal rate 0.5 \[0.5, 0.5\].*80 paired episodes"):
        assert_beats(run("base", base), run("base", base))
    # Better on most episodes but far worse on the rest: P(A > B) says A, the return's IQM says B.
    a = run("a", [GOAL] * 40, returns=[1.0] * 28 + [-50.0] * 12)
    b = run("b", [GOAL] * 40, returns=[0.0] * 40)
    assert_beats(a, b, metric="return")
    with pytest.raises(AssertionError):
        assert_beats(a, b, metric="return", rule="difference")


def test_runs_on_different_episodes_are_not_compared():
    with pytest.raises(ValueError, match="ran different episodes"):
        assert_beats(run("a", [GOAL] * 10), run("b", [GOAL] * 12))


def test_on_a_real_run_of_the_simulator():
    pytest.importorskip("torch")
    from pytest_driveeval.policies.control_baselines import ConstantAction
    from pytest_driveeval.sim.blueprints import make_blueprint
    from pytest_driveeval.usecases.policy_benchmark.evaluate import run_policy

    seeds, strata = seeds_for(0, 12, 4)
    constant = run_policy(make_blueprint("merging"), seeds, ConstantAction(), "constant", strata=strata)
    with pytest.raises(AssertionError, match=r"'constant' goal rate .*12 episodes\) is not >= 50 %"):
        assert_goal_rate(constant, at_least=50)
