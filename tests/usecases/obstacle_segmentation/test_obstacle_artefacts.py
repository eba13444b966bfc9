"""The seam between judging frames and writing them: the judgement writes nothing,
the artefact sink writes result.jsonl and plots exactly as the use case always has."""
from __future__ import annotations

import hashlib

import pytest
import yaml
from conftest import REPO_ROOT

from pytest_driveeval.core.errors import DataError
from pytest_driveeval.obstacle import bag_pointclouds, evaluate_obstacle_segmentation
from pytest_driveeval.usecases.obstacle_segmentation.artefacts import ObstacleArtefacts
from pytest_driveeval.usecases.obstacle_segmentation.evaluate import ObstacleEvaluation
from pytest_driveeval.usecases.obstacle_segmentation.jsonl import read_jsonl

pytest.importorskip("rosbags")

DATASET = REPO_ROOT / "fixtures" / "t4" / "missed_object"   # the lead car's points are gone in odd frames
SCENARIO = REPO_ROOT / "scenario_tests" / "obstacle_segmentation" / "missed_object" / "scenario.yaml"
TOPIC = "/perception/obstacle_segmentation/pointcloud"
# sha256 of the result.jsonl this dataset and scenario gave before judging and writing were
# separated; driving_log_replayer's tools read these bytes, so they may change only on purpose.
JSONL_SHA256 = "33eae4ca343137c5fa43bdd9bb7f6dbb10427998507f365711eaf5b70f153d47"
ODD_FRAMES = [f"frame_{i}_{1_700_000_000_000_000_000 + i * 100_000_000}" for i in (1, 3, 5, 7, 9)]


@pytest.fixture(scope="module")
def evaluation() -> dict:
    return yaml.safe_load(SCENARIO.read_text())["Evaluation"]


def clouds():
    return bag_pointclouds(DATASET, TOPIC)


def test_judging_frames_writes_nothing(tmp_path, monkeypatch, evaluation):
    before = sorted(p.relative_to(DATASET) for p in DATASET.rglob("*"))
    monkeypatch.chdir(tmp_path)
    result = evaluate_obstacle_segmentation(DATASET, clouds(), evaluation)
    assert list(tmp_path.iterdir()) == []
    assert sorted(p.relative_to(DATASET) for p in DATASET.rglob("*")) == before
    assert result.summary == ("Failed: Detection (Fail): 5 / 10 -> 50.00% (Warn: 0), "
                              "NonDetection (Success): 10 / 10 -> 100.00%")


def test_the_artefact_sink_writes_the_same_jsonl_and_plots_as_before(tmp_path, evaluation):
    cfg = ObstacleEvaluation.load(DATASET, evaluation).cfg
    with ObstacleArtefacts(tmp_path / "result.jsonl", cfg.condition_record(), tmp_path) as artefacts:
        evaluate_obstacle_segmentation(DATASET, clouds(), evaluation, on_frame=artefacts)
    assert hashlib.sha256((tmp_path / "result.jsonl").read_bytes()).hexdigest() == JSONL_SHA256
    assert list(artefacts.files) == ["result", *ODD_FRAMES]
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([f"{n}.png" for n in ODD_FRAMES] + ["result.jsonl"])


def test_the_sink_sees_every_judged_frame_with_its_points(evaluation):
    seen = []

    def sink(frame, points, result):
        seen.append((frame.name, frame.failed, len(points), result.frames))

    result = evaluate_obstacle_segmentation(DATASET, clouds(), evaluation, on_frame=sink)
    assert [s[0] for s in seen] == result.frame_names
    assert [s[1] for s in seen] == [d == "Fail" for d in result.detection]
    assert [s[3] for s in seen] == list(range(1, result.frames + 1))  # called once the frame is counted
    assert all(n > 0 for _, _, n, _ in seen)


def test_a_data_error_keeps_the_judged_frames_and_the_final_line(tmp_path, evaluation):
    def three_then_broken():
        for i, cloud in enumerate(clouds()):
            if i == 3:
                raise DataError("bag ends early")
            yield cloud

    cfg = ObstacleEvaluation.load(DATASET, evaluation).cfg
    sink = ObstacleArtefacts(tmp_path / "result.jsonl", cfg.condition_record(), tmp_path, max_plots=0)
    with pytest.raises(DataError) as info, sink:
        evaluate_obstacle_segmentation(DATASET, three_then_broken(), evaluation, on_frame=sink)
    assert info.value.partial_result.frame_names == ["0", "1", "2"]
    lines = read_jsonl(tmp_path / "result.jsonl")
    assert len(lines) == 2 + 3 + 1 and "GraphData" in lines[-1]["Frame"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["result.jsonl"]


def test_bad_inputs_fail_before_a_sink_would_open(evaluation):
    bad = {**evaluation, "Conditions": {**evaluation["Conditions"], "Detection": {
        "PassRate": 99.0, "BoundingBoxConfig": [{"00000000000000000000000000000bad": None}]}}}
    with pytest.raises(DataError, match="00000000000000000000000000000bad"):
        ObstacleEvaluation.load(DATASET, bad)


def test_progress_counts_the_frames_judged_of_the_annotated_ones(evaluation):
    seen = []
    result = ObstacleEvaluation.load(DATASET, evaluation).run(
        clouds(), progress=lambda done, total: seen.append((done, total)))
    assert seen == [(done, 10) for done in range(11)] and result.frames == 10
