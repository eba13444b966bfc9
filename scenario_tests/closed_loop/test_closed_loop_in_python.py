"""Closed-loop checks written as Python tests, with the scenario's dataset and model fixtures."""
import pytest

from pytest_driveeval import assert_collision_free, assert_drift_within
from pytest_driveeval.closed_loop import unroll_scenes


@pytest.mark.driveeval_scenario("real_scene_baseline.scenario.yaml")
def test_replaying_the_log_is_collision_free_and_does_not_drift(driveeval_dataset):
    from pytest_driveeval.policies.baselines import ReplayLogPolicy

    unroll = unroll_scenes(driveeval_dataset, ReplayLogPolicy(), scenes=[0], start_frame=10, steps=100)
    assert_collision_free(unroll)
    assert_drift_within(unroll, meters=0.01)


@pytest.mark.driveeval_scenario("real_scene.scenario.yaml")
def test_planning_model_causes_no_collision_and_stays_near_the_log(driveeval_dataset, driveeval_model):
    unroll = unroll_scenes(driveeval_dataset, driveeval_model, scenes=[0], start_frame=10, steps=100)
    assert_collision_free(unroll, at_fault_only=True)
    assert_drift_within(unroll, meters=10.0, seconds=1.0)
