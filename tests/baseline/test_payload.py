"""What a run keeps of an item (payload.py): the dataset's identity, the fingerprint's settings,
and the payload of each use case's outcome, built from hand-made Outcomes like the ones the use
cases return."""
from __future__ import annotations

import json
import os
import shutil
from pathlib import Path
from types import SimpleNamespace

import pytest

from pytest_driveeval.baseline import payload as payload_module
from pytest_driveeval.baseline.compare import REGRESSED, compare
from pytest_driveeval.baseline.payload import (NOT_FINGERPRINT, PAYLOAD_VERSION, dataset_identity, fingerprint,
                                               make_payload, settings_of)
from pytest_driveeval.baseline.rules import RegressionSpec
from pytest_driveeval.baseline.units import Units
from pytest_driveeval.core.outcome import FAILED, PASSED, Finding, Outcome
from pytest_driveeval.scenario.loaded import DatasetRef
from pytest_driveeval.core.usecase import get_usecase
from pytest_driveeval.usecases.policy_benchmark.regression import episode_outcomes


def ref(path: Path, name: str = "data") -> DatasetRef:
    return DatasetRef(name, path, {}, None)


# --- dataset identity -----------------------------------------------------------------------------

def make_dataset(folder: Path) -> Path:
    (folder / "sub").mkdir(parents=True)
    (folder / "a.bin").write_bytes(b"abc" * 100)
    (folder / "sub" / "b.json").write_text('{"x": 1}')
    return folder


def test_identical_copies_at_different_paths_have_one_identity(tmp_path):
    one = make_dataset(tmp_path / "one")
    two = tmp_path / "elsewhere" / "two"
    shutil.copytree(one, two)
    a, b = dataset_identity(ref(one)), dataset_identity(ref(two))
    assert a == b
    assert str(tmp_path) not in json.dumps(a)
    assert a["files"] == 2 and a["bytes"] == 308 and a["name"] == "data"


def test_a_changed_file_changes_the_identity(tmp_path):
    one = make_dataset(tmp_path / "one")
    before = dataset_identity(ref(one))
    target = one / "sub" / "b.json"
    stat = target.stat()
    target.write_text('{"x": 2}')  # same size
    os.utime(target, ns=(stat.st_atime_ns, stat.st_mtime_ns + 10 ** 9))
    assert dataset_identity(ref(one))["sha256"] != before["sha256"]


def test_a_renamed_file_changes_the_identity(tmp_path):
    one = make_dataset(tmp_path / "one")
    before = dataset_identity(ref(one))
    (one / "a.bin").rename(one / "c.bin")
    assert dataset_identity(ref(one))["sha256"] != before["sha256"]


def test_a_single_file_dataset_copied_under_another_name_keeps_its_identity(tmp_path):
    (tmp_path / "a").mkdir()
    (tmp_path / "a" / "log.bag").write_bytes(b"rosbag" * 50)
    shutil.copy(tmp_path / "a" / "log.bag", tmp_path / "log_copy.bag")
    assert dataset_identity(ref(tmp_path / "a" / "log.bag")) == dataset_identity(ref(tmp_path / "log_copy.bag"))
    (tmp_path / "other.bag").write_bytes(b"rosbaG" * 50)
    assert dataset_identity(ref(tmp_path / "other.bag")) != dataset_identity(ref(tmp_path / "log_copy.bag"))


def test_a_single_file_dataset_and_a_missing_one(tmp_path):
    file = tmp_path / "log.bin"
    file.write_bytes(b"x" * 10)
    assert dataset_identity(ref(file))["bytes"] == 10
    assert dataset_identity(ref(tmp_path / "nope")) == {"name": "data", "missing": True}
    assert dataset_identity(None) is None


def test_the_identity_is_cached_until_a_file_changes(tmp_path, monkeypatch):
    one = make_dataset(tmp_path / "one")
    first = dataset_identity(ref(one))
    opened = []
    real_open = open
    monkeypatch.setattr("builtins.open", lambda *a, **k: opened.append(a[0]) or real_open(*a, **k))
    assert dataset_identity(ref(one)) is first
    assert opened == []
    (one / "a.bin").write_bytes(b"abcd")
    assert dataset_identity(ref(one))["bytes"] == 12
    assert len(opened) == 2


def test_a_large_dataset_is_hashed_by_its_edges(tmp_path, monkeypatch):
    monkeypatch.setattr(payload_module, "WHOLE_HASH_LIMIT", 1000)
    monkeypatch.setattr(payload_module, "_EDGE", 10)
    data = bytearray(b"0" * 2000)
    (tmp_path / "big.bin").write_bytes(bytes(data))
    first = dataset_identity(ref(tmp_path / "big.bin"))
    assert first["hashed"] == "sizes, first and last MiB"
    data[-1:] = b"1"  # in the last edge
    (tmp_path / "big.bin").write_bytes(bytes(data))
    os.utime(tmp_path / "big.bin", ns=(0, 10 ** 9))
    assert dataset_identity(ref(tmp_path / "big.bin"))["sha256"] != first["sha256"]


# --- settings and fingerprint ------------------------------------------------------------------

def scenario(evaluation: dict, use_case="closed_loop", regression=None, confidence=None):
    conditions = SimpleNamespace(Confidence=confidence) if confidence is not None else None
    return SimpleNamespace(raw={"Evaluation": evaluation}, use_case=use_case, format_version="0.1.0", name="S",
                           regression=regression, config=SimpleNamespace(Conditions=conditions))


def test_settings_drop_what_only_judges_shows_or_names_the_model():
    evaluation = {k: {"x": 1} for k in NOT_FINGERPRINT} | {"Scenes": {"Count": 3}, "Steps": 50}
    assert settings_of(scenario(evaluation)) == {"Scenes": {"Count": 3}, "Steps": 50}
    for key in ("Conditions", "Artefacts", "Policies", "Model", "Executor", "Datasets"):
        assert key in NOT_FINGERPRINT


def test_settings_take_the_sessions_search_options_only_for_a_search():
    options = SimpleNamespace(examples=30, replay=None)
    assert "session search" not in settings_of(scenario({"Steps": 1}), options)
    with_search = settings_of(scenario({"Steps": 1, "Perturbation": {"speed": [0, 1]}}), options)
    assert with_search["session search"] == {"examples": 30, "replay": None}


def test_fingerprint_of_a_scenario(tmp_path):
    data = make_dataset(tmp_path / "d")
    made = fingerprint(scenario({"Steps": 5, "Model": "m.onnx"}), ref(data), 7)
    assert made["seed"] == 7 and made["use_case"] == "closed_loop" and made["settings"] == {"Steps": 5}
    assert made["dataset"] == dataset_identity(ref(data))


# --- make_payload for each use case ------------------------------------------------------------

def closed_loop_outcome(passed: list[bool], error: dict[int, str] | None = None) -> Outcome:
    error = error or {}
    scenes = [{"scene": i, "passed": ok, "at_fault": 0 if ok else 1, "error": error.get(i)} for i, ok in
              enumerate(passed)]
    findings = [Finding("collision with car 3", figure="at_fault", value=1, limit=0, frame=12, scene=i)
                for i, ok in enumerate(passed) if not ok and i not in error]
    figures = {"at_fault": sum(not ok for ok in passed), "drift_resets": 0, "max_displacement": 0.5,
               "scenes_passed": sum(passed), "front": 0}
    return Outcome("closed_loop", PASSED if all(passed) else FAILED, f"{sum(passed)}/{len(passed)} scenes passed",
                   figures=figures, findings=findings, details={"policy": "expert", "scenes": scenes})


def test_closed_loop_payload_keeps_key_figures_scenes_and_their_reasons():
    outcome = closed_loop_outcome([True, False, True, False], error={3: "NaN pose"})
    made = make_payload(outcome, "s.scenario.yaml::closed_loop", use_case=get_usecase("closed_loop"),
                        item="closed_loop", file="s.scenario.yaml")
    assert made["version"] == PAYLOAD_VERSION
    assert made["key"] == {"file": "s.scenario.yaml", "scenario": None, "item": "closed_loop",
                           "nodeid": "s.scenario.yaml::closed_loop"}
    assert set(made["figures"]) == {"at_fault", "drift_resets", "max_displacement", "scenes_passed"}  # not "front"
    assert made["model"] == "expert" and made["fingerprint"] is None and made["search"] is None
    units = Units.from_json(made["units"])
    assert units.ids == ["0", "1", "2", "3"] and units.columns == {"scene": "pfpe"}
    assert units.reasons == {"1": "at_fault at frame 12 (collision with car 3)", "3": "error: NaN pose"}
    assert json.loads(json.dumps(made)) == made


def test_closed_loop_payloads_compare_naming_the_scene():
    use_case = get_usecase("closed_loop")
    before = make_payload(closed_loop_outcome([True, True, True]), "n", use_case=use_case)
    after = make_payload(closed_loop_outcome([True, True, False]), "n", use_case=use_case)
    result = compare(before, after, "run r1")
    assert result.status == REGRESSED
    assert "scene 2 passed before, failed now: at_fault at frame 12 (collision with car 3)" in result.message()


def test_closed_loop_payload_with_a_scenario_has_its_fingerprint_and_rules(tmp_path):
    spec = RegressionSpec.model_validate({"Figures": {"drift_resets": {"Ignore": True}}, "Confidence": 99})
    made = make_payload(closed_loop_outcome([True]), "n", use_case=get_usecase("closed_loop"),
                        scenario=scenario({"Steps": 5}, regression=spec), dataset=ref(make_dataset(tmp_path / "d")),
                        seed=3)
    assert made["key"]["scenario"] == "S"
    assert made["fingerprint"]["seed"] == 3 and made["fingerprint"]["dataset"]["files"] == 2
    assert "drift_resets" not in made["figures"] and "drift_resets" not in made["rules"]["figures"]
    assert made["rules"]["confidence"] == 99


def obstacle_outcome(detection: list[str | None], non_detection: list[str | None], errors=None) -> Outcome:
    errors = errors or {}
    frames = [{"frame": f"{n:04d}", "stamp_ns": 1000 + n, "detection": d, "non_detection": nd, "topic_rate": None,
               "area_points": 0, "error": errors.get(n)} for n, (d, nd) in enumerate(zip(detection, non_detection))]
    return Outcome("obstacle_segmentation", PASSED, "ok", figures={"detection_rate": 100.0, "frames": len(frames)},
                   details={"frames": frames})


def test_obstacle_payload_keeps_two_columns_of_frames_with_stamps_for_the_failed_ones():
    outcome = obstacle_outcome(["Success", "Warn", "Fail", None], ["Success", "Fail", "Success", None],
                               errors={3: "no transform"})
    made = make_payload(outcome, "n", use_case=get_usecase("obstacle_segmentation"))
    units = Units.from_json(made["units"])
    assert units.kind == "frame" and units.ids == ["0000", "0001", "0002", "0003"]
    assert units.columns == {"detection": "SWFE", "non_detection": "SFSE"}
    assert units.reasons == {"0001": "stamp_ns 1001", "0002": "stamp_ns 1002",
                             "0003": "stamp_ns 1003, error: no transform"}
    assert made["figures"] == {"detection_rate": 100.0}


def test_obstacle_frames_that_fail_now_are_named_with_their_column_and_stamp():
    use_case = get_usecase("obstacle_segmentation")
    before = make_payload(obstacle_outcome(["Success", "Warn"], ["Success", "Success"]), "n", use_case=use_case)
    after = make_payload(obstacle_outcome(["Success", "Fail"], ["Success", "Success"]), "n", use_case=use_case)
    assert [c.text for c in compare(before, after).changes] == [
        "frame 0001 detection Warn before, Fail now: stamp_ns 1001"]


def policy_outcome(names: list[str], seeds: list[int]) -> Outcome:
    figures = {f"{k}_rate": 100.0 * names.count(k) / len(names) for k in ("goal", "collision", "off_road")}
    return Outcome("policy_benchmark", PASSED, "rates", figures={**figures, "episodes": len(names)},
                   details={"policy": "idm", "episode_outcomes": episode_outcomes(seeds, names)})


def test_policy_payload_keeps_episodes_by_seed():
    names = ["goal", "collision", "off_road", "step_limit", "running"]
    made = make_payload(policy_outcome(names, [10, 11, 12, 13, 14]), "n", use_case=get_usecase("policy_benchmark"))
    assert made["units"]["ids"] == {"from": 10, "count": 5}
    units = Units.from_json(made["units"])
    assert units.columns == {"outcome": "gcosr"} and units.word("o") == "off road"
    assert made["model"] == "idm" and set(made["figures"]) == {"goal_rate", "collision_rate", "off_road_rate"}


def test_policy_payload_with_scattered_seeds_keeps_their_list():
    made = make_payload(policy_outcome(["goal", "goal"], [5, 9]), "n", use_case=get_usecase("policy_benchmark"))
    assert made["units"]["ids"] == ["5", "9"]


def test_policy_payloads_compare_paired_by_seed():
    use_case = get_usecase("policy_benchmark")
    seeds = list(range(100, 130))
    before = make_payload(policy_outcome(["goal"] * 30, seeds), "n", use_case=use_case)
    after = make_payload(policy_outcome(["goal"] * 20 + ["off_road"] * 10, seeds), "n", use_case=use_case)
    result = compare(before, after)
    assert result.status == REGRESSED
    off_road = next(c for c in result.changes if c.what == "off_road_rate")
    assert "episodes 120, 121, 122, 123, 124, 125, 126, 127 and 2 more now end in off road" in off_road.text


def test_a_searched_outcome_keeps_the_search_and_no_units():
    outcome = closed_loop_outcome([False])
    outcome.figures.update(search_examples=40, search_failures=3, minimal_speed=1.5)
    outcome.details["search"] = {"minimal_text": "speed +1.5", "replay": "pytest --x", "examples": 40}
    made = make_payload(outcome, "n", use_case=get_usecase("closed_loop"))
    assert made["units"] is None
    assert made["search"] == {"broke": True, "minimal": {"speed": 1.5}, "text": "speed +1.5",
                              "replay": "pytest --x", "examples": 40}


def test_an_outcome_without_a_use_case_has_no_rules_nor_units():
    made = make_payload(Outcome("custom", PASSED, "ok", figures={"x": 1}), "n")
    assert made["units"] is None and made["figures"] == {} and made["rules"]["figures"] == {}
