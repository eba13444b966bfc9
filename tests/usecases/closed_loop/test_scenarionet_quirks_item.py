"""A closed-loop item on ScenarioNet scenes as real datasets write them: a scene with degenerate map
features and jittering timestamps drives, and the item's details list what was skipped; an item
whose scenes are all refused says that no scene was scored instead of printing a mean of none."""
import json

import numpy as np

from conftest import REPO_ROOT, module_at

SCENARIO = """\
ScenarioFormatVersion: 3.0.0
ScenarioName: {name}
Evaluation:
  UseCaseName: closed_loop
  UseCaseFormatVersion: 0.1.0
  Datasets:
    - made: {{Path: {data}}}
  Model: log_replay
  Unroll: {{StartFrame: 10, Steps: 20}}
  Conditions:
    Score: {{MeanAtLeast: 0.5}}
"""


def _made():
    """tests/io/scenarionet_made.py, the reader tests' scenario maker (its folder is not on the path here)."""
    return module_at(REPO_ROOT / "tests" / "io" / "scenarionet_made.py", "scenarionet_made")


def _waymo_like(made, steps=40, gap=False):
    times = np.arange(steps) * 0.0999889 + np.where(np.arange(steps) % 2, 4e-5, 0.0)
    if gap:
        times[20:] += 0.1
    data = made.scenario(steps=steps, metadata__ts=times.astype(np.float32))
    del data["metadata"]["sample_rate"]  # Waymo's converter writes none
    data["map_features"]["204"] = {"type": "LANE_SURFACE_STREET", "polyline": np.array([[3.0, 4.0, 0.0]], np.float32)}
    return data


def test_a_scene_with_waymos_quirks_drives_and_the_details_say_what_was_skipped(pytester):
    made = _made()
    folder = pytester.path / "scenes"
    folder.mkdir()
    made.write(folder, _waymo_like(made), "sd_waymo.pkl")
    pytester.makefile(".scenario.yaml", quirks=SCENARIO.format(name="quirks", data=folder))
    pytester.runpytest("-p", "no:randomly")
    (record,) = json.loads((pytester.path / "driveeval-results" / "summary.json").read_text())["results"]
    assert record["figures"]["scenes"] == 1 and "score" in record["figures"]
    assert not [f for f in record["findings"] if "cannot be read" in f["message"]]
    (read,) = record["details"]["read"]
    assert read["scene"] == 0
    assert read["skipped"] == ["map feature 204 (LANE_SURFACE_STREET): not read: its polyline has 1 point(s); a line "
                               "needs 2"]
    assert read["notes"][0].startswith("timestamps jitter up to ") and "treated as 0.1 s" in read["notes"][0]


def test_an_item_whose_scenes_are_all_refused_prints_no_score_line(pytester):
    made = _made()
    folder = pytester.path / "scenes"
    folder.mkdir()
    made.write(folder, _waymo_like(made, gap=True), "sd_gap.pkl")
    pytester.makefile(".scenario.yaml", refused=SCENARIO.format(name="refused", data=folder))
    result = pytester.runpytest("-p", "no:randomly")
    (record,) = json.loads((pytester.path / "driveeval-results" / "summary.json").read_text())["results"]
    assert record["verdict"] == "failed" and record["figures"]["scenes"] == 0 and "score" not in record["figures"]
    messages = [f["message"] for f in record["findings"]]
    assert messages[0] == "no nuPlan score: no scene was scored; every scene asked for was refused (the reasons follow)"
    assert "a gap, a frame missing there" in messages[1]
    output = result.stdout.str()
    assert "no nuPlan score: no scene was scored" in output
    assert "mean nuPlan score" not in output and "over 0 scene(s)" not in output
