"""A robustness property written in Python with hypothesis: the same strategies and
assertion helpers as the scenario's Perturbation section, for checks a YAML cannot say."""
import pytest
from hypothesis import HealthCheck, given, settings

from pytest_driveeval import assert_collision_free, assert_drift_within
from pytest_driveeval.closed_loop import unroll_scenes
from pytest_driveeval.strategies import start_perturbations


@pytest.mark.driveeval_scenario("real_scene_lateral.scenario.yaml")
# The dataset and model fixtures do not change between examples, so sharing them is safe.
@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(perturbation=start_perturbations(lateral=(-1.0, 1.0), speed_scale=(0.9, 1.1)))
def test_a_start_within_a_metre_of_the_lane_keeps_the_model_on_the_log(driveeval_dataset, driveeval_model,
                                                                       perturbation):
    unroll = unroll_scenes(driveeval_dataset, driveeval_model, scenes=[0], start_frame=10, steps=100,
                           perturbation=perturbation)
    assert_collision_free(unroll, at_fault_only=True)
    assert_drift_within(unroll, meters=4.0, seconds=1.0)
