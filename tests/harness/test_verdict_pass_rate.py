"""verdict.PassRate and verdict.listing: the pass-rate rule and the one way failing frames are listed."""
from __future__ import annotations

from pytest_driveeval.verdict import PassRate, listing


def test_listing_names_the_first_few_and_counts_the_rest():
    assert listing([]) == ""
    assert listing(["a", "b"]) == "a, b"
    assert listing(list("abcdefg"), sep="; ") == "a; b; c; d; e; ... 2 more"
    # only the first texts made, the total given
    assert listing(["a", "b"], limit=2, total=9) == "a, b, ... 7 more"


def test_pass_rate_counts_success_and_warn_apart():
    rate = PassRate()
    assert rate.rate == 0.0 and rate.meets(None) and rate.meets(0.0) and not rate.meets(1.0)
    for verdict in ("Success", "Warn", "Fail", "Success"):
        rate.add(verdict)
    assert (rate.total, rate.passed, rate.warned, rate.rate) == (4, 2, 1, 50.0)
    assert rate.meets(50.0) and not rate.meets(50.1)


def test_pass_rate_finding_lists_failing_frames():
    rate = PassRate()
    for verdict in ["Fail"] * 7 + ["Success"] * 3:
        rate.add(verdict)
    assert rate.finding(30.0, what="Detection", failing=[], figure="x") is None
    assert rate.finding(None, what="Detection", failing=[], figure="x") is None
    assert PassRate().finding(99.0, what="Detection", failing=[], figure="x") is None  # nothing judged
    texts = [f"frame {i}" for i in range(7)]
    finding = rate.finding(99.0, what="Detection", failing=texts, figure="detection_rate",
                           keypath=("Evaluation", "Conditions", "Detection", "PassRate"))
    assert finding.message == ("Detection: 3 / 10 frame(s) passed (30.00%), 99% required; "
                               "frame 0; frame 1; frame 2; frame 3; frame 4; ... 2 more")
    assert (finding.figure, finding.value, finding.limit) == ("detection_rate", 30.0, 99.0)
    # only the listed frames described, the count of failing ones given
    short = rate.finding(99.0, what="Detection", failing=texts[:5], failing_total=7, figure="detection_rate")
    assert short.message == finding.message
