"""Issue 11: each damaged dataset fails its own scenario with a located message; the others still run.

Every input is a generated dataset (no shared data needed), copied and then damaged the way
recorders, copies and hand edits damage real ones."""
from __future__ import annotations

import json
import shutil
import sqlite3

import pytest

t4gen = pytest.importorskip("pytest_driveeval.synth.t4gen")

TOPIC = "/perception/obstacle_segmentation/pointcloud"
SCENARIO = """\
ScenarioFormatVersion: 3.0.0
ScenarioName: {name}
Evaluation:
  UseCaseName: obstacle_segmentation
  UseCaseFormatVersion: 0.3.0
  Datasets:
    - {name}:
        Path: {path}
  Conditions:
    Detection:
      PassRate: 99.0
      BoundingBoxConfig:
        - dcb2b352232fff50c4fad23718f31611: {{Start: null, End: null}}
    NonDetection: null
  SensingEvaluationConfig:
    evaluation_config_dict:
      evaluation_task: sensing
      target_uuids: null
      box_scale_0m: 1.0
      box_scale_100m: 1.0
      min_points_threshold: 1
"""


@pytest.fixture(scope="module")
def generated(tmp_path_factory):
    root = tmp_path_factory.mktemp("t4")
    return {storage: t4gen.generate_t4_dataset(root / storage, num_frames=8, seed=3, storage=storage).root
            for storage in ("sqlite3", "mcap")}


def delete_points(db, where="1"):
    with sqlite3.connect(db) as con:
        con.execute(f"DELETE FROM messages WHERE topic_id = (SELECT id FROM topics WHERE name = ?) AND {where}",
                    (TOPIC,))
    con.close()


def cut_last_chunk(mcap):
    from rosbags.rosbag2 import Reader
    with Reader(mcap) as r:
        chunk = r.storage.chunks[-1]
    raw = mcap.read_bytes()
    end = chunk.chunk_start_offset + chunk.chunk_length + chunk.message_index_length
    mcap.write_bytes(raw[:chunk.chunk_start_offset] + raw[end:])


def ros1_only(bag):
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore
    shutil.rmtree(bag)
    bag.mkdir()
    with Writer(bag / "recording.bag") as w:
        w.add_connection(TOPIC, "sensor_msgs/msg/PointCloud2", typestore=get_typestore(Stores.ROS1_NOETIC))


def no_sweep(root):
    shutil.rmtree(root / "input_bag")  # evaluated on its lidar sweeps, one of which is gone
    (root / "data/LIDAR_TOP/00003.pcd.bin").unlink()


def sample_token(root, index):
    rows = sorted(json.loads((root / "annotation/sample.json").read_text()), key=lambda r: r["timestamp"])
    return rows[index]["token"]


DAMAGE = {  # name: (storage, damage(root), the line the user reads)
    "bare_mcap": ("mcap", lambda root: (root / "input_bag/metadata.yaml").unlink(), None),
    "ros1": ("sqlite3", lambda root: ros1_only(root / "input_bag"), (
        "*input_bag: holds a ROS 1 bag (recording.bag), and only ROS 2 bags (.db3 or .mcap storage) can be read; "
        "convert it with `rosbags-convert --src *input_bag/recording.bag --dst *input_bag_ros2`*")),
    "empty_topic": ("sqlite3", lambda root: (delete_points(root / "input_bag/input_bag.db3"),
                                             (root / "input_bag/metadata.yaml").unlink()),
                    f"*input_bag: topic '{TOPIC}' has no messages; the bag holds: /diagnostics_agg *"),
    "deleted_rows": ("sqlite3", lambda root: delete_points(root / "input_bag/input_bag.db3", (
        "timestamp BETWEEN 1700000000200000000 AND 1700000000400000000")), (
        f"*input_bag: topic '{TOPIC}': metadata.yaml lists 8 messages, but only 5 can be read (storage files "
        "input_bag.db3): 3 are missing (deleted, or lost with a damaged part of the file); the longest gap, 0.400 s, "
        "is between message #1 (log time 1700000000.100000000) and #2 (log time 1700000000.500000000)")),
    "lost_chunk": ("mcap", lambda root: cut_last_chunk(root / "input_bag/input_bag.mcap"), (
        "*input_bag: input_bag.mcap: chunk 2 of 2 (log time * s, /* x4, *) is missing: the file is * bytes shorter "
        "than its index says; `mcap recover`*")),
    "no_sweep": ("sqlite3", no_sweep, (
        "*t4_dataset *no_sweep: sample '{token}' (sample_data '*', timestamp * us): lidar sweep "
        "data/LIDAR_TOP/00003.pcd.bin does not exist*")),
}


def test_each_bad_dataset_fails_alone_with_its_message(pytester, generated):
    for name, (storage, damage, _) in DAMAGE.items():
        root = pytester.path / "data" / name
        shutil.copytree(generated[storage], root)
        damage(root)
        pytester.makefile(".scenario.yaml", **{name: SCENARIO.format(name=name, path=root)})
    pytester.makefile(".scenario.yaml", good=SCENARIO.format(name="good", path=generated["sqlite3"]))
    result = pytester.runpytest("-q")
    result.assert_outcomes(passed=2, failed=len(DAMAGE) - 1)
    out = result.stdout.str()
    assert "Traceback" not in out and "FileNotFoundError" not in out
    for name, (_, _, line) in DAMAGE.items():
        if line:
            result.stdout.fnmatch_lines([line.format(token=sample_token(pytester.path / "data" / name, 3))])
    data = json.loads((pytester.path / "driveeval-results" / "summary.json").read_text())
    bare = next(r for r in data["results"] if r["nodeid"].startswith("bare_mcap"))
    good = next(r for r in data["results"] if r["nodeid"].startswith("good"))
    assert bare["status"] == "passed" and bare["figures"]["frames"] == good["figures"]["frames"] == 8


def test_a_missing_input_bag_is_named_once_and_the_dataset_beside_it_passes(pytester):
    """Without input_bag/ the clouds fall back to the lidar sweeps, but the map's lanelets still need
    the ego's pose from the bag's TF: one error naming the bag, not one per frame."""
    from conftest import REPO_ROOT

    text = (REPO_ROOT / "scenario_tests" / "obstacle_segmentation" / "clean" / "scenario.yaml").read_text()
    for name in ("good", "nobag"):
        shutil.copytree(REPO_ROOT / "fixtures" / "t4" / "clean", pytester.path / "data" / name)
        pytester.makefile(".scenario.yaml", **{name: text.replace("../../../fixtures/t4/clean", f"data/{name}")})
    shutil.rmtree(pytester.path / "data" / "nobag" / "input_bag")
    result = pytester.runpytest("-q", "-W", "ignore::pytest.PytestUnknownMarkWarning")
    result.assert_outcomes(passed=1, failed=1)
    result.stdout.fnmatch_lines([
        "*DataError: t4_dataset */data/nobag: its input bag */data/nobag/input_bag is missing: the NonDetection area "
        "is cut to the road lanelets of */data/nobag/map/lanelet2_map.osm at the ego's pose (TF map -> base_link), "
        "which the bag's /tf holds"])
    out = result.stdout.str()
    assert "TF has none" not in out and "could not be evaluated" not in out
    records = json.loads((pytester.path / "driveeval-results" / "summary.json").read_text())["results"]
    assert {r["nodeid"].split(".")[0]: r["status"] for r in records} == {"good": "passed", "nobag": "failed"}


def test_a_bag_without_tf_under_a_map_is_named_before_any_frame(tmp_path):
    from conftest import REPO_ROOT
    from pytest_driveeval.core.errors import DataError
    from pytest_driveeval.io.t4.t4dataset import T4Dataset
    from pytest_driveeval.scenario import load_scenario
    from pytest_driveeval.usecases.obstacle_segmentation.evaluate import ObstacleEvaluation

    root = tmp_path / "notf"
    shutil.copytree(REPO_ROOT / "fixtures" / "t4" / "clean", root)
    (root / "input_bag" / "metadata.yaml").unlink()  # it lists the topics removed below
    with sqlite3.connect(root / "input_bag" / "input_bag.db3") as con:
        con.execute("DELETE FROM messages WHERE topic_id IN (SELECT id FROM topics WHERE name LIKE '/tf%')")
        con.execute("DELETE FROM topics WHERE name LIKE '/tf%'")
    con.close()
    config = load_scenario(REPO_ROOT / "scenario_tests" / "obstacle_segmentation" / "clean" / "scenario.yaml").config
    with pytest.raises(DataError) as failed:
        ObstacleEvaluation.load(T4Dataset(root), config)
    assert str(failed.value).startswith(f"{root / 'input_bag'}: the bag has no /tf or /tf_static: the NonDetection "
                                        f"area is cut to the road lanelets of {root / 'map' / 'lanelet2_map.osm'}")
    # Without NonDetection the map is not needed, and the same bag loads.
    without = config.model_copy(update={"Conditions": config.Conditions.model_copy(update={"NonDetection": None})})
    assert ObstacleEvaluation.load(T4Dataset(root), without).tf is None
