"""Key figures beside their baseline's in the terminal table and summary.md, from records as
results.item_record makes them (a comparison's JSON and the item's payload)."""
from __future__ import annotations

from pytest_driveeval.baseline.compare import compare
from pytest_driveeval.report.deltas import figure_deltas
from pytest_driveeval.report.summary import markdown_summary, terminal_rows, terminal_table

RULES = {"figures": {"goal_rate": {"better": "higher"}, "collision_rate": {"better": "lower"},
                     "max_displacement": {"better": "lower", "atol": 0.5}}}
AGAINST = "baseline `abc123` (2026-11-20T10:00:00+00:00)"


def payload(**figures) -> dict:
    return {"figures": figures, "rules": RULES, "fingerprint": None, "verdict": "passed"}


def record(nodeid: str, before: dict, after: dict, status: str = "passed") -> dict:
    comparison = compare(payload(**before), payload(**after), AGAINST, "bl/x.json")
    return {"nodeid": nodeid, "status": status, "verdict": "passed", "summary": f"{nodeid} ran",
            "use_case": "policy_benchmark", "figures": dict(after), "baseline": payload(**after),
            "comparison": comparison.to_json()}


def regressed() -> dict:
    return record("a.yaml::worse", {"goal_rate": 100.0, "collision_rate": 0.0, "max_displacement": 1.0},
                  {"goal_rate": 94.0, "collision_rate": 0.0, "max_displacement": 1.2}, status="failed")


def improved() -> dict:
    return record("b.yaml::better", {"goal_rate": 90.0, "collision_rate": 5.0, "max_displacement": 3.0},
                  {"goal_rate": 90.0, "collision_rate": 5.0, "max_displacement": 1.0})


def not_compared(status: str, note: str) -> dict:
    return {"nodeid": f"c.yaml::{status}", "status": "passed", "summary": "ran", "figures": {"goal_rate": 50.0},
            "baseline": payload(goal_rate=50.0),
            "comparison": {"status": status, "against": "", "message": note, "changes": []}}


def test_a_figure_shows_its_baseline_value_the_change_and_whether_the_gate_counted_it():
    deltas = {d.name: d for d in figure_deltas(regressed())}
    assert deltas["goal_rate"].text() == "goal_rate=94 (100, ▼6)" and deltas["goal_rate"].tone == "worse"
    assert deltas["collision_rate"].text() == "collision_rate=0 (0, =)" and deltas["collision_rate"].tone is None
    # Worse by the rules' direction, but inside its tolerance: neither a number nor a colour.
    moved = deltas["max_displacement"]
    assert moved.text() == "max_displacement=1.2 (1, ≈)" and moved.direction == "worse" and moved.tone is None
    better = {d.name: d for d in figure_deltas(improved())}["max_displacement"]
    assert better.text() == "max_displacement=1 (3, ▼2)" and better.tone == "better"


def test_float_noise_within_the_tolerance_is_no_change_and_a_move_beyond_it_is_shown():
    noise = record("n.yaml::noise", {"goal_rate": 50.0, "max_displacement": 10.85},
                   {"goal_rate": 50.0, "max_displacement": 10.85 - 1.058e-07})
    assert [d.text() for d in figure_deltas(noise)] == ["goal_rate=50 (50, =)", "max_displacement=10.85 (10.85, ≈)"]
    # A rate tested paired (no tolerance of its own) keeps its move, uncoloured when not counted.
    paired = {"better": "higher", "paired": ["outcome", "g"]}
    rules = {"figures": {"goal_rate": paired}}
    item = record("p.yaml::rate", {"goal_rate": 100.0}, {"goal_rate": 94.0})
    item["baseline"]["rules"] = rules
    item["comparison"]["changes"] = []
    (delta,) = figure_deltas(item)
    assert delta.text() == "goal_rate=94 (100, ▼6)" and delta.tone is None


def test_nothing_beside_the_figures_of_an_item_that_was_not_compared():
    assert figure_deltas(not_compared("stale", "stale baseline: the seed changed")) == []
    assert figure_deltas({"nodeid": "x", "figures": {"goal_rate": 1.0}}) == []


def test_terminal_table_shows_status_baseline_values_and_colours_only_counted_changes():
    records = [regressed(), improved(), not_compared("missing", "no baseline yet")]
    text = "\n".join(terminal_table(records, 200))
    assert "baseline: regressed; goal_rate=94 (100, ▼6), collision_rate=0 (0, =), max_displacement=1.2 (1, ≈)" \
        in text
    assert "baseline: improved; goal_rate=90 (90, =), collision_rate=5 (5, =), max_displacement=1 (3, ▼2)" in text
    assert "baseline: missing; goal_rate=50" in text
    toned = {text: tone for line in terminal_rows(records, 200) for text, tone in line if tone}
    assert toned == {"baseline: regressed": "worse", "goal_rate=94 (100, ▼6)": "worse",
                     "baseline: improved": "better", "max_displacement=1 (3, ▼2)": "better",
                     "baseline: missing": "note"}


def test_a_stale_baseline_says_why_in_the_terminal_table():
    records = [not_compared("stale", "stale baseline `abc` (2026-11-20): the seed changed (1 -> 2) since it was "
                                     "made; not compared (update the baseline)")]
    text = "\n".join(terminal_table(records, 300))
    assert "baseline: stale baseline `abc` (2026-11-20): the seed changed (1 -> 2) since it was made; not compared " \
           "(update the baseline); goal_rate=50" in text


def test_a_narrow_terminal_wraps_a_coloured_figure_and_keeps_its_colour():
    rows = terminal_rows([regressed()], 48)
    plain = ["".join(t for t, _ in line) for line in rows]
    assert all(len(line) <= 48 for line in plain[1:])
    assert any(t == "goal_rate=94 (100, ▼6)," or t == "goal_rate=94 (100, ▼6)"
               for line in rows for t, tone in line if tone == "worse")


def test_markdown_has_a_baseline_column_deltas_and_what_the_comparisons_found():
    summary = {"counts": {"failed": 1, "passed": 3}, "run": {"id": "R"},
               "results": [regressed(), improved(), not_compared("missing", "no baseline yet: run with "
                                                                "--driveeval-baseline-update"),
                           not_compared("stale", "stale baseline: the seed changed (1 -> 2)")]}
    markdown = markdown_summary(summary)
    assert "| verdict | scenario | use case | summary | key figures | baseline |" in markdown
    assert ("| `a.yaml::worse` | policy_benchmark | a.yaml::worse ran | 🔴 goal_rate=94 (100, ▼6), "
            "collision_rate=0 (0, =), max_displacement=1.2 (1, ≈) | 🔴 regressed |") in markdown
    assert "🟢 max_displacement=1 (3, ▼2) | 🟢 improved |" in markdown
    section = markdown.split(f"### Compared with {AGAINST}")[1].split("###")[0]
    assert section.strip().splitlines() == [
        "- 🔴 regressed: `a.yaml::worse`",
        "  - goal_rate 100 -> 94 (higher is better; tolerance 0)",
        "- 🟢 improved: `b.yaml::better`",
        "  - max_displacement 3 -> 1 (better; tolerance 0.5)"]
    missing = markdown.split("### Not compared")[1]
    assert "- 🟡 missing: `c.yaml::missing`: no baseline yet: run with --driveeval-baseline-update" in missing
    assert "- 🟡 stale: `c.yaml::stale`: stale baseline: the seed changed (1 -> 2)" in missing


def test_markdown_without_comparisons_keeps_its_columns():
    plain = {"nodeid": "a.yaml::x", "status": "passed", "summary": "ok", "figures": {"goal_rate": 50.0}}
    markdown = markdown_summary({"counts": {"passed": 1}, "results": [plain]})
    assert "| verdict | scenario | use case | summary | key figures |\n" in markdown
    assert "Compared with" not in markdown and "Not compared" not in markdown
