"""The clean obstacle-segmentation scenario's check, written as a Python test."""
import pytest

from pytest_driveeval.obstacle import assert_pass_rate, evaluate_obstacle_segmentation


@pytest.mark.driveeval_scenario("clean/scenario.yaml")
def test_every_annotated_object_is_seen_and_the_lane_ahead_is_free(
        driveeval_scenario, driveeval_dataset, driveeval_pointclouds):
    result = evaluate_obstacle_segmentation(driveeval_dataset, driveeval_pointclouds, driveeval_scenario.config)
    assert_pass_rate(result, detection=100.0, non_detection=100.0)
