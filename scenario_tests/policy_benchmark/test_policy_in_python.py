"""The policy benchmark as a Python test, gated on its baseline like the YAML items."""
import pytest

from pytest_driveeval import assert_figure_within, assert_no_regression


@pytest.mark.driveeval_scenario("merging.scenario.yaml")
def test_the_gnn_merges_no_worse_than_on_main(driveeval_run, driveeval_baseline):
    outcome = driveeval_run()
    assert_figure_within(outcome, "goal_rate", min=80)
    assert_no_regression(outcome, driveeval_baseline)
