"""The session's end looks for baselines of items that no longer exist with the item names each
scenario file collected, not by loading every file again; what -k deselected still exists."""
from __future__ import annotations

import pytest

import pytest_driveeval.harness.collect as collect
from conftest import speed_scenario

UNUSED = "of items that no longer exist"


@pytest.fixture
def counted_loads(monkeypatch):
    calls = []
    real = collect.load_scenario

    def load(path, *args, **kwargs):
        calls.append(path.name)
        return real(path, *args, **kwargs)

    monkeypatch.setattr(collect, "load_scenario", load)
    return calls


def test_each_file_is_loaded_once_and_the_unused_baselines_are_still_found(project, counted_loads):
    project.makefile(".scenario.yaml", urban=speed_scenario(datasets=("slow.csv", "fast.csv"), max_speed=30.0),
                     ramp=speed_scenario(name="ramp", max_speed=30.0))
    options = ("-p", "no:randomly", "--driveeval-baseline", "base")
    project.runpytest(*options, "--driveeval-baseline-update").assert_outcomes(passed=3)
    assert len(list((project.path / "base").rglob("*.json"))) == 3
    counted_loads.clear()

    result = project.runpytest(*options)
    result.assert_outcomes(passed=3)
    assert sorted(counted_loads) == ["ramp.scenario.yaml", "urban.scenario.yaml"]
    result.stdout.fnmatch_lines(["driveeval baselines (base): 3 unchanged"])
    assert UNUSED not in result.stdout.str()

    # Deselected items still exist: their baselines are not unused.
    result = project.runpytest(*options, "-k", "slow and urban")
    result.assert_outcomes(passed=1)
    assert UNUSED not in result.stdout.str()

    project.makefile(".scenario.yaml", urban=speed_scenario(datasets=("slow.csv",), max_speed=30.0))
    result = project.runpytest(*options)
    result.assert_outcomes(passed=2)
    result.stdout.fnmatch_lines([f"driveeval baselines: 1 {UNUSED} (*fast.csv*)*"])
    # An xdist controller collects nothing itself: it loads the files, and finds the same.
    result = project.runpytest(*options, "-n", "2")
    result.assert_outcomes(passed=2)
    result.stdout.fnmatch_lines([f"driveeval baselines: 1 {UNUSED} (*fast.csv*)*"])
