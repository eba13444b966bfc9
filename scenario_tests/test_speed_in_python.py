"""The urban check of speed/urban.scenario.yaml, written as a Python test."""
import pytest

from pytest_driveeval import assert_figure_within, assert_passed


@pytest.mark.driveeval_scenario("speed/urban.scenario.yaml")
def test_urban_drive_brakes_gently(driveeval_run):
    outcome = driveeval_run()
    assert_passed(outcome)
    assert_figure_within(outcome, "max_acceleration", max=2.5)
