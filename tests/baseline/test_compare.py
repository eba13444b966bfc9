"""compare(): one item's payload against its reference, by hand-made payloads (no session)."""
from __future__ import annotations

import pytest

from pytest_driveeval.baseline.compare import (ERROR, IMPROVED, MISSING, REGRESSED, STALE, UNCHANGED, Change,
                                               Comparison, against_text, compare, stale_reasons)
from pytest_driveeval.baseline.rules import FigureRule, RegressionSpec, effective_rules
from pytest_driveeval.baseline.units import Units
from pytest_driveeval.usecases.closed_loop.regression import FIGURES as CLOSED_LOOP
from pytest_driveeval.usecases.policy_benchmark.regression import FIGURES as POLICY, LEGEND as EPISODES

SCENE_LEGEND = {"p": "passed", "f": "failed", "e": "error"}


def payload(figures=None, rules=None, units=None, verdict="passed", summary="fine", search=None,
            fingerprint=None, section=None) -> dict:
    return {"figures": figures or {}, "units": units.to_json() if units is not None else None,
            "verdict": verdict, "summary": summary, "search": search, "fingerprint": fingerprint,
            "rules": effective_rules(rules if rules is not None else CLOSED_LOOP,
                                     RegressionSpec.model_validate(section) if section else None).to_json()}


def scenes(codes: str, reasons=None) -> Units:
    return Units("scene", [str(i) for i in range(len(codes))], {"scene": codes}, SCENE_LEGEND, {"scene": "p"},
                 reasons or {})


# --- deterministic figures ------------------------------------------------------------------------

@pytest.mark.parametrize("after, status", [
    (10.0, UNCHANGED),
    (10.19, UNCHANGED),
    (10.21, REGRESSED),
    (9.79, IMPROVED),
    (9.81, UNCHANGED),
])
def test_a_lower_is_better_figure_within_and_beyond_its_tolerance(after, status):
    rules = {"max_displacement": FigureRule("lower", atol=0.1, rtol=0.01)}  # 0.1 + 0.1 = 0.2 at 10
    result = compare(payload({"max_displacement": 10.0}, rules), payload({"max_displacement": after}, rules))
    assert result.status == status
    assert len(result.changes) == (status != UNCHANGED)


def test_a_higher_is_better_figure_regresses_when_it_falls():
    rules = {"scenes_passed": FigureRule("higher")}
    worse = compare(payload({"scenes_passed": 5}, rules), payload({"scenes_passed": 4}, rules))
    better = compare(payload({"scenes_passed": 5}, rules), payload({"scenes_passed": 6}, rules))
    assert worse.status == REGRESSED and better.status == IMPROVED
    assert worse.changes[0].text == "scenes_passed 5 -> 4 (higher is better; tolerance 0)"
    assert better.changes[0].text == "scenes_passed 5 -> 6 (better; tolerance 0)"


def test_the_current_payloads_rules_decide_not_the_references():
    loose = {"max_displacement": FigureRule("lower", atol=5.0)}
    strict = {"max_displacement": FigureRule("lower")}
    assert compare(payload({"max_displacement": 1.0}, strict),
                   payload({"max_displacement": 2.0}, loose)).status == UNCHANGED
    assert compare(payload({"max_displacement": 1.0}, loose),
                   payload({"max_displacement": 2.0}, strict)).status == REGRESSED


@pytest.mark.parametrize("before, after", [(None, 3), (3, None), (True, 3), (float("nan"), 3), ("3", 4)])
def test_figures_that_are_not_finite_numbers_on_either_side_are_not_compared(before, after):
    rules = {"at_fault": FigureRule("lower")}
    assert compare(payload({"at_fault": before}, rules, verdict="failed"),
                   payload({"at_fault": after}, rules, verdict="failed")).status == UNCHANGED


def test_an_ignored_figure_is_not_compared():
    result = compare(payload({"at_fault": 0}), payload({"at_fault": 4}, section={"Figures": {"at_fault": {"Ignore": True}}}))
    assert result.status == UNCHANGED


# --- units (scenes) and the verdict -------------------------------------------------------------

def test_scenes_that_flipped_are_named_with_the_reason_they_fail_now():
    before = payload({"scenes_passed": 2}, units=scenes("pfp", {"1": "at_fault at frame 3 (hit)"}))
    after = payload({"scenes_passed": 2}, units=scenes("ppf", {"2": "drift_resets at frame 9 (drifted)"}))
    result = compare(before, after)
    assert result.status == REGRESSED
    assert [c.text for c in result.changes] == [
        "scene 1 failed before, passed now",
        "scene 2 passed before, failed now: drift_resets at frame 9 (drifted)",
    ]
    assert [c.worse for c in result.changes] == [False, True]
    # the message lists what got worse only
    assert compare(before, after, "run r1").message() == (
        "regression against run r1:\n    scene 2 passed before, failed now: drift_resets at frame 9 (drifted)")


def test_units_false_in_the_section_leaves_scenes_out():
    result = compare(payload(units=scenes("pp")), payload(units=scenes("pf"), section={"Units": False}, verdict="passed"))
    assert result.status == UNCHANGED


def test_frames_name_their_column():
    legend = {"S": "Success", "F": "Fail", "-": "not judged"}
    units = lambda det: Units("frame", ["0", "1"], {"detection": det}, legend, {"detection": "S-"},
                              {"1": "stamp_ns 42"} if "F" in det else {})
    result = compare(payload(units=units("SS")), payload(units=units("SF")))
    assert [c.text for c in result.changes] == ["frame 1 detection Success before, Fail now: stamp_ns 42"]


def test_verdict_passed_to_failed_is_a_regression_when_nothing_else_says_why():
    result = compare(payload({"at_fault": 0}), payload({"at_fault": 0}, verdict="failed", summary="1/2 scenes passed"))
    assert result.status == REGRESSED
    assert [c.text for c in result.changes] == ["verdict passed -> failed: 1/2 scenes passed"]


def test_verdict_change_is_not_repeated_beside_a_figure_that_explains_it():
    result = compare(payload({"at_fault": 0}), payload({"at_fault": 2}, verdict="failed"))
    assert [c.what for c in result.changes] == ["at_fault"]


def test_verdict_failed_to_passed_alone_is_no_change():
    assert compare(payload(verdict="failed"), payload(verdict="passed")).status == UNCHANGED


# --- paired episode rates ---------------------------------------------------------------------

def episodes(codes: str, first: int = 100) -> Units:
    return Units("episode", [str(first + i) for i in range(len(codes))], {"outcome": codes}, EPISODES,
                 {"outcome": "g"})


def rate(codes: str, code: str) -> float:
    return 100.0 * codes.count(code) / len(codes)


def policy_payload(codes: str, verdict="passed", section=None) -> dict:
    figures = {"goal_rate": rate(codes, "g"), "collision_rate": rate(codes, "c"), "off_road_rate": rate(codes, "o")}
    return payload(figures, POLICY, episodes(codes), verdict=verdict, section=section)


def test_a_significant_rise_in_collisions_is_a_regression_naming_the_seeds():
    before, after = "g" * 40, "g" * 28 + "c" * 12
    result = compare(policy_payload(before), policy_payload(after))
    assert result.status == REGRESSED
    by = {c.what: c for c in result.changes}
    assert by["collision_rate"].worse is True
    assert by["goal_rate"].worse is True   # fewer goals: worse too
    text = by["collision_rate"].text
    assert "collision_rate 0 % -> 30 %" in text and "McNemar exact p = " in text
    assert "episodes 128, 129, 130, 131, 132, 133, 134, 135 and 4 more now end in collision" in text


def test_a_significant_fall_in_collisions_is_an_improvement():
    result = compare(policy_payload("g" * 28 + "c" * 12), policy_payload("g" * 40))
    assert result.status == IMPROVED
    assert {c.what: c.worse for c in result.changes} == {"collision_rate": False, "goal_rate": False}
    text = next(c.text for c in result.changes if c.what == "collision_rate")
    assert "episodes 128, 129, 130, 131, 132, 133, 134, 135 and 4 more no longer end in collision" in text


def test_a_few_changed_episodes_are_not_significant():
    before = "g" * 38 + "cg"
    after = "g" * 38 + "gc"   # the same rate, two seeds swapped
    assert compare(policy_payload(before), policy_payload(after)).status == UNCHANGED
    after = "g" * 37 + "ccg"  # one more collision
    assert compare(policy_payload(before), policy_payload(after)).status == UNCHANGED


def test_the_confidence_of_the_section_decides_significance():
    before, after = "g" * 20, "g" * 15 + "c" * 5   # 5 discordant, all worse: p = 0.0625
    assert compare(policy_payload(before), policy_payload(after, section={"Confidence": 90})).status == REGRESSED
    assert compare(policy_payload(before), policy_payload(after, section={"Confidence": 95})).status == UNCHANGED


def test_paired_rules_neither_list_units_nor_fall_back_to_the_verdict():
    before, after = "g" * 20, "g" * 19 + "c"
    result = compare(policy_payload(before), policy_payload(after, verdict="failed"))
    assert result.status == UNCHANGED and result.changes == []


def test_only_seeds_both_runs_played_are_paired():
    before = policy_payload("g" * 20)
    after = payload({"collision_rate": 50.0}, POLICY, episodes("c" * 20, first=500))
    assert compare(before, after).status == UNCHANGED


# --- the robustness search --------------------------------------------------------------------

def search(broke, minimal=None, text="speed 2", replay="@reproduce_failure('x')", examples=50):
    return {"broke": broke, "minimal": minimal or {}, "text": text, "replay": replay if broke else None,
            "examples": examples}


def test_search_passed_before_and_breaks_now_is_a_regression_with_its_replay_line():
    result = compare(payload(search=search(False)), payload(search=search(True, {"speed": 2.0})))
    assert result.status == REGRESSED
    assert result.changes[0].text == ("the search found nothing before (50 examples) and breaks it now: "
                                      "speed 2; replay: @reproduce_failure('x')")


def test_search_broke_before_and_passes_now_is_an_improvement():
    result = compare(payload(search=search(True, {"speed": 2.0})), payload(search=search(False, examples=80)))
    assert result.status == IMPROVED
    assert result.changes[0].text == "the search broke it before (speed 2), finds nothing now (80 examples)"


@pytest.mark.parametrize("before, after, status", [
    (2.0, 1.5, REGRESSED),     # towards zero by 0.5 > 0.1 + 0.1 * 2
    (2.0, 1.75, UNCHANGED),    # by 0.25 <= 0.3
    (2.0, 2.25, UNCHANGED),
    (2.0, 2.5, IMPROVED),      # further from zero
    (-2.0, -1.5, REGRESSED),   # the sign does not matter, the distance to zero does
    (-2.0, -2.5, IMPROVED),
])
def test_minimal_breaking_change_against_its_tolerance(before, after, status):
    section = {"Search": {"Tolerance": 0.1, "RelativeTolerance": 0.1}}
    result = compare(payload(search=search(True, {"speed": before})),
                     payload(search=search(True, {"speed": after}), section=section))
    assert result.status == status
    if status == REGRESSED:
        assert result.changes[0].what == "minimal_speed"
        assert f"smallest breaking speed {before:g} before, {after:g} now (towards zero by 0.5, tolerance 0.3)" \
            in result.changes[0].text
        assert "replay: @reproduce_failure('x')" in result.changes[0].text


def test_search_tolerance_per_parameter():
    section = {"Search": {"Tolerance": {"yaw": 1.0}, "RelativeTolerance": 0}}
    before = payload(search=search(True, {"speed": 2.0, "yaw": 2.0}))
    result = compare(before, payload(search=search(True, {"speed": 1.9, "yaw": 1.5}), section=section))
    assert [c.what for c in result.changes] == ["minimal_speed"]


def test_search_never_broke_is_unchanged_and_ignores_figures():
    result = compare(payload({"at_fault": 0}, search=search(False)),
                     payload({"at_fault": 9}, search=search(False), verdict="failed"))
    assert result.status == UNCHANGED


# --- stale references and status -------------------------------------------------------------

def fp(**changes) -> dict:
    base = {"use_case": "closed_loop", "format_version": "0.1.0", "seed": 1,
            "settings": {"Scenes": {"Count": 4, "Map": "town"}, "Steps": 100},
            "dataset": {"name": "d", "files": 1, "bytes": 10, "sha256": "aa"}}
    return {**base, **changes}


def test_identical_or_unknown_fingerprints_are_not_stale():
    assert stale_reasons(fp(), fp()) == []
    assert stale_reasons(None, fp()) == [] and stale_reasons(fp(), None) == []


def test_stale_reasons_name_the_dataset_the_seed_and_each_settings_key_path():
    after = fp(seed=2, dataset={"name": "d", "files": 1, "bytes": 11, "sha256": "bb"},
               settings={"Scenes": {"Count": 5, "Map": "town", "Weather": "rain"}, "Steps": 100})
    reasons = stale_reasons(fp(), after)
    assert reasons == [
        "the dataset changed (d sha256 aa, 10 bytes -> d sha256 bb, 11 bytes)",
        "the seed changed (1 -> 2)",
        "the settings changed (Evaluation.Scenes.Count 4 -> 5, Evaluation.Scenes.Weather (absent) -> rain)",
    ]


def test_stale_reasons_shorten_a_long_list_of_settings():
    after = fp(settings={"A": 1, "B": 2, "C": 3, "D": 4, "E": 5})
    (reason,) = stale_reasons(fp(settings={}), after)
    assert reason.endswith("Evaluation.C (absent) -> 3 and 2 more)")


def test_use_case_and_format_version_changes_are_stale():
    assert stale_reasons(fp(), fp(use_case="other")) == ["the use case changed (closed_loop -> other)"]
    assert stale_reasons(fp(), fp(format_version="0.2.0")) == ["the format version changed (0.1.0 -> 0.2.0)"]


def test_stale_wins_over_any_figure_change():
    result = compare(payload({"at_fault": 0}, fingerprint=fp()), payload({"at_fault": 9}, fingerprint=fp(seed=3)),
                     "baseline `abc`")
    assert result.status == STALE and result.changes == []
    assert result.message() == ("stale baseline `abc`: the seed changed (1 -> 3) since it was made; not compared "
                                "(update the baseline)")


def test_regressed_wins_over_improved():
    rules = {"at_fault": FigureRule("lower"), "scenes_passed": FigureRule("higher")}
    result = compare(payload({"at_fault": 0, "scenes_passed": 3}, rules),
                     payload({"at_fault": 1, "scenes_passed": 9}, rules), "run r1")
    assert result.status == REGRESSED and result.regressed
    assert [c.what for c in result.worse] == ["at_fault"] and [c.what for c in result.better] == ["scenes_passed"]
    assert result.message() == "regression against run r1:\n    at_fault 0 -> 1 (lower is better; tolerance 0)"


@pytest.mark.parametrize("status, expected", [
    (IMPROVED, "improvement against run r1:\n    b"),
    (UNCHANGED, "no change against run r1"),
    (REGRESSED, "regression against run r1:\n    a"),
    (MISSING, "the note"),
    (STALE, "the note"),
    (ERROR, "the note"),
])
def test_message_of_each_status(status, expected):
    changes = [Change("a", 1, 2, True, "a"), Change("b", 1, 2, False, "b"), Change("c", 1, 2, None, "c")]
    comparison = Comparison(status, "run r1", "s.json", changes, note="the note")
    assert comparison.message() == expected
    assert comparison.to_json()["message"] == expected and comparison.to_json()["status"] == status


def test_against_text():
    run = {"commit": "0123456789abcdef", "dirty": True, "started": "2026-01-01T00:00:00", "id": "r9"}
    assert against_text({"run": run}) == "baseline `0123456789ab` with uncommitted changes (2026-01-01T00:00:00)"
    assert against_text({}) == "baseline `no commit` (unknown date)"
    assert against_text({"run": run}, "run") == "run r9 (`0123456789ab`, 2026-01-01T00:00:00)"
