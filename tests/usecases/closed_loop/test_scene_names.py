"""Scenes named by what they are in the data, beside their index: the identity per format, the
wording messages use, GIF names that stay safe file names, and findings named once wherever
they were made.  The whole runs (messages, summary.json, closed_loop.json, GIFs) are tested in
test_closed_loop_usecase.py and test_scenarionet_datasets.py."""
from __future__ import annotations

import pytest
from conftest import REPO_ROOT

from pytest_driveeval.core.filenames import NAME_PART_MAX, safe_name_part
from pytest_driveeval.core.outcome import Finding
from pytest_driveeval.usecases.closed_loop.names import (
    caption,
    gif_name,
    name_findings,
    name_verdicts,
    named,
    scene_identity,
    scene_label,
)

FIXTURE_SCENES = REPO_ROOT / "fixtures" / "scenarionet" / "nuscenes"
ZARR = REPO_ROOT / "fixtures" / "l5kit" / "single_scene.zarr"


def test_an_l5_scene_is_its_index_and_its_zarr():
    from pytest_driveeval.io.l5.l5kit_zarr import L5Dataset

    identity = scene_identity(L5Dataset.open(ZARR), 0)
    assert identity == {"index": 0, "zarr": "single_scene.zarr"}
    assert named(0, identity) == "scene 0 (single_scene.zarr)"
    assert gif_name(0, identity) == "scene_0_single_scene.gif"


def test_a_scenarionet_scene_is_its_scenario_id_and_its_file():
    from pytest_driveeval.io.scenarionet.scenarionet_l5 import ScenarioNetDataset

    identity = scene_identity(ScenarioNetDataset.open(FIXTURE_SCENES), 2)
    assert identity == {"index": 2, "file": "sd_nuscenes_v1.0-mini_scene-0757.pkl", "scenario_id": "scene-0757"}
    assert named(2, identity) == "scene 2 (scenario scene-0757, sd_nuscenes_v1.0-mini_scene-0757.pkl)"
    assert gif_name(2, identity) == "scene_2_scene-0757.gif"
    assert caption(2, identity) == "scene 2 (scene-0757)"


def test_a_scenario_file_that_cannot_be_read_is_named_by_its_file(tmp_path):
    from pytest_driveeval.io.scenarionet.scenarionet_l5 import ScenarioNetDataset

    (tmp_path / "sd_cut.pkl").write_bytes((FIXTURE_SCENES / "sd_nuscenes_v1.0-mini_scene-0103.pkl").read_bytes()[:999])
    identity = scene_identity(ScenarioNetDataset.open(tmp_path), 0)
    assert identity == {"index": 0, "file": "sd_cut.pkl"}
    assert scene_label(identity) == "sd_cut.pkl" and gif_name(0, identity) == "scene_0_sd_cut.gif"


def test_a_scene_known_to_be_broken_is_not_read_again_to_name_it():
    from types import SimpleNamespace

    def source(index):
        raise AssertionError("read again")

    dataset = SimpleNamespace(files=["a/sd_x.pkl"], source=source, num_scenes=1)
    assert scene_identity(dataset, 0, read=False) == {"index": 0, "file": "sd_x.pkl"}
    problem = Finding("scene 0 cannot be read: sd_x.pkl is truncated", scene=0)
    assert name_verdicts(dataset, [], [problem]) == {0: {"index": 0, "file": "sd_x.pkl"}}
    assert problem.message == "scene 0 (sd_x.pkl) cannot be read: sd_x.pkl is truncated"


def test_a_dataset_object_that_says_nothing_keeps_the_bare_index():
    identity = scene_identity(object(), 4)
    assert identity == {"index": 4} and named(4, identity) == "scene 4"
    assert gif_name(4, identity) == "scene_4.gif" and caption(4, identity) == "scene 4"


@pytest.mark.parametrize("scenario_id", [
    "../../etc/passwd", "a/b\\c", "id with spaces and ünïcode", ".hidden", "x" * 300, "a:b*c?d|e<f>g\"h", "\x00\n",
])
def test_gif_names_stay_safe_file_names(tmp_path, scenario_id):
    name = gif_name(7, {"index": 7, "scenario_id": scenario_id, "file": "f.pkl"})
    assert "/" not in name and "\\" not in name and not name.startswith(".")
    assert name.startswith("scene_7_") and name.endswith(".gif")
    assert len(name) <= len("scene_7_.gif") + NAME_PART_MAX
    (tmp_path / name).write_bytes(b"GIF")  # the file system takes it, in the folder asked for
    assert [p.name for p in tmp_path.iterdir()] == [name]


def test_a_long_id_keeps_its_start_and_end_so_two_long_ids_stay_apart():
    a, b = "waymo_" + "0" * 100 + "_a", "waymo_" + "0" * 100 + "_b"
    assert safe_name_part(a) != safe_name_part(b) and len(safe_name_part(a)) == NAME_PART_MAX
    assert safe_name_part(a).startswith("waymo_") and safe_name_part(a).endswith("_a")


def test_findings_are_named_once_and_only_their_own_scene():
    findings = [Finding("scene 1: 2 front collision frame(s)", scene=1),
                Finding("scene 10: drift", scene=10),
                Finding("scene 1 cannot be read: x.pkl is truncated", scene=1),
                Finding("scene 12345 is out of range", scene=12345),
                Finding("mean nuPlan score 0.5 over 2 scene(s) < 0.8")]
    names = {1: "scene 1 (scenario a, a.pkl)", 10: "scene 10 (scenario b, b.pkl)"}
    name_findings(findings, names)
    name_findings(findings, names)  # a second pass (a search's replay) names nothing twice
    assert [f.message for f in findings] == [
        "scene 1 (scenario a, a.pkl): 2 front collision frame(s)", "scene 10 (scenario b, b.pkl): drift",
        "scene 1 (scenario a, a.pkl) cannot be read: x.pkl is truncated", "scene 12345 is out of range",
        "mean nuPlan score 0.5 over 2 scene(s) < 0.8"]


def test_verdicts_from_anywhere_get_their_identity_and_named_findings():
    from pytest_driveeval.io.scenarionet.scenarionet_l5 import ScenarioNetDataset
    from pytest_driveeval.usecases.closed_loop.evaluate import SceneVerdict

    dataset = ScenarioNetDataset.open(FIXTURE_SCENES)
    verdict = SceneVerdict(1, False, {}, [Finding("scene 1: 3 reset(s) on drift, 0 allowed", scene=1)])
    problem = Finding("scene 5 is out of range: scenes 0..2", scene=5)
    identities = name_verdicts(dataset, [verdict], [problem])
    file = "sd_nuscenes_v1.0-mini_scene-0553.pkl"
    assert identities == {1: {"index": 1, "file": file, "scenario_id": "scene-0553"}}
    assert verdict.findings[0].message.startswith(f"scene 1 (scenario scene-0553, {file}): ")
    assert problem.message == "scene 5 is out of range: scenes 0..2"


def test_the_python_api_names_the_scene_in_its_assertion_messages():
    pytest.importorskip("torch")
    from pytest_driveeval.io.l5.l5kit_zarr import L5Dataset
    from pytest_driveeval.usecases.closed_loop.assertions import assert_drift_within
    from pytest_driveeval.usecases.closed_loop.baselines import baseline
    from pytest_driveeval.usecases.closed_loop.evaluate import unroll_scenes

    dataset = L5Dataset.open(ZARR)
    unroll = unroll_scenes(dataset, baseline("constant_velocity", None), [0], start_frame=10, steps=60,
                           drift_threshold=None)
    assert unroll.scene_name(0) == "scene 0 (single_scene.zarr)"
    with pytest.raises(AssertionError, match=r"^scene 0 \(single_scene\.zarr\): displacement"):
        assert_drift_within(unroll, meters=0.01)


def test_the_score_table_shows_the_index_and_the_name():
    from pytest_driveeval.report.score_table import score_rows

    terms = {"no_ego_at_fault_collisions": {"value": 1.0}}
    _, rows, _ = score_rows({"scenes": [{"scene": 3, "name": "scenario scene-0061, sd_x.pkl", "score": 1.0,
                                         "score_terms": terms},
                                        {"scene": 4, "score": 1.0, "score_terms": terms}]})
    assert [row[0] for row in rows] == ["3 (scenario scene-0061, sd_x.pkl)", "4"]


def test_baseline_units_stay_keyed_by_index():
    """Old baselines keep matching: a scene's unit is its index, the name only rides along."""
    from pytest_driveeval.core.outcome import Outcome
    from pytest_driveeval.usecases.closed_loop.regression import scene_units

    outcome = Outcome("closed_loop", "failed", "", details={"scenes": [
        {"scene": 0, "name": "scenario a, a.pkl", "identity": {"index": 0}, "passed": True, "error": None},
        {"scene": 1, "name": "scenario b, b.pkl", "identity": {"index": 1}, "passed": False, "error": None}]},
        findings=[Finding("scene 1 (scenario b, b.pkl): drift", scene=1, figure="Displacement")])
    units = scene_units(outcome)
    assert units is not None and list(units.ids) == ["0", "1"]


CHUNKED = """\
ScenarioFormatVersion: 3.0.0
ScenarioName: chunked
Evaluation:
  UseCaseName: closed_loop
  UseCaseFormatVersion: 0.1.0
  Datasets:
    - nuscenes: {{Path: {data}}}
  Model: constant_velocity
  Unroll: {{Scenes: [0, 2], StartFrame: 10, Steps: 30}}
  Conditions:
    Collisions: {{Front: 0, Side: 0, Rear: 0}}
    Displacement: {{Max: 0.01}}
  Artefacts: {{Animations: all}}
  Executor: {{Kind: local, ChunkSize: 1}}
"""


def test_scenes_judged_in_chunks_are_named_where_the_item_runs(pytester):
    """Chunks judge and draw on their own process (here: local ones); the item names what they return."""
    import json

    pytester.makefile(".scenario.yaml", chunked=CHUNKED.format(data=FIXTURE_SCENES))
    pytester.runpytest("-p", "no:randomly").assert_outcomes(failed=1)
    (record,) = json.loads((pytester.path / "driveeval-results" / "summary.json").read_text())["results"]
    assert [c["work"] for c in record["details"]["executor"]["chunks"]] == ["scenes 0..0 of nuscenes",
                                                                            "scenes 2..2 of nuscenes"]
    assert [s["name"] for s in record["details"]["scenes"]] == [
        "scenario scene-0103, sd_nuscenes_v1.0-mini_scene-0103.pkl",
        "scenario scene-0757, sd_nuscenes_v1.0-mini_scene-0757.pkl"]
    drift = [f["message"] for f in record["findings"] if f.get("figure") == "Displacement"]
    assert drift and all(m.startswith(("scene 0 (scenario scene-0103, ", "scene 2 (scenario scene-0757, "))
                         for m in drift)
    assert record["artefacts"]["scene_0_gif"].endswith("/scene_0_scene-0103.gif")
    assert record["artefacts"]["scene_2_gif"].endswith("/scene_2_scene-0757.gif")
