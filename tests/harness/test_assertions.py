"""Assertion helpers: messages name scenario, frame and figure; own frames hidden."""
from __future__ import annotations

import math

import numpy as np
import pytest

import pytest_driveeval.assertions as assertions
from pytest_driveeval import Outcome, assert_figure_within, assert_passed, assert_values_within
from pytest_driveeval.core.outcome import Finding
from pytest_driveeval.verdict import within


def test_within_names_first_and_worst_frames():
    finding = within([1.0, 5.0, 2.0, 9.0, 0.5], figure="drift", max=3.0, unit=" m", frames=[10, 11, 12, 13, 14])
    assert finding is not None
    assert finding.frame == 13 and finding.value == 9.0 and finding.limit == 3.0
    assert "drift should be <= 3 m but is not at 2 of 5 frame(s): frame 11 (5 m), frame 13 (9 m)" in finding.message
    assert "worst at frame 13: 9 m" in finding.message


def test_within_passes_inside_bounds_and_fails_on_nan():
    assert within(np.linspace(0, 1, 50), figure="x", min=0.0, max=1.0) is None
    finding = within([0.1, math.nan, 0.2], figure="x", max=1.0)
    assert finding is not None and finding.frame == 1


def test_within_lists_at_most_five_frames():
    finding = within(np.arange(20.0), figure="x", max=-1)
    assert finding.message.count("frame ") == 6  # five listed plus the worst
    assert "... 15 more" in finding.message


def test_assert_values_within_message_names_scenario_scene_and_frame():
    with pytest.raises(AssertionError, match=r"scenario 'urban': scene 3: speed should be <= 14.*frame 2 \(20\)"):
        assert_values_within([10, 12, 20], figure="speed", max=14, scenario="urban", scene=3)
    assert_values_within([10, 12, 13], figure="speed", max=14)


def test_assert_passed_and_figure_within():
    good = Outcome("u", "passed", "fine", figures={"rate": 0.99}, scenario="s [u]")
    assert_passed(good)
    assert_figure_within(good, "rate", min=0.95)
    bad = Outcome("u", "failed", "too slow", findings=[Finding("frame 4 late")], scenario="s [u]")
    with pytest.raises(AssertionError, match=r"(?s)scenario 's \[u\]': u failed: too slow.*frame 4 late"):
        assert_passed(bad)
    with pytest.raises(AssertionError, match=r"no figure 'speed'; it has \['rate'\]"):
        assert_figure_within(good, "speed", max=1)
    with pytest.raises(AssertionError, match=r"rate = 0.99, outside \[None, 0.5\]"):
        assert_figure_within(good, "rate", max=0.5)


def test_helpers_module_is_rewritten_by_pytest():
    assert type(assertions.__loader__).__name__ == "AssertionRewritingHook"


def test_failure_traceback_stops_at_the_test_not_inside_the_helper(pytester):
    pytester.makepyfile(test_drift='''
        from pytest_driveeval import assert_values_within

        def test_drift():
            assert_values_within([0.1, 0.2, 4.0], figure="drift", max=2.0, unit=" m", scenario="lane-keep")
        ''')
    result = pytester.runpytest("-q")
    result.assert_outcomes(failed=1)
    result.stdout.fnmatch_lines(["*AssertionError: scenario 'lane-keep': drift should be <= 2 m*frame 2 (4 m)*"])
    assert "assertions.py" not in result.stdout.str()
