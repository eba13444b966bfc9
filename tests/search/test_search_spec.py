"""The rules a replayed case meets are the ranges' own, for every use case that searches."""
from __future__ import annotations

import pytest
from pydantic import ValidationError

from pytest_driveeval.search.spec import StartSearchSpec, parse_replay
from pytest_driveeval.usecases.obstacle_segmentation.config import ObstaclePerturbation
from pytest_driveeval.usecases.policy_benchmark.config import PolicyPerturbation


@pytest.mark.parametrize("spec, field, value, problem", [
    (StartSearchSpec(Lateral=(-1, 1)), "lateral", 1.0, None),
    (StartSearchSpec(Lateral=(-1, 1)), "lateral", 1.01, "outside the scenario's range Lateral: [-1, 1]"),
    (StartSearchSpec(Lateral=(-1, 1)), "lateral", 1.0 + 2e-16, None),  # a drawn edge an ulp past the range
    (StartSearchSpec(Lateral=(-1, 1)), "lateral", float("nan"), "a finite number is needed"),
    (StartSearchSpec(Lateral=(-1, 1)), "heading", 0.3, None),  # not searched, and no bound: a what-if
    (StartSearchSpec(Lateral=(-1, 1)), "speed_scale", 0.0, "a speed scale must stay above 0"),
    (StartSearchSpec(Lateral=(-1, 1)), "scene", 3.0, None),  # the case label is the item's to check
    (PolicyPerturbation(Lateral=(-1, 1)), "gap_scale", 0.0, "a gap scale must stay above 0"),
    (PolicyPerturbation(GapScale=(0.5, 2)), "gap_scale", 0.4, "outside the scenario's range GapScale: [0.5, 2]"),
    (ObstaclePerturbation(GhostPoints=(0, 40)), "ghost_points", 2.5, "a whole number is needed"),
    (ObstaclePerturbation(GhostPoints=(0, 40)), "ghost_points", 40.0, None),
    (ObstaclePerturbation(RangeNoise=(0, 0.1)), "dropout", 1.5, "a fraction of the points, within [0, 1]"),
])
def test_replay_problem(spec, field, value, problem):
    assert spec.replay_problem(field, value) == problem


def test_a_scenarios_own_replay_meets_the_same_rules_at_its_key():
    with pytest.raises(ValidationError) as failed:
        ObstaclePerturbation.model_validate({"GhostPoints": [0, 40], "Replay": {"Frame": 0, "GhostPoints": 2.5}})
    (error,) = failed.value.errors()
    assert error["loc"] == ("Replay", "GhostPoints") and error["msg"] == "a whole number is needed; got 2.5"


@pytest.mark.parametrize("text", ["frame=0,dropout=nan", "frame=0,dropout=-inf", "frame=inf", "seed=0,lateral=1e999"])
def test_the_replay_option_refuses_what_is_not_a_finite_number(text):
    with pytest.raises(ValueError, match="a finite number is needed"):
        parse_replay(text)
