"""The session summary: written once by the controller, the same under xdist."""
from __future__ import annotations

import json

import pytest

from conftest import speed_scenario


def load_summary(pytester) -> dict:
    return json.loads((pytester.path / "driveeval-results" / "summary.json").read_text())


def without_timings(summary: dict) -> dict:
    """The summary without what differs between two sessions by design: times and the run's identity."""
    run_id = summary["run"]["id"]
    summary = json.loads(json.dumps(summary).replace(run_id, "RUN"))
    summary = {k: v for k, v in summary.items() if k not in ("duration", "run")}
    summary["results"] = [{k: v for k, v in r.items() if k != "duration"} for r in summary["results"]]
    return summary


@pytest.fixture
def mixed(project):
    project.makefile(".scenario.yaml",
                     ok=speed_scenario("ok", datasets=("slow.csv", "fast.csv"), max_speed=25),
                     too_fast=speed_scenario("too-fast", datasets=("fast.csv",)),
                     skipped=speed_scenario("skipped", extra="Skip: later\n"),
                     known=speed_scenario("known", datasets=("fast.csv",), extra="XFail: ticket 7\n"),
                     broken="ScenarioFormatVersion: 3.0.0\n",
                     nodata=speed_scenario("nodata", datasets=("absent.csv",)))
    return project


def test_summary_records_every_scenario_item(mixed):
    result = mixed.runpytest("-q")
    assert result.ret == 1
    summary = load_summary(mixed)
    assert summary["exit_status"] == 1
    assert summary["counts"] == {"error": 1, "failed": 2, "passed": 2, "skipped": 1, "xfailed": 1}
    by_id = {r["nodeid"]: r for r in summary["results"]}
    assert list(by_id) == sorted(by_id)
    passed = by_id["ok.scenario.yaml::speed_limit[slow.csv]"]
    assert passed["status"] == "passed" and passed["verdict"] == "passed"
    assert passed["scenario"] == "ok" and passed["use_case"] == "speed_limit" and passed["dataset"] == "slow.csv"
    assert passed["figures"]["max_speed"] == pytest.approx(10.0)
    failed = by_id["too_fast.scenario.yaml::speed_limit[fast.csv]"]
    assert failed["status"] == "failed" and failed["findings"][0]["figure"] == "speed"
    assert failed["findings"][0]["keypath"] == ["Evaluation", "Conditions", "MaxSpeed"]
    assert "speed should be <= 14 m/s" in failed["message"]
    assert by_id["skipped.scenario.yaml::speed_limit[slow.csv]"]["message"] == "later"
    known = by_id["known.scenario.yaml::speed_limit[fast.csv]"]
    assert known["status"] == "xfailed" and known["verdict"] == "failed"
    assert known["expected_to_fail"] == "ticket 7"
    broken = by_id["broken.scenario.yaml::scenario"]
    assert broken["status"] == "failed" and "missing required key 'ScenarioName'" in broken["message"]
    assert by_id["nodata.scenario.yaml::speed_limit[absent.csv]"]["status"] == "error"


def test_terminal_table_shows_verdicts_and_figures(mixed, monkeypatch):
    monkeypatch.setenv("COLUMNS", "200")
    result = mixed.runpytest("-q")
    result.stdout.fnmatch_lines([
        "*driveeval: 7 scenario item(s)*",
        "verdict*scenario*what decided it; key figures",
        "failed*broken.scenario.yaml::scenario*",
        "xfailed*known.scenario.yaml::speed_limit[[]fast.csv[]]",
        "*expected to fail: ticket 7; speed should be <= 14 m/s but is not at 29 of 29 frame(s)*",
        "*max_speed=20*",
        "error*nodata.scenario.yaml::speed_limit[[]absent.csv[]]*",
        "passed*ok.scenario.yaml::speed_limit[[]fast.csv[]]*max_speed=20*",
        "passed*ok.scenario.yaml::speed_limit[[]slow.csv[]]*max_speed=10*",
        "skipped*skipped.scenario.yaml::speed_limit[[]slow.csv[]]*",
        "failed*too_fast.scenario.yaml::speed_limit[[]fast.csv[]]",
        "*speed should be <= 14 m/s but is not at 29 of 29 frame(s)*worst at frame 22: 20 m/s",
        "*max_speed=20*",
        "results: *driveeval-results*summary.json (run *)",
    ])


def test_a_row_names_the_failed_condition_and_the_reason_an_item_was_expected_to_fail(mixed):
    mixed.makefile(".scenario.yaml", two_limits=speed_scenario("two", datasets=("fast.csv",)).replace(
        "MaxSpeed: 14.0", "MaxSpeed: 14.0\n    MaxAcceleration: 1.0e-20"))
    mixed.runpytest("-q")
    rows = {line.split(" | ")[1].strip("`"): line for line in
            (mixed.path / "driveeval-results" / "summary.md").read_text().splitlines() if line.startswith("| ")}
    too_fast = rows["too_fast.scenario.yaml::speed_limit[fast.csv]"]
    assert "speed should be <= 14 m/s but is not at 29 of 29 frame(s)" in too_fast
    assert "max speed 20.00 m/s" not in too_fast  # the figures are in their own column
    known = rows["known.scenario.yaml::speed_limit[fast.csv]"]
    assert "expected to fail: ticket 7; speed should be <= 14 m/s" in known
    # The first condition that failed, and how many more did.
    assert "speed should be <= 14 m/s" in rows["two_limits.scenario.yaml::speed_limit[fast.csv]"]
    assert "(and 1 more)" in rows["two_limits.scenario.yaml::speed_limit[fast.csv]"]
    # A pass still shows its outcome's summary, a skip its reason.
    assert "max speed 10.00 m/s" in rows["ok.scenario.yaml::speed_limit[slow.csv]"]
    assert " | later | " in rows["skipped.scenario.yaml::speed_limit[slow.csv]"]


def test_narrow_terminal_wraps_the_verdicts_reason_and_figures_under_the_node_id(mixed, monkeypatch):
    monkeypatch.setenv("COLUMNS", "60")
    result = mixed.runpytest("-q")
    result.stdout.fnmatch_lines(["passed    ok.scenario.yaml::speed_limit[[]slow.csv[]]",
                                 "          max speed 10.00 m/s, max |acceleration| 0.00 m/s^2",
                                 "          max_speed=10*"])
    table = result.stdout.str().split("driveeval: 7")[1].split("results:")[0]
    # Wider than the terminal only where one word is (a path in an error's message), never cut.
    assert all(len(line) <= 60 or len(line.split()) == 1 for line in table.splitlines()[1:])
    assert not any(line.endswith("...") for line in table.splitlines())


def test_same_summary_with_two_workers(mixed):
    mixed.runpytest("-q")
    alone = without_timings(load_summary(mixed))
    result = mixed.runpytest("-q", "-n", "2")
    result.assert_outcomes(passed=2, failed=2, skipped=1, xfailed=1, errors=1)
    assert without_timings(load_summary(mixed)) == alone
    leftovers = [p.name for p in (mixed.path / "driveeval-results").rglob("*") if ".tmp" in p.name]
    assert leftovers == []


def test_no_summary_when_no_scenario_ran(pytester):
    pytester.makepyfile(test_plain="def test_x():\n    pass\n")
    result = pytester.runpytest("-q")
    result.assert_outcomes(passed=1)
    assert not (pytester.path / "driveeval-results" / "summary.json").exists()
    assert "driveeval:" not in result.stdout.str()
