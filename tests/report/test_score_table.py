"""The nuPlan score table of the reports: one row per scene, each term's value with the first frame it
failed at, "n/a" with its reason below."""
import pytest

from pytest_driveeval.report.score_table import score_html, score_markdown, score_rows, score_text

# a fast reader / score / report check: CI runs these at the lowest declared versions (-m smoke)
pytestmark = pytest.mark.smoke

TERMS = {"no_ego_at_fault_collisions": {"value": 0.5, "used": 0.5, "frames": [41, 42]},
         "drivable_area_compliance": {"value": 1.0, "used": 1.0},
         "ego_is_making_progress": {"value": 1.0, "used": 1.0},
         "driving_direction_compliance": {"value": 1.0, "used": 1.0},
         "ego_progress_along_expert_route": {"value": 0.8123, "used": 0.8123},
         "time_to_collision_within_bound": {"value": 0.0, "used": 0.0, "frames": [39]},
         "speed_limit_compliance": {"value": None, "used": 1.0, "reason": "no speed limit in the map"},
         "ego_is_comfortable": {"value": 1.0, "used": 1.0}}
DETAILS = {"scenes": [{"scene": 3, "score": 0.296, "score_terms": TERMS},
                      {"scene": 4, "error": "no frame"}]}


def test_a_row_per_scored_scene_with_frames_and_reasons():
    header, rows, notes = score_rows(DETAILS)
    assert header[:3] == ["scene", "score", "collisions"]
    assert rows == [["3", "0.296", "0.5 (frame 41)", "1", "1", "1", "0.812", "0 (frame 39)", "n/a", "1"]]
    assert notes == ["speed limit: no speed limit in the map"]


def test_markdown_html_and_text_carry_the_same_rows():
    markdown = "\n".join(score_markdown("scenarios/x.scenario.yaml::real", DETAILS))
    assert "#### nuPlan score per scene: `scenarios/x.scenario.yaml::real`" in markdown
    assert "| 3 | 0.296 | 0.5 (frame 41) |" in markdown and "- speed limit: no speed limit in the map" in markdown
    html = score_html(DETAILS)
    assert "<td>0 (frame 39)</td>" in html and "<li>speed limit: no speed limit in the map</li>" in html
    assert "0.5 (frame 41)" in score_text(DETAILS)


def test_nothing_for_items_without_a_score():
    assert score_markdown("a::b", {"scenes": [{"scene": 0}]}) == [] and score_html({}) == "" and score_text({}) == ""
