"""The compare command's rows from hand-made sides (no session): float noise within a figure's
tolerance is no change, and --only-changed puts the regressions first and sums up the items only
one side ran."""
from __future__ import annotations

import json

from pytest_driveeval.baseline.cli import Side, compare_sides, figure_text, render_json, render_text, select
from pytest_driveeval.baseline.rules import effective_rules
from pytest_driveeval.usecases.closed_loop.regression import FIGURES as CLOSED_LOOP

RULES = effective_rules(CLOSED_LOOP, None).to_json()


def payload(nodeid: str, **figures) -> dict:
    return {"key": {"nodeid": nodeid}, "verdict": "passed", "summary": "ran", "use_case": "closed_loop",
            "figures": {"at_fault": 0, "max_displacement": 10.85, **figures}, "rules": RULES, "fingerprint": None}


def sides() -> tuple[Side, Side]:
    a, b = Side("A", "run a", "a/summary.json"), Side("B", "run b", "b/summary.json")
    for i in range(41):  # a full run against a subset run: most items only in A
        a.payloads[f"sub/s{i:02}.yaml::closed_loop[x]"] = payload(f"s{i}")
    for name in ("m.yaml::worse", "z.yaml::worse"):
        a.payloads[name], b.payloads[name] = payload(name), payload(name, at_fault=2)
    a.payloads["n.yaml::noise"] = payload("n")
    b.payloads["n.yaml::noise"] = payload("n", max_displacement=10.85 - 1.058e-07)
    a.payloads["b.yaml::better"] = payload("b", at_fault=1)
    b.payloads["b.yaml::better"] = payload("b")
    return a, b


def test_float_noise_within_the_tolerance_is_shown_as_no_change():
    rows = {r.nodeid: r for r in compare_sides(*sides())}
    noise = rows["n.yaml::noise"]
    assert noise.status == "unchanged" and not noise.changed
    moved = next(f for f in noise.figures if f.name == "max_displacement")
    assert moved.within and figure_text(moved, noise.status, ("↑", "↓", "≈")) == \
        "max_displacement 10.85 -> 10.85 (≈ within tolerance)"
    # A move the rule counts is still shown as a number.
    worse = next(f for f in rows["m.yaml::worse"].figures if f.name == "at_fault")
    assert figure_text(worse, "regressed", ("↑", "↓", "≈")) == "at_fault 0 -> 2 (+2 ↑ worse)"


def test_only_changed_lists_the_regressions_first_and_sums_up_what_only_one_side_ran():
    a, b = sides()
    rows = compare_sides(a, b)
    selection = select(rows, a, b, only_changed=True)
    assert [r.nodeid for r in selection.shown] == ["m.yaml::worse", "z.yaml::worse", "b.yaml::better"]
    assert selection.folded == ["41 item(s) only in A (not run in B, b/summary.json); without --only-changed they "
                                "are listed"]
    lines = render_text(a, b, rows, selection, 200)
    statuses = [line.split("  ")[0] for line in lines[3:] if line[:1] != " "]
    assert statuses[:3] == ["regressed", "regressed", "improved"]
    assert lines[-2:] == [selection.folded[0], "2 regressed, 1 improved, 1 unchanged, 41 only in A "
                                               "(1 unchanged not shown)"]
    assert len(lines) < 20  # not one block per item only in A
    assert json.loads(render_json(a, b, rows, selection))["folded"] == selection.folded
    # Without --only-changed every row is there, in node id order.
    everything = select(rows, a, b, only_changed=False)
    assert len(everything.shown) == len(rows) == 45 and everything.folded == []
