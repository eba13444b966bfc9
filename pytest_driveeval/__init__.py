"""pytest-driveeval: driving-software evaluations as pytest scenarios."""
from __future__ import annotations

import pytest

# Must precede the import below, or the helpers' asserts would not be rewritten.
pytest.register_assert_rewrite("pytest_driveeval.assertions",
                               "pytest_driveeval.usecases.closed_loop.assertions",
                               "pytest_driveeval.usecases.obstacle_segmentation.assertions",
                               "pytest_driveeval.usecases.policy_benchmark.assertions")

from .assertions import (  # noqa: E402
    assert_beats,
    assert_collision_free,
    assert_collision_rate,
    assert_comfortable,
    assert_drift_within,
    assert_drivable_area_compliant,
    assert_driving_direction_compliant,
    assert_figure_within,
    assert_goal_rate,
    assert_making_progress,
    assert_no_regression,
    assert_pass_rate,
    assert_passed,
    assert_score_at_least,
    assert_speed_limit_compliant,
    assert_term_at_least,
    assert_time_to_collision_within_bound,
    assert_values_within,
)
from .core.errors import DataError, DriveEvalError, ModelError, ScenarioError  # noqa: E402
from .core.outcome import FAILED, PASSED, Finding, Outcome  # noqa: E402
from .scenario import Scenario, load_scenario  # noqa: E402
from .core.usecase import Case, ConditionsModel, RunContext, UseCase, register_usecase  # noqa: E402

__version__ = "0.1.0"
__all__ = [
    "Case", "ConditionsModel", "DataError", "DriveEvalError", "FAILED", "Finding", "ModelError", "Outcome",
    "PASSED", "RunContext", "Scenario", "ScenarioError", "UseCase", "assert_beats", "assert_collision_free",
    "assert_collision_rate", "assert_drift_within", "assert_figure_within", "assert_goal_rate", "assert_pass_rate",
    "assert_no_regression", "assert_passed", "assert_score_at_least", "assert_term_at_least",
    "assert_drivable_area_compliant", "assert_driving_direction_compliant", "assert_time_to_collision_within_bound",
    "assert_comfortable", "assert_speed_limit_compliant", "assert_making_progress",
    "assert_values_within", "load_scenario", "register_usecase",
]
