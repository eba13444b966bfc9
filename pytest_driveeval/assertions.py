"""Assertion helpers for scenario tests written in Python.

Registered for assertion rewriting (see ``__init__``); each hides its own frame
so a failure points at the test, and its message names the scenario, the
frame and the figure.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from .baseline.gate import assert_no_regression
from .core.outcome import Outcome, format_figure
from .verdict import within

# A use case's own helpers live with the use case, which knows its results;
# they are re-exported here so that every helper is one import away.  One line
# per use case (each module is also registered for rewriting in ``__init__``).
from .usecases.closed_loop.assertions import (assert_collision_free, assert_comfortable, assert_drift_within,
                                              assert_drivable_area_compliant, assert_driving_direction_compliant,
                                              assert_making_progress, assert_score_at_least, assert_speed_limit_compliant,
                                              assert_term_at_least, assert_time_to_collision_within_bound)
from .usecases.obstacle_segmentation.assertions import assert_pass_rate
from .usecases.policy_benchmark.assertions import assert_beats, assert_collision_rate, assert_goal_rate

__all__ = [
    "assert_figure_within", "assert_no_regression", "assert_passed", "assert_values_within",
    "assert_collision_free", "assert_drift_within", "assert_score_at_least", "assert_term_at_least",  # closed_loop
    "assert_drivable_area_compliant", "assert_driving_direction_compliant", "assert_time_to_collision_within_bound",
    "assert_comfortable", "assert_speed_limit_compliant", "assert_making_progress",
    "assert_pass_rate",  # obstacle_segmentation
    "assert_beats", "assert_collision_rate", "assert_goal_rate",  # policy_benchmark
]


def _scenario_prefix(outcome_or_name: Outcome | str | None) -> str:
    name = outcome_or_name.scenario if isinstance(outcome_or_name, Outcome) else outcome_or_name
    return f"scenario '{name}': " if name else ""


def assert_passed(outcome: Outcome) -> None:
    """The evaluation's own verdict is 'passed'; otherwise list its findings."""
    __tracebackhide__ = True
    if not outcome.passed:
        reasons = "\n".join(f"  - {f.message}" for f in outcome.findings) or f"  {outcome.summary}"
        raise AssertionError(f"{_scenario_prefix(outcome)}{outcome.use_case} {outcome.verdict}: "
                             f"{outcome.summary}\n{reasons}")


def assert_figure_within(outcome: Outcome, figure: str, *, max: float | None = None,
                         min: float | None = None) -> None:
    """One key figure of an outcome lies in [min, max]."""
    __tracebackhide__ = True
    if figure not in outcome.figures:
        raise AssertionError(f"{_scenario_prefix(outcome)}no figure '{figure}'; "
                             f"it has {sorted(outcome.figures)}")
    finding = within([outcome.figures[figure]], figure=figure, max=max, min=min)
    if finding is not None:
        raise AssertionError(f"{_scenario_prefix(outcome)}{figure} = {format_figure(outcome.figures[figure])}, "
                             f"outside [{min}, {max}]")


def assert_values_within(values: Sequence[float] | np.ndarray, *, figure: str, max: float | None = None,
                         min: float | None = None, frames: Sequence[int] | None = None, unit: str = "",
                         scenario: str | None = None, scene: int | str | None = None) -> None:
    """Every per-frame value lies in [min, max]; the message names the frames that do not."""
    __tracebackhide__ = True
    finding = within(values, figure=figure, max=max, min=min, frames=frames, unit=unit, scene=scene)
    if finding is not None:
        raise AssertionError(_scenario_prefix(scenario) + finding.message)
