"""pytest's cache works for scenario items as for any test: --lf, --ff and --sw, also under xdist."""
from __future__ import annotations

import pytest
from conftest import speed_scenario, write_trajectory
from test_fixtures import summary

WORKERS = [pytest.param([], id="serial"), pytest.param(["-n", "2"], id="xdist")]


def ran(pytester) -> list[str]:
    """The scenario items the last session ran, in the order the summary keeps."""
    return sorted(r["nodeid"] for r in summary(pytester)["results"])


@pytest.fixture
def three(project):
    """a and c pass; b drives 20 m/s where 14 m/s is the limit."""
    project.makefile(".scenario.yaml", a=speed_scenario("a", datasets=("slow.csv",)))
    project.makefile(".scenario.yaml", b=speed_scenario("b", datasets=("slow.csv", "fast.csv")))
    project.makefile(".scenario.yaml", c=speed_scenario("c", datasets=("slow.csv",)))
    return project


FAILED = "b.scenario.yaml::speed_limit[fast.csv]"


@pytest.mark.parametrize("workers", WORKERS)
def test_last_failed_reruns_only_the_failed_scenario_item(three, workers):
    three.runpytest("-q", *workers).assert_outcomes(passed=3, failed=1)
    assert (three.path / ".pytest_cache" / "v" / "cache" / "lastfailed").is_file()
    three.runpytest("-q", "--lf", *workers).assert_outcomes(failed=1)
    assert ran(three) == [FAILED]
    # --ff runs every item, the failed one too.
    three.runpytest("-q", "--ff", *workers).assert_outcomes(passed=3, failed=1)
    # Fixed, it passes; the next --lf has no failure left and runs everything again.
    write_trajectory(three.path / "fast.csv", 12.0)
    three.runpytest("-q", "--lf", *workers).assert_outcomes(passed=1)
    assert ran(three) == [FAILED]
    three.runpytest("-q", "--lf", *workers).assert_outcomes(passed=4)


def test_failed_first_runs_the_failed_scenario_item_first(three):
    three.runpytest("-q").assert_outcomes(passed=3, failed=1)
    result = three.runpytest("-v", "--ff")
    result.assert_outcomes(passed=3, failed=1)
    order = [line.split(" ")[0] for line in result.outlines if "::speed_limit[" in line and "%]" in line]
    assert order == [FAILED, "a.scenario.yaml::speed_limit[slow.csv]", "b.scenario.yaml::speed_limit[slow.csv]",
                     "c.scenario.yaml::speed_limit[slow.csv]"]


@pytest.mark.parametrize("workers", WORKERS)
def test_stepwise_stops_at_the_failed_scenario_item_and_resumes_there(three, workers):
    first = three.runpytest("-q", "--sw", *workers)
    assert first.parseoutcomes()["failed"] == 1
    assert FAILED in ran(three)
    # The next run starts at the failed item: the items before it are not run again.
    again = three.runpytest("-q", "--sw", *workers)
    assert again.parseoutcomes()["failed"] == 1
    assert "a.scenario.yaml::speed_limit[slow.csv]" not in ran(three) and FAILED in ran(three)
    write_trajectory(three.path / "fast.csv", 12.0)
    three.runpytest("-q", "--sw", *workers).assert_outcomes(passed=2)
    assert ran(three) == [FAILED, "c.scenario.yaml::speed_limit[slow.csv]"]
