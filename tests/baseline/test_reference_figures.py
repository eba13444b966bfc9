"""A comparison carries its reference's key figures, so reports can show "now (before, change)"."""
from __future__ import annotations

from pytest_driveeval.baseline.compare import STALE, UNCHANGED, compare

RULES = {"figures": {"max_displacement": {"better": "lower", "atol": 0.5}}}


def test_compared_items_keep_the_reference_figures():
    before = {"figures": {"max_displacement": 1.0}, "rules": RULES}
    after = {"figures": {"max_displacement": 1.2}, "rules": RULES}
    comparison = compare(before, after, "baseline `abc`")
    assert comparison.status == UNCHANGED
    assert comparison.to_json()["reference_figures"] == {"max_displacement": 1.0}


def test_a_stale_reference_shows_no_figures_to_compare_with():
    before = {"figures": {"max_displacement": 1.0}, "rules": RULES, "fingerprint": {"seed": 1}}
    after = {"figures": {"max_displacement": 1.2}, "rules": RULES, "fingerprint": {"seed": 2}}
    comparison = compare(before, after)
    assert comparison.status == STALE and comparison.to_json()["reference_figures"] == {}
