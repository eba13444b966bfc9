"""Assertion helpers for policy-benchmark tests written in Python, on the
:class:`~pytest_driveeval.usecases.policy_benchmark.evaluate.PolicyRun` of
``run_policy``.  The verdicts are the YAML conditions' own: decided on a
confidence interval, whose bounds and episode count the message gives.

Registered for assertion rewriting (see ``pytest_driveeval/__init__``).  The
statistics (scipy) load on first use, so ``import pytest_driveeval`` stays light.
"""
from __future__ import annotations

from typing import Literal

from pytest_driveeval.usecases.policy_benchmark.evaluate import PolicyRun

__all__ = ["assert_beats", "assert_collision_rate", "assert_goal_rate"]


def _check(decision) -> None:
    __tracebackhide__ = True
    if not decision.passed:
        raise AssertionError(decision.message)


def assert_goal_rate(result: PolicyRun, at_least: float, *, confidence: float = 95.0, seed: int = 0) -> None:
    """The goal rate (%) is >= ``at_least`` with ``confidence`` (%): the interval's lower bound clears it."""
    __tracebackhide__ = True
    from pytest_driveeval.metrics import benchmark_stats as stats
    from pytest_driveeval.usecases.policy_benchmark.judge import rate_estimate

    estimate = rate_estimate(result, "goal", confidence, seed)
    _check(stats.at_least(estimate, at_least / 100.0, label=f"'{result.policy}' goal rate"))


def assert_collision_rate(result: PolicyRun, at_most: float, *, confidence: float = 95.0, seed: int = 0) -> None:
    """The collision rate (%) is <= ``at_most`` with ``confidence``: the interval's upper bound stays under it."""
    __tracebackhide__ = True
    from pytest_driveeval.metrics import benchmark_stats as stats
    from pytest_driveeval.usecases.policy_benchmark.judge import rate_estimate

    estimate = rate_estimate(result, "collision", confidence, seed)
    _check(stats.at_most(estimate, at_most / 100.0, label=f"'{result.policy}' collision rate"))


def assert_beats(a: PolicyRun, b: PolicyRun, metric: Literal["goal_rate", "collision_rate", "return"] = "goal_rate",
                 *, rule: Literal["improvement", "difference"] = "improvement", confidence: float = 95.0,
                 seed: int = 0) -> None:
    """``a`` is better than ``b`` on the same episodes, with confidence: by default the
    lower bound of P(a better than b) exceeds 0.5 (Agarwal et al. 2021)."""
    __tracebackhide__ = True
    from pytest_driveeval.metrics import benchmark_stats as stats
    from pytest_driveeval.usecases.policy_benchmark.judge import comparison

    result = comparison(a, b, metric, confidence, seed)
    _check(stats.beats(result, rule=rule, label=f"'{a.policy}' beats '{b.policy}' on {metric.replace('_', ' ')}"))
