"""Baselines of what an XFail does not hide (a robustness search that got easier to break) and of
Python tests gated with the driveeval_baseline fixture."""
from __future__ import annotations

import pytest

pytest.importorskip("torch")

from baseline_sessions import closed_loop, edit_baseline, records, run, with_closed_loop_data  # noqa: E402

# The IDM expert, made to steer off the road when its ego starts turned left by more than 0.03 rad.
FRAGILE = '''
import weakref

import pytest

from pytest_driveeval.policies.idm_expert import IDMExpert


class Fragile:
    def __init__(self):
        self.expert = IDMExpert()
        self.start = weakref.WeakKeyDictionary()

    def act_on_episodes(self, episodes):
        start = self.start.setdefault(episodes, episodes.yaw[:, 0].copy())
        actions = self.expert.act_on_episodes(episodes)
        actions[start > 0.03] = [0.0, episodes.blueprint.params.ego_max_steer]
        return actions


@pytest.fixture
def driveeval_model():
    return Fragile()
'''

SEARCH = """\
ScenarioFormatVersion: 3.0.0
ScenarioName: {name}
XFail:
  Reason: steers off the road when it starts turned left
  Strict: true
Evaluation:
  UseCaseName: policy_benchmark
  UseCaseFormatVersion: 0.1.0
  Blueprint: {{Name: merging}}
  Episodes: 4
  Policies:
    mine: constant
  Perturbation:
    Heading: [-0.08, 0.08]
    Examples: 16
    Batch: 8
Regression:
  Search: {{Tolerance: 0.01, RelativeTolerance: 0}}
"""


def test_an_xfail_search_that_breaks_sooner_or_breaks_where_it_passed_before_fails(pytester):
    pytester.makeconftest(FRAGILE)
    pytester.makefile(".scenario.yaml", closer=SEARCH.format(name="closer"), fresh=SEARCH.format(name="fresh"),
                      same=SEARCH.format(name="same"))
    search = ["--driveeval-search-profile=ci"]
    run(pytester, *search, "--driveeval-baseline-update").assert_outcomes(xfailed=3)
    node = {n: f"{n}.scenario.yaml::policy_benchmark[mine]" for n in ("closer", "fresh", "same")}
    minimal = records(pytester)[node["closer"]]["baseline"]["search"]["minimal"]["heading"]
    assert 0.03 < minimal < 0.032

    def further(data):
        data["search"]["minimal"]["heading"] = 0.06

    def passed(data):
        data["search"].update(broke=False, minimal={}, text="no failure in 16 examples", replay=None)

    edit_baseline(pytester, node["closer"], further)
    edit_baseline(pytester, node["fresh"], passed)
    result = run(pytester, *search)
    result.assert_outcomes(failed=2, xfailed=1)  # the expected failure no longer hides a regression
    by_id = records(pytester)
    assert by_id[node["same"]]["comparison"]["status"] == "unchanged"
    (closer,) = by_id[node["closer"]]["comparison"]["changes"]
    assert (closer["what"], closer["before"], closer["after"], closer["worse"]) == ("minimal_heading", 0.06, minimal,
                                                                                    True)
    assert closer["text"].startswith(f"smallest breaking heading 0.06 before, {minimal:.4g} now (towards zero by "
                                     f"{0.06 - minimal:.4g}, tolerance 0.01); before: heading=")
    (fresh,) = by_id[node["fresh"]]["comparison"]["changes"]
    assert fresh["worse"] is True and (fresh["before"], fresh["after"]) == ("passed", "broke")
    assert fresh["text"].startswith("the search found nothing before (")
    assert f"breaks it now: heading={minimal!r}; replay: pytest '{node['fresh']}' --driveeval-replay seed=" \
           in fresh["text"]
    result.stdout.fnmatch_lines(["*RegressionFailed: regression against baseline*",
                                 "    smallest breaking heading 0.06 before, * now (towards zero by *",
                                 "  its own verdict: failed: *"])
    # Within the tolerance it is the expected failure again.
    edit_baseline(pytester, node["closer"], lambda d: d["search"]["minimal"].update(heading=minimal + 0.009))
    run(pytester, *search, "closer.scenario.yaml").assert_outcomes(xfailed=1)


PYTHON_TEST = '''
import pytest
from pytest_driveeval.assertions import assert_no_regression


@pytest.mark.driveeval_scenario("drive.yaml")
def test_gated(driveeval_run, driveeval_baseline):
    outcome = driveeval_run()
    comparison = assert_no_regression(outcome, driveeval_baseline)
    print("compared:", comparison.status)
'''


def test_a_python_test_gates_on_its_baseline_with_the_fixture(pytester):
    with_closed_loop_data(pytester)
    pytester.makefile(".yaml", drive=closed_loop(scenes="[0, 1, 2]", steps=40))  # not a scenario file: bound only
    pytester.makepyfile(test_gated=PYTHON_TEST)
    nodeid = "test_gated.py::test_gated"
    run(pytester, "-s").assert_outcomes(passed=1)
    assert records(pytester)[nodeid]["comparison"]["message"] == "no baseline yet: run with --driveeval-baseline-update"
    run(pytester, "--driveeval-baseline-strict").assert_outcomes(failed=1)
    run(pytester, "--driveeval-baseline-update").assert_outcomes(passed=1)
    result = run(pytester, "-s")
    result.assert_outcomes(passed=1)
    result.stdout.fnmatch_lines(["*compared: unchanged*"])
    result = run(pytester, "--driveeval-model", "constant_velocity")
    result.assert_outcomes(failed=1)
    record = records(pytester)[nodeid]
    assert record["comparison"]["status"] == "regressed"
    assert "scene 2 passed before, failed now: front at frame" in record["comparison"]["message"]
    result.stdout.fnmatch_lines(["*regression against baseline*", "*scene 2 passed before, failed now: front at*"])
