"""obstacle_segmentation end to end: driving_log_replayer's own scenario files on generated datasets."""
from __future__ import annotations

import json
import re
import shutil

import pytest

from pytest_driveeval.usecases.obstacle_segmentation.jsonl import (
    key_structure,
    merge_structures,
    read_jsonl,
)

t4gen = pytest.importorskip("pytest_driveeval.synth.t4gen")

DLR_FILES = ("scenario.yaml", "scenario_detection_only.yaml", "scenario_non_detection_only.yaml")


@pytest.fixture(scope="session")
def datasets(tmp_path_factory):
    root = tmp_path_factory.mktemp("t4")
    return {d or "clean": t4gen.generate_t4_dataset(root / (d or "clean"), num_frames=8, seed=3, defect=d).root
            for d in t4gen.DEFECTS}


def dlr_scenario(shared_data, name: str, dataset) -> str:
    text = (shared_data / "driving_log_replayer" / "obstacle_segmentation" / name).read_text()
    return re.sub(r"(\n( +)VehicleId: default[^\n]*)", rf"\1\n\2Path: {dataset}", text, count=1)


def summary(pytester) -> dict:
    data = json.loads((pytester.path / "driveeval-results" / "summary.json").read_text())
    return {r["nodeid"]: r for r in data["results"]}


def test_dlr_scenarios_pass_on_a_clean_dataset_and_write_their_jsonl(pytester, shared_data, datasets):
    for name in DLR_FILES:
        sub = pytester.mkdir(name.replace(".yaml", ""))
        (sub / "scenario.yaml").write_text(dlr_scenario(shared_data, name, datasets["clean"]))
    pytester.runpytest("-q").assert_outcomes(passed=3)
    records = summary(pytester)
    assert all(r["figures"]["frames"] == 8 and r["figures"]["frames_skipped"] == 0 for r in records.values())
    out = pytester.path / "driveeval-results"
    full = next(r for k, r in records.items() if k.startswith("scenario/"))
    lines = read_jsonl(out / full["artefacts"]["result"])
    assert list(lines[0]) == ["Condition"] and lines[1]["Result"]["Summary"] == "NoData"
    assert lines[-2]["Result"]["Summary"] == ("Passed: Detection (Success): 8 / 8 -> 100.00% (Warn: 0), "
                                              "NonDetection (Success): 8 / 8 -> 100.00%")
    # every key driving_log_replayer writes, we write (we add Objects and, on errors, Error)
    real = read_jsonl(shared_data / "driving_log_replayer" / "obstacle_segmentation" / "result.json")
    ours = merge_structures(key_structure(r) for r in lines[2:-1])
    theirs = merge_structures(key_structure(r) for r in real[2:-1])
    assert key_structure(lines[0]) == key_structure(real[0])

    def missing(a, b, path=""):
        if not isinstance(b, dict):
            return []
        return [m for k, v in b.items() for m in ([f"{path}.{k}"] if not isinstance(a, dict) or k not in a
                                                    else missing(a[k], v, f"{path}.{k}"))]
    # Info holds one key per verdict kind seen; a clean run has no DetectionFail
    assert [m for m in missing(ours, theirs) if not re.search(r"\.Info\.\w+$", m)] == []
    assert set(lines[-1]) == set(real[-1]) and "GraphData" in lines[-1]["Frame"]


@pytest.mark.parametrize("defect, part, what", [("missed_object", "Detection", "Fail (0 point(s))"),
                                                 ("ghost_points", "NonDetection", "point(s) in the non-detection")])
def test_defects_fail_naming_frames_and_uuids_with_plots(pytester, shared_data, datasets, defect, part, what):
    pytester.makefile(".scenario.yaml", bad=dlr_scenario(shared_data, "scenario.yaml", datasets[defect]))
    result = pytester.runpytest("-q")
    result.assert_outcomes(failed=1)
    result.stdout.fnmatch_lines([f"*{part}: 4 / 8 frame(s) passed (50.00%), 99% required; frame 1 @ *{what}*"])
    if defect == "missed_object":
        result.stdout.fnmatch_lines(["*UUID dcb2b352232fff50c4fad23718f31611 Fail*"])
    (record,) = summary(pytester).values()
    pngs = [k for k in record["artefacts"] if k.startswith("frame_")]
    assert len(pngs) == 4 and all((pytester.path / "driveeval-results" / record["artefacts"][k]).stat().st_size
                                  > 5000 for k in pngs)


def test_bad_inputs_are_located_and_the_rest_runs(pytester, shared_data, datasets):
    good = dlr_scenario(shared_data, "scenario_non_detection_only.yaml", datasets["clean"])
    pytester.makefile(".scenario.yaml", good=good)
    ccw = good.replace("- [10.0, 1.5]\n          - [10.0, -1.5]\n          - [0.0, -1.5]\n          - [0.0, 1.5]",
                       "- [0.0, 1.5]\n          - [0.0, -1.5]\n          - [10.0, -1.5]\n          - [10.0, 1.5]")
    pytester.makefile(".scenario.yaml", ccw=ccw)
    uuid = dlr_scenario(shared_data, "scenario_detection_only.yaml", datasets["clean"]).replace(
        "dcb2b352232fff50c4fad23718f31611", "00000000000000000000000000000bad")
    pytester.makefile(".scenario.yaml", uuid=uuid)
    broken = pytester.path / "broken"
    shutil.copytree(datasets["clean"], broken)
    db = next((broken / "input_bag").glob("*.db3"))
    db.write_bytes(db.read_bytes()[: db.stat().st_size // 3])
    pytester.makefile(".scenario.yaml", truncated=good.replace(str(datasets["clean"]), str(broken)))
    topic = good.replace("  SensingEvaluationConfig:", "  PointCloud: {Topic: /no/such/topic}\n  SensingEvaluationConfig:")
    pytester.makefile(".scenario.yaml", topic=topic)
    result = pytester.runpytest("-q")
    result.assert_outcomes(passed=1, failed=4)
    result.stdout.fnmatch_lines([
        ("*ccw.scenario.yaml:18: Evaluation.Conditions.NonDetection.ProposedArea.polygon_2d: the polygon is "
         "counter-clockwise*list the same vertices in reverse order*"),
        ("*uuid.scenario.yaml:17: Evaluation.Conditions.Detection.BoundingBoxConfig[[]0[]]."
         "00000000000000000000000000000bad: UUID '00000000000000000000000000000bad' is not an instance*"),
    ])
    result.stdout.fnmatch_lines(["*topic '/no/such/topic' not in bag; available:*"])
    assert re.search(r"truncated.*(cannot open bag|corrupt or truncated)", result.stdout.str(), re.DOTALL)


def test_pointcloud_filter_fixture_and_parallel_runs_agree(pytester, shared_data, datasets):
    text = dlr_scenario(shared_data, "scenario_detection_only.yaml", datasets["clean"]).replace(
        "  SensingEvaluationConfig:", "  PointCloud: {RawTopic: /perception/obstacle_segmentation/pointcloud}\n"
                                      "  SensingEvaluationConfig:")
    sub = pytester.mkdir("filtered")
    (sub / "scenario.yaml").write_text(text)
    (sub / "conftest.py").write_text(
        "import pytest\n\n@pytest.fixture\ndef driveeval_pointclouds():\n"
        "    return lambda points: points[points['x'] < 0]   # a filter that drops everything ahead\n")
    (pytester.path / "plain.scenario.yaml").write_text(text)
    pytester.runpytest("-q").assert_outcomes(passed=1, failed=1)
    serial = {k: (r["status"], r["summary"]) for k, r in summary(pytester).items()}
    pytester.runpytest("-q", "-n", "2").assert_outcomes(passed=1, failed=1)
    assert {k: (r["status"], r["summary"]) for k, r in summary(pytester).items()} == serial
    assert serial["filtered/scenario.yaml::obstacle_segmentation[sample_dataset]"][0] == "failed"


def test_t4_sample_sweep_without_bag_is_one_frame(pytester, shared_data):
    (pytester.path / "obs.scenario.yaml").write_text(
        "ScenarioFormatVersion: 3.0.0\nScenarioName: sweep\nEvaluation:\n  UseCaseName: obstacle_segmentation\n"
        "  UseCaseFormatVersion: 0.1.0\n  Datasets:\n    - t4_sample:\n        Path: "
        f"{shared_data / 't4_sample'}\n  Conditions:\n    ObstacleDetection: {{PassRate: 100.0}}\n"
        "    NonDetection: null\n  SensingEvaluationConfig:\n    evaluation_config_dict:\n"
        "      target_uuids: null\n      min_points_threshold: 1\n")
    pytester.runpytest("-q").assert_outcomes(passed=1)
    (record,) = summary(pytester).values()
    assert record["figures"]["frames"] == 1 and record["figures"]["detection_rate"] == 100.0
    assert "topic rate unknown" in record["summary"]


def test_a_filter_that_never_returns_fails_its_item_naming_the_cloud_and_keeps_the_judged_frames(
        pytester, shared_data, datasets):
    text = dlr_scenario(shared_data, "scenario_detection_only.yaml", datasets["clean"]).replace(
        "  SensingEvaluationConfig:", "  PointCloud: {RawTopic: /perception/obstacle_segmentation/pointcloud}\n"
                                      "  SensingEvaluationConfig:").replace("Evaluation:", "TimeLimit: 2\nEvaluation:", 1)
    sub = pytester.mkdir("hangs")
    (sub / "scenario.yaml").write_text(text)
    (sub / "conftest.py").write_text(
        "import time\nimport pytest\n\ncalls = []\n\n@pytest.fixture\ndef driveeval_pointclouds():\n"
        "    def stuck_on_the_fourth(points):\n        calls.append(1)\n"
        "        if len(calls) == 4:\n            time.sleep(3600)\n        return points\n"
        "    return stuck_on_the_fourth\n")
    (pytester.path / "plain.scenario.yaml").write_text(text)
    result = pytester.runpytest("-q", "-p", "no:randomly")
    result.assert_outcomes(passed=1, failed=1)
    result.stdout.fnmatch_lines(["*TimeLimitExceeded: scenario *: time limit of 2 s exceeded in a model call that "
                                 "did not return at the point-cloud filter on the cloud stamped * ns*"])
    record = summary(pytester)["hangs/scenario.yaml::obstacle_segmentation[sample_dataset]"]
    assert record["status"] == "failed" and record["figures"]["frames"] == 3
