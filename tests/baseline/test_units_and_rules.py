"""Units (how each scene / frame / episode ended) and the rules of what counts as worse: pure
functions, no session."""
from __future__ import annotations

import json

import pytest
from pydantic import ValidationError

from pytest_driveeval.baseline.rules import (DEFAULT_CONFIDENCE, FigureRule, RegressionSpec, Rules,
                                             SearchTolerance, effective_rules)
from pytest_driveeval.baseline.units import LINE, Units, compact_ids, expand_ids, unit_changes

LEGEND = {"p": "passed", "f": "failed", "e": "error"}


def scenes(codes: str, ids: list[str] | None = None, reasons: dict[str, str] | None = None) -> Units:
    ids = ids if ids is not None else [str(i) for i in range(len(codes))]
    return Units("scene", ids, {"scene": codes}, LEGEND, {"scene": "p"}, reasons or {})


# --- ids ----------------------------------------------------------------------------------------

@pytest.mark.parametrize("ids", [["0", "1", "2"], ["7", "8"], ["12"]])
def test_consecutive_canonical_integers_compact_to_from_and_count(ids):
    assert compact_ids(ids) == {"from": int(ids[0]), "count": len(ids)}
    assert expand_ids(compact_ids(ids)) == ids


@pytest.mark.parametrize("ids", [
    [],
    ["0", "2", "3"],          # a gap
    ["3", "2"],               # descending
    ["01", "02"],             # not canonical: "01" would come back as "1"
    ["-1", "0"],              # not whole numbers by isdigit
    ["a", "b"],
    ["1", "1"],
    ["²"],                    # isdigit() but int() refuses it
    ["١", "٢"],               # Arabic-Indic digits: int() reads them, str() writes "1", "2"
])
def test_anything_else_stays_a_list_and_comes_back_unchanged(ids):
    compact = compact_ids(ids)
    assert compact == ids
    assert expand_ids(json.loads(json.dumps(compact))) == ids


@pytest.mark.parametrize("data", [None, "0-3", {"from": 0}, {"count": 3}, {"from": "0", "count": 3},
                                  {"from": True, "count": 2}, {"from": 0, "count": -1}, [1.5], [None],
                                  [True]])
def test_ids_neither_range_nor_list_are_refused_naming_the_key(data):
    with pytest.raises(ValueError, match=r"^units\.ids"):
        expand_ids(data)


# --- Units round trip -----------------------------------------------------------------------------

def test_round_trip_keeps_everything_and_cuts_columns_into_lines():
    n = 2 * LINE + 5
    codes = "".join("pfe"[i % 3] for i in range(n))
    units = Units("scene", [str(i) for i in range(10, 10 + n)], {"scene": codes}, LEGEND, {"scene": "p"},
                  {"11": "at_fault at frame 4 (collision)"})
    data = json.loads(json.dumps(units.to_json()))
    assert data["ids"] == {"from": 10, "count": n}
    assert [len(line) for line in data["columns"]["scene"]] == [LINE, LINE, 5]
    assert Units.from_json(data) == units


def test_round_trip_of_named_units_keeps_the_list_and_every_column():
    units = Units("frame", ["a", "b", "c"], {"detection": "SWF", "non_detection": "-SF"},
                  {"S": "Success", "W": "Warn", "F": "Fail", "-": "not judged"},
                  {"detection": "SW-", "non_detection": "S-"}, {"c": "stamp_ns 3"})
    data = json.loads(json.dumps(units.to_json()))
    assert data["ids"] == ["a", "b", "c"]
    assert Units.from_json(data) == units


def test_one_changed_unit_changes_one_line():
    a = scenes("p" * (3 * LINE))
    b = scenes("p" * (LINE + 3) + "f" + "p" * (2 * LINE - 4))
    la, lb = a.to_json()["columns"]["scene"], b.to_json()["columns"]["scene"]
    assert [x == y for x, y in zip(la, lb)] == [True, False, True]


def good_json() -> dict:
    return scenes("pfp", reasons={"1": "why"}).to_json()


@pytest.mark.parametrize("mutate, key", [
    (lambda d: d.update(kind=3), "units.kind"),
    (lambda d: d.pop("kind"), "units.kind"),
    (lambda d: d.update(legend=["p"]), "units.legend"),
    (lambda d: d.update(legend={"pp": "passed"}), "units.legend"),
    (lambda d: d.update(legend={"p": 1}), "units.legend"),
    (lambda d: d.update(good=None), "units.good"),
    (lambda d: d.update(good={"scene": 1}), "units.good"),
    (lambda d: d.update(reasons=[]), "units.reasons"),
    (lambda d: d.update(reasons={"1": 2}), "units.reasons"),
    (lambda d: d.update(columns="pfp"), "units.columns"),
    (lambda d: d.update(columns={"scene": "pfp"}), "units.columns.scene"),
    (lambda d: d.update(columns={"scene": ["pf", 3]}), "units.columns.scene"),
    (lambda d: d.update(columns={"scene": ["pf"]}), "units.columns.scene"),       # too short
    (lambda d: d.update(columns={"scene": ["pfpp"]}), "units.columns.scene"),     # too long
    (lambda d: d.update(columns={"scene": ["pxp"]}), "units.columns.scene"),      # code not in the legend
    (lambda d: d.update(ids="0,1,2"), "units.ids"),
    (lambda d: d.update(ids={"from": 0, "count": 2}), "units.columns.scene"),     # 2 ids, 3 codes
    (lambda d: d.pop("ids"), "units.ids"),
])
def test_malformed_units_raise_a_value_error_naming_the_key(mutate, key):
    data = good_json()
    mutate(data)
    with pytest.raises(ValueError) as info:
        Units.from_json(data)
    assert str(info.value).startswith(key + ":") or str(info.value).startswith(key + " "), str(info.value)


def test_units_not_a_mapping_is_refused():
    with pytest.raises(ValueError, match="units: not a mapping"):
        Units.from_json(["p"])


def test_code_not_in_legend_is_named():
    with pytest.raises(ValueError, match=r"units.columns.scene: code\(s\) 'x', 'y' not in the legend"):
        scenes("pxy")


# --- unit_changes -------------------------------------------------------------------------------

def test_only_flipped_units_are_changes_with_direction_and_the_failing_sides_reason():
    before = scenes("ppffe", reasons={"2": "old reason 2", "3": "old reason 3", "4": "error: boom"})
    after = scenes("pfpfp", reasons={"1": "at_fault at frame 7 (collision)", "3": "new reason 3"})
    changes = unit_changes(before, after)
    assert [(c.unit, c.before, c.after, c.worse, c.reason) for c in changes] == [
        ("1", "passed", "failed", True, "at_fault at frame 7 (collision)"),
        ("2", "failed", "passed", False, "old reason 2"),
        ("4", "error", "passed", False, "error: boom"),
    ]


def test_a_bad_end_changing_into_another_bad_end_is_no_change():
    assert unit_changes(scenes("f"), scenes("e")) == []


def test_units_are_matched_by_id_not_position_and_new_or_gone_ones_are_skipped():
    before = scenes("pf", ids=["3", "5"])
    after = scenes("fpp", ids=["9", "5", "3"])
    assert [(c.unit, c.worse) for c in unit_changes(before, after)] == [("5", False)]


def test_columns_missing_on_one_side_are_skipped_and_each_column_judged_by_its_good_codes():
    legend = {"S": "Success", "W": "Warn", "F": "Fail", "-": "not judged"}
    before = Units("frame", ["0", "1"], {"detection": "WS", "non_detection": "SS"}, legend,
                   {"detection": "SW-", "non_detection": "S-"})
    after = Units("frame", ["0", "1"], {"detection": "SF", "extra": "FF", "non_detection": "WS"}, legend,
                  {"detection": "SW-", "non_detection": "S-", "extra": "S"})
    changes = unit_changes(before, after)
    # W -> S in detection is good -> good; W in non_detection is bad; "extra" has nothing to compare with
    assert [(c.unit, c.column, c.worse) for c in changes] == [("0", "non_detection", True),
                                                            ("1", "detection", True)]


# --- rules ----------------------------------------------------------------------------------------

DEFAULTS = {
    "max_displacement": FigureRule("lower", atol=0.01, rtol=0.01, unit="m"),
    "at_fault": FigureRule("lower"),
    "goal_rate": FigureRule("higher", paired=("outcome", "g"), unit="%"),
}


def spec(**data) -> RegressionSpec:
    return RegressionSpec.model_validate(data)


def test_effective_rules_without_a_section_are_the_defaults():
    rules = effective_rules(DEFAULTS, None)
    assert rules.figures == DEFAULTS
    assert rules.confidence == DEFAULT_CONFIDENCE == 95.0
    assert rules.units is True
    assert rules.search == SearchTolerance()


def test_overrides_replace_only_what_they_name_and_ignore_drops_the_figure():
    rules = effective_rules(DEFAULTS, spec(Figures={"max_displacement": {"Atol": 0.5},
                                                     "at_fault": {"Rtol": 0.2},
                                                     "goal_rate": {"Ignore": True}}, Units=False))
    assert rules.figures["max_displacement"] == FigureRule("lower", atol=0.5, rtol=0.01, unit="m")
    assert rules.figures["at_fault"] == FigureRule("lower", atol=0.0, rtol=0.2)
    assert "goal_rate" not in rules.figures
    assert rules.units is False


def test_an_override_of_zero_is_kept_not_taken_for_absent():
    rules = effective_rules(DEFAULTS, spec(Figures={"max_displacement": {"Atol": 0, "Rtol": 0}}))
    assert (rules.figures["max_displacement"].atol, rules.figures["max_displacement"].rtol) == (0, 0)


@pytest.mark.parametrize("section, conditions, expected", [
    (None, None, 95.0),
    (None, 90.0, 90.0),
    ({"Confidence": 99}, 90.0, 99.0),
    ({"Confidence": 80}, None, 80.0),
    ({}, 97.5, 97.5),
])
def test_confidence_precedence(section, conditions, expected):
    rules = effective_rules(DEFAULTS, spec(**section) if section is not None else None, conditions)
    assert rules.confidence == expected


@pytest.mark.parametrize("data", [
    {"Figure": {}},                                       # typo
    {"Figures": {"at_fault": {"atol": 1}}},
    {"Figures": {"at_fault": {"Atol": -0.1}}},
    {"Figures": {"at_fault": {"Rtol": -1}}},
    {"Figures": {"at_fault": {"Atol": float("inf")}}},
    {"Confidence": 50},
    {"Confidence": 100},
    {"Confidence": 120},
    {"Search": {"Tolerance": 0.1, "Extra": 1}},
    {"Search": {"RelativeTolerance": -0.1}},
    {"Search": {"Tolerance": -0.1}},
    {"Search": {"Tolerance": {"speed": -1}}},
    {"Units": "maybe"},
])
def test_regression_section_refuses_unknown_keys_and_out_of_range_values(data):
    with pytest.raises(ValidationError):
        RegressionSpec.model_validate(data)


def test_rules_round_trip_through_json():
    rules = effective_rules(DEFAULTS, spec(Confidence=90, Search={"Tolerance": {"speed": 0.5},
                                                                   "RelativeTolerance": 0.2}, Units=False))
    back = Rules.from_json(json.loads(json.dumps(rules.to_json())))
    assert back == rules
    assert back.figures["goal_rate"].paired == ("outcome", "g")
    assert back.figures["max_displacement"].unit == "m"


def test_rules_from_an_empty_record_are_the_plain_defaults():
    rules = Rules.from_json({})
    assert (rules.figures, rules.confidence, rules.units) == ({}, 95.0, True)


def test_search_tolerance_with_one_number_for_every_parameter():
    tolerance = SearchTolerance(Tolerance=0.5, RelativeTolerance=0.1)
    assert tolerance.allowed("speed", 2.0) == pytest.approx(0.7)
    assert tolerance.allowed("yaw", -4.0) == pytest.approx(0.9)


def test_search_tolerance_per_parameter_defaults_to_zero_for_others():
    tolerance = SearchTolerance(Tolerance={"speed": 0.5}, RelativeTolerance=0.0)
    assert tolerance.allowed("speed", 2.0) == 0.5
    assert tolerance.allowed("yaw", 2.0) == 0.0
    assert SearchTolerance().allowed("yaw", 2.0) == pytest.approx(0.2)  # the default 10 %


def test_figure_rule_direction_and_tolerance():
    lower, higher = FigureRule("lower", atol=0.1, rtol=0.5), FigureRule("higher")
    assert lower.worse_by(1.0, 1.5) == 0.5 and lower.worse_by(1.0, 0.5) == -0.5
    assert higher.worse_by(1.0, 1.5) == -0.5 and higher.worse_by(1.0, 0.5) == 0.5
    assert lower.tolerance(-2.0) == pytest.approx(1.1)
