"""``python -m pytest_driveeval check-data PATH...``: every supported format read as the evaluation
reads it, on the repository's fixtures, on every shared data folder, and on broken input
(truncated, of the wrong format, an empty folder, a path that does not exist), with the exit
status the docs promise: 0 every file can be evaluated, 1 some cannot, 2 a wrong command line."""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from types import SimpleNamespace

import pytest
from conftest import REPO_ROOT

from pytest_driveeval.__main__ import main
from pytest_driveeval.datacheck import check_paths, skipped_entries
from pytest_driveeval.datacheck.cli import ALL_FINE, SOME_CANNOT, USAGE

FIXTURES = REPO_ROOT / "fixtures"
SCENE_0103 = FIXTURES / "scenarionet" / "nuscenes" / "sd_nuscenes_v1.0-mini_scene-0103.pkl"
TUTORIAL = FIXTURES / "commonroad" / "ZAM_Tutorial-1_2_T-1.xml"


def checked(paths) -> dict:
    checks, _ = check_paths(list(paths))
    return {c.path: c for c in checks}


def run_json(capsys, *paths) -> tuple[int, dict]:
    code = main(["check-data", "--json", *map(str, paths)])
    return code, json.loads(capsys.readouterr().out)


# --------------------------------------------------------------------------- the repository's fixtures

def test_an_l5_zarr_with_its_map_is_read_scene_by_scene(capsys):
    code = main(["check-data", str(FIXTURES / "l5kit" / "single_scene.zarr")])
    out = capsys.readouterr().out
    assert code == ALL_FINE
    assert "ok    " in out and "(l5kit zarr)" in out
    assert "read: 1 scene, 248 frames, 20802 agent rows, 3216 traffic-light faces" in out  # SOURCES.md's counts
    assert "read: semantic map semantic_map.pb: 15 lanes, 4 crosswalks" in out


def test_an_l5_zarr_without_a_map_beside_it_is_evaluable_and_says_what_the_map_would_give(tmp_path):
    shutil.copytree(FIXTURES / "l5kit" / "single_scene.zarr", tmp_path / "alone.zarr")
    (check,) = checked([tmp_path / "alone.zarr"]).values()
    assert check.ok and any("no semantic_map.pb and meta.json beside the zarr" in s for s in check.skipped)


def test_scenarionet_files_each_say_their_scenario_tracks_map_and_closed_loop_scene():
    checks = checked([FIXTURES / "scenarionet" / "nuscenes"])
    assert [p.name for p in checks] == ["sd_nuscenes_v1.0-mini_scene-0103.pkl", "sd_nuscenes_v1.0-mini_scene-0553.pkl",
                                        "sd_nuscenes_v1.0-mini_scene-0757.pkl"]
    check = checks[SCENE_0103]
    assert check.ok and check.format == "ScenarioNet"
    text = "\n".join(check.read)
    assert "scenario scene-0103 (nuscenes, map boston-seaport): 196 steps every 0.1 s" in text
    assert "122 tracks: 61 VEHICLE, 46 PEDESTRIAN, 8 TRAFFIC_CONE, 7 CYCLIST" in text
    assert "513 map features: 358 lane, 155 road_line" in text
    assert "closed-loop scene: 196 frames" in text


def test_a_commonroad_file_says_its_planning_problems_as_scenes():
    (check,) = checked([TUTORIAL]).values()
    assert check.ok
    assert check.read == ["benchmark ZAM_Tutorial-1_1_T-1, format 2020a, a step every 0.1 s",
                          "3 lanelets; 3 obstacles (2 dynamic, 1 static: 2 car, 1 parkedVehicle)",
                          "planning problems: 100",
                          "3 <lanelet>: bounds, neighbours and speed limits: the road and its drivable area",
                          "3 obstacles: 2 dynamic, 1 static, replayed at their recorded states and collided with",
                          "1 <planningProblem>: each one an item of the CommonRoad benchmark",
                          "planning problem 100: a scene of 40 steps from time step 0, 3 obstacles replayed"]


def test_a_t4_dataset_and_its_input_bag_are_both_checked():
    checks = checked([FIXTURES / "t4" / "clean"])
    t4, bag = checks[FIXTURES / "t4" / "clean"], checks[FIXTURES / "t4" / "clean" / "input_bag"]
    assert t4.ok and t4.format == "t4_dataset" and bag.ok and bag.format == "ROS 2 bag"
    assert t4.read[0].startswith("10 samples, 120 annotated boxes") and "lidar sweeps: 10 of 10 present" in t4.read[0]
    assert "/perception/obstacle_segmentation/pointcloud (sensor_msgs/msg/PointCloud2): 10 messages" in bag.read


def test_the_fixtures_folder_is_searched_and_every_dataset_in_it_can_be_evaluated(capsys):
    code, report = run_json(capsys, FIXTURES)
    assert code == ALL_FINE and report["ok"]
    formats = {c["format"] for c in report["checks"]}
    assert formats == {"l5kit zarr", "ScenarioNet", "CommonRoad", "t4_dataset", "ROS 2 bag"}
    assert all(c["ok"] for c in report["checks"])
    # models, trajectories and the provenance file are no dataset: listed, not checked, not failed
    assert str(FIXTURES / "SOURCES.md") in report["not_read"]


# --------------------------------------------------------------------------- the shared data

def test_every_shared_data_folder(shared_data, capsys):
    code, report = run_json(capsys, shared_data)
    checks = {c["path"]: c for c in report["checks"]}
    by_format: dict = {}
    for check in checks.values():
        by_format.setdefault(check["format"], []).append(check)
    # each format the shared data holds is found and read
    assert len(by_format["ScenarioNet"]) == len(list((shared_data / "scenarionet").rglob("*.pkl")))
    assert len(by_format["CommonRoad"]) == len(list((shared_data / "commonroad").glob("*.xml")))
    assert {"l5kit zarr", "ROS 2 bag", "t4_dataset"} <= set(by_format)
    for kind in ("ScenarioNet", "l5kit zarr", "ROS 2 bag", "t4_dataset"):
        assert all(c["ok"] for c in by_format[kind]), [c for c in by_format[kind] if not c["ok"]]
    bag = checks[str(shared_data / "rosbag" / "tf_example")]
    assert bag["read"][:2] == ["2 topics, 518 messages over 51.7 s", "/tf (tf2_msgs/msg/TFMessage): 517 messages"]
    # A CommonRoad file that cannot be evaluated says why, naming itself; a map without a planning
    # problem (Starnberg) is one whatever the readers learn.
    for check in by_format["CommonRoad"]:
        assert check["ok"] or all(check["path"] in p for p in check["problems"]), check
    starnberg = checks[str(shared_data / "commonroad" / "DEU_Starnberg-1_1_T-1.xml")]
    assert not starnberg["ok"] and "no <planningProblem>" in starnberg["problems"][0]
    assert code == SOME_CANNOT and not report["ok"]


# --------------------------------------------------------------------------- broken input

def test_a_truncated_scenario_fails_naming_the_file_and_the_good_one_beside_it_still_passes(tmp_path, capsys):
    shutil.copy(SCENE_0103, tmp_path / "sd_good.pkl")
    (tmp_path / "sd_cut.pkl").write_bytes(SCENE_0103.read_bytes()[:4000])
    code = main(["check-data", str(tmp_path)])
    out = capsys.readouterr().out
    assert code == SOME_CANNOT
    assert f"FAIL  {tmp_path / 'sd_cut.pkl'} (ScenarioNet)" in out and "truncated" in out
    assert f"ok    {tmp_path / 'sd_good.pkl'} (ScenarioNet)" in out
    assert out.rstrip().endswith(f"1 can be evaluated, 1 cannot: {tmp_path / 'sd_cut.pkl'}")


@pytest.mark.parametrize("name, content, expected", [
    ("sd_text.pkl", b"this is not a pickle\n", "sd_text.pkl"),
    ("map.xml", b"<?xml version='1.0'?>\n<osm version='0.6'/>\n", "not a CommonRoad file"),
    ("cut.xml", TUTORIAL.read_bytes()[:3000], "cut.xml"),
    ("empty.xml", b"", "empty.xml"),
    ("zero.db3", b"", "zero.db3"),
    ("noise.mcap", b"\x89MCAP0\r\n" + b"\x00" * 50, "noise.mcap"),
])
def test_a_file_of_the_wrong_format_or_truncated_fails_naming_itself(tmp_path, name, content, expected):
    (tmp_path / name).write_bytes(content)
    (check,) = checked([tmp_path / name]).values()
    assert not check.ok and expected in check.problems[0] and name in check.problems[0], check.problems


def test_a_scenario_the_closed_loop_cannot_drive_fails_with_the_readers_reason(tmp_path):
    """Readable, but sampled at 5 Hz: the closed loop steps at 10 Hz and refuses it."""
    from pytest_driveeval.io.scenarionet.safe_pickle import load_data_pickle

    data = load_data_pickle(SCENE_0103)
    data["metadata"]["ts"] = data["metadata"]["ts"] * 2
    data["metadata"]["sample_rate"] = 0.2
    import pickle

    (tmp_path / "sd_slow.pkl").write_bytes(pickle.dumps(data))
    (check,) = checked([tmp_path / "sd_slow.pkl"]).values()
    assert not check.ok and "sampled every 0.2 s" in check.problems[0]
    assert any("scenario scene-0103" in line for line in check.read)  # what was read is still said


def test_broken_zarr_bag_and_t4_folders_fail_naming_themselves(tmp_path):
    zarr = tmp_path / "broken.zarr"
    shutil.copytree(FIXTURES / "l5kit" / "single_scene.zarr", zarr)
    shutil.rmtree(zarr / "agents")
    bag = tmp_path / "bag"
    bag.mkdir()
    (bag / "metadata.yaml").write_text("rosbag2_bagfile_information: [unclosed\n")
    t4 = tmp_path / "t4"
    (t4 / "annotation").mkdir(parents=True)
    (t4 / "annotation" / "sample.json").write_text("[]")
    checks = checked([zarr, bag, t4])
    assert [c.format for c in checks.values()] == ["l5kit zarr", "ROS 2 bag", "t4_dataset"]
    for path, check in checks.items():
        assert not check.ok and str(path) in check.problems[0], check.problems
    assert "agents" in checks[zarr].problems[0]
    assert "lacks table(s)" in checks[t4].problems[0]


def test_an_empty_folder_and_a_missing_path_cannot_be_evaluated(tmp_path, capsys):
    (tmp_path / "empty").mkdir()
    (tmp_path / "notes").mkdir()
    (tmp_path / "notes" / "readme.txt").write_text("no data here")
    code = main(["check-data", str(tmp_path / "empty"), str(tmp_path / "absent.zarr"), str(tmp_path / "notes"),
                 str(TUTORIAL)])
    out = capsys.readouterr().out
    assert code == SOME_CANNOT
    assert f"{tmp_path / 'empty'}: a folder without a dataset in it" in out
    assert f"{tmp_path / 'absent.zarr'}: no such file or folder" in out
    assert "it holds 1 other file(s)" in out
    assert "checked 4 dataset file(s): 1 can be evaluated, 3 cannot" in out  # the good file is still checked


def test_a_wrong_command_line_exits_2():
    for argv in (["check-data"], ["check-data", "--no-such-option", "x"]):
        with pytest.raises(SystemExit) as exc:
            main(argv)
        assert exc.value.code == USAGE


def test_the_command_as_a_user_runs_it_exits_with_the_documented_status(tmp_path):
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO_ROOT), os.environ.get("PYTHONPATH", "")])}

    def status(*paths) -> int:
        return subprocess.run([sys.executable, "-m", "pytest_driveeval", "check-data", *map(str, paths)],
                              env=env, capture_output=True, text=True, timeout=300).returncode

    assert status(TUTORIAL) == ALL_FINE
    assert status(TUTORIAL, tmp_path / "absent.xml") == SOME_CANNOT
    assert status() == USAGE


# --------------------------------------------------------------------------- what the readers skipped

def test_what_a_readers_object_lists_as_skipped_is_printed_in_words():
    listed = SimpleNamespace(skipped=[
        "map feature 204: a one-point polyline",
        ("map feature 205", "a zero-length line"),
        {"what": "track 7", "why": "never valid"},
        SimpleNamespace(id="light 3", reason="no lane"),
    ])
    assert skipped_entries(listed, object(), SimpleNamespace(skipped=None)) == [
        "map feature 204: a one-point polyline", "map feature 205: a zero-length line", "track 7: never valid",
        "light 3: no lane"]


def test_a_scenarionet_scenes_skipped_list_reaches_the_report(monkeypatch):
    """Once the reader keeps what it left out (``skipped`` on the scene it returns), check-data prints it."""
    from pytest_driveeval.io.scenarionet import scenarionet

    real = scenarionet.read_scenario

    def reading(path):
        scene = real(path)
        scene.skipped = [("map feature 204", "its polyline has 1 point(s)")]
        return scene

    monkeypatch.setattr(scenarionet, "read_scenario", reading)
    (check,) = checked([SCENE_0103]).values()
    assert check.ok and "map feature 204: its polyline has 1 point(s)" in check.skipped


def test_a_commonroad_scenarios_skipped_list_reaches_the_report(monkeypatch):
    from pytest_driveeval.io.commonroad import commonroad

    real = commonroad.read_commonroad

    def reading(path):
        scenario = real(path)
        scenario.skipped = ["<dynamicObstacle id='9'>: an occupancy set, kept for collisions only"]
        return scenario

    monkeypatch.setattr(commonroad, "read_commonroad", reading)
    (check,) = checked([TUTORIAL]).values()
    assert check.skipped[0] == "<dynamicObstacle id='9'>: an occupancy set, kept for collisions only"


def test_the_commonroad_readers_own_notes_say_what_was_read_and_skipped_with_their_lines():
    (check,) = checked([TUTORIAL]).values()
    assert "3 <lanelet>: bounds, neighbours and speed limits: the road and its drivable area" in check.read
    assert check.skipped == ["1 <location> (first at line 3): geographic location and environment: not used",
                             "1 <scenarioTags> (first at line 8): tags: not used"]


def test_the_scenarionet_readers_skipped_features_and_notes_reach_the_report(tmp_path):
    """A one-point lane is skipped by the reader (ScenarioNetScene.skipped, a Skipped record) and
    check-data prints the reader's own line for it, with the feature's id and type."""
    from pytest_driveeval.io.scenarionet.scenarionet_features import Skipped

    entry = Skipped("204", "LANE_SURFACE_STREET", "not read: its polyline has 1 point(s); a line needs 2")
    assert skipped_entries(SimpleNamespace(skipped=[entry])) == [
        "map feature 204 (LANE_SURFACE_STREET): not read: its polyline has 1 point(s); a line needs 2"]
