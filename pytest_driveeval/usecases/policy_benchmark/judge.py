"""The verdict of a policy benchmark item: statistics over the seeded episodes, not raw differences.

Every condition is decided on a confidence interval (stratified bootstrap
over the seed groups; paired where two policies are compared) and its
message carries the interval and the number of episodes.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from pytest_driveeval.metrics import benchmark_stats as stats
from pytest_driveeval.core.outcome import Finding
from pytest_driveeval.usecases.policy_benchmark.config import BenchmarkConditions, RateLimit
from pytest_driveeval.usecases.policy_benchmark.evaluate import PolicyRun

__all__ = ["RATES", "Judgement", "comparison", "interval", "judge", "rate_estimate", "rate_intervals"]

RATES = {"GoalRate": ("goal rate", "goal"), "CollisionRate": ("collision rate", "collision"),
         "OffRoadRate": ("off-road rate", "off_road")}


@dataclass
class Judgement:
    passed: bool
    findings: list[Finding]
    #: every interval computed, for the summary and the comparison plot
    intervals: dict[str, dict]


def rate_estimate(run: PolicyRun, outcome: str, confidence: float, seed: int) -> stats.Estimate:
    return stats.rate_interval(getattr(run, outcome), run.strata, confidence=confidence / 100.0, seed=seed)


def comparison(a: PolicyRun, b: PolicyRun, metric: str, confidence: float, seed: int) -> stats.Comparison:
    """A vs B on the same episodes; "better" means more goals, fewer collisions, a higher return."""
    if not np.array_equal(a.seeds, b.seeds):
        raise ValueError(f"policies '{a.policy}' and '{b.policy}' ran different episodes; a comparison is paired")
    if metric == "goal_rate":
        left, right, statistic = a.goal, b.goal, "mean"
    elif metric == "collision_rate":
        left, right, statistic = ~a.collision, ~b.collision, "mean"
    else:
        left, right, statistic = a.returns, b.returns, "iqm"
    return stats.compare(left, right, a.strata, statistic=statistic, confidence=confidence / 100.0, seed=seed)


def interval(estimate: stats.Estimate) -> dict:
    scale = 100.0 if estimate.percent else 1.0
    return {"point": scale * estimate.point, "low": scale * estimate.low, "high": scale * estimate.high,
            "n": estimate.n, "confidence": 100.0 * estimate.confidence, "method": estimate.method}


def rate_intervals(run: PolicyRun, confidence: float, seed: int) -> dict[str, dict]:
    """Every rate of ``run`` with its interval, keyed ``goal_rate``, ``collision_rate``, ``off_road_rate``."""
    return {f"{outcome}_rate": interval(rate_estimate(run, outcome, confidence, seed)) for _, outcome in RATES.values()}


COMPARED_METRICS = ("goal_rate", "collision_rate")


def judge(run: PolicyRun, baselines: dict[str, PolicyRun], conditions: BenchmarkConditions, seed: int,
          compare: Sequence[str] = ()) -> Judgement:
    """The conditions decided on ``run``; ``compare`` names policies of ``baselines`` whose paired
    comparison on goal and collision rate (``vs_<policy>_<metric>``) is reported and decides nothing."""
    findings: list[Finding] = []
    intervals: dict[str, dict] = {}
    passed = True
    for key, (label, outcome) in RATES.items():  # every rate's interval, for the report; limits where set
        estimate = rate_estimate(run, outcome, conditions.Confidence, seed)
        intervals[f"{outcome}_rate"] = interval(estimate)
        limit: RateLimit | None = getattr(conditions, key)
        if limit is None:
            continue
        if limit.AtLeast is not None:
            decision = stats.at_least(estimate, limit.AtLeast / 100.0, label=label)
        else:
            decision = stats.at_most(estimate, limit.AtMost / 100.0, label=label)
        if not decision.passed:
            passed = False
            findings.append(Finding(decision.message, figure=f"{outcome}_rate",
                                    keypath=("Evaluation", "Conditions", key)))
    for index, spec in enumerate(conditions.Beats):
        other = baselines[spec.Baseline]
        result = comparison(run, other, spec.Metric, conditions.Confidence, seed)
        label = f"'{run.policy}' beats '{other.policy}' on {spec.Metric.replace('_', ' ')}"
        decision = stats.beats(result, rule=spec.Rule, label=label)
        intervals[f"beats_{other.policy}_{spec.Metric}"] = {
            "improvement": interval(result.improvement), "difference": interval(result.difference)}
        if not decision.passed:
            passed = False
            findings.append(Finding(decision.message, figure=spec.Metric,
                                    keypath=("Evaluation", "Conditions", "Beats", index)))
    for name in compare:
        if name == run.policy:
            continue
        for metric in COMPARED_METRICS:
            result = comparison(run, baselines[name], metric, conditions.Confidence, seed)
            intervals[f"vs_{name}_{metric}"] = {"improvement": interval(result.improvement),
                                                "difference": interval(result.difference)}
    return Judgement(passed, findings, intervals)
