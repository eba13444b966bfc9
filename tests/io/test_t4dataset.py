"""t4_dataset ground truth, on the real nuScenes-derived sample and on broken copies."""
from __future__ import annotations

import json
import re
import shutil

import numpy as np
import pytest

from pytest_driveeval.geometry import yaw_from_quat_wxyz
from pytest_driveeval.io.t4.t4dataset import T4Dataset, T4DatasetError

# a fast reader / score / report check: CI runs these at the lowest declared versions (-m smoke)
pytestmark = pytest.mark.smoke

TS = 1532402927647951


@pytest.fixture
def t4(shared_data):
    return T4Dataset(shared_data / "t4_sample")


@pytest.fixture
def t4_copy(shared_data, tmp_path):
    dst = tmp_path / "t4"
    shutil.copytree(shared_data / "t4_sample", dst)
    for p in dst.rglob("*"):
        p.chmod(0o755 if p.is_dir() else 0o644)
    return dst


def test_real_sample_ground_truth(t4):
    assert len(t4) == 1 and t4.sample_timestamps_us.tolist() == [TS]
    gt = t4.ground_truth_at(TS + 1000)
    assert gt.timestamp_us == TS and gt.frame_id == "map" and len(gt) == 1
    assert gt.instance_tokens.tolist() == ["6dd2cbf4c24b4caeb625035869bca7b5"]
    assert gt.category_names.tolist() == ["human.pedestrian.adult"]
    assert gt.visibility.tolist() == ["v80-100"]  # token "full" -> level
    assert gt.num_lidar_pts.tolist() == [1]
    assert np.allclose(gt.centers, [[373.256, 1130.419, 0.8]])
    assert np.allclose(gt.sizes, [[0.621, 0.669, 1.642]])
    assert gt.yaws[0] == pytest.approx(2 * np.arctan2(-0.18301629506281616, 0.9831098797903927))
    assert gt.lidar_path.name.endswith("1532402927647951.pcd.bin")
    assert t4.read_lidar(gt.sample_token).size == 34688
    assert t4.input_bag is None and t4.lanelet2_map is None


def test_tolerance(t4):
    assert t4.ground_truth_at(TS + 75_000) is not None
    assert t4.ground_truth_at(TS - 75_001) is None
    assert t4.ground_truth_at(TS + 10**6, tolerance_us=10**6) is not None


def test_to_base_link(t4):
    gt = t4.ground_truth_at(TS)
    bl = gt.to_base_link()
    assert bl.frame_id == "base_link"
    # back to map with the ego pose gives the stored centre
    back = gt.ego_pose[:3, :3] @ bl.centers[0] + gt.ego_pose[:3, 3]
    assert np.allclose(back, gt.centers[0])
    assert np.linalg.norm(bl.centers[0, :2]) == pytest.approx(
        np.linalg.norm(gt.centers[0, :2] - gt.ego_pose[:2, 3]), rel=1e-3)
    ego_yaw = yaw_from_quat_wxyz([0.5720320396729045, -0.0016977771610471074,
                                  0.011798001930183783, -0.8201446642457809])
    d = (bl.yaws[0] - (gt.yaws[0] - ego_yaw) + np.pi) % (2 * np.pi) - np.pi
    assert abs(d) < 0.03  # ego has ~1 deg of roll/pitch
    assert bl.to_base_link() is bl


def test_missing_table_names_file(t4_copy):
    (t4_copy / "annotation/ego_pose.json").unlink()
    with pytest.raises(T4DatasetError, match=rf"^t4_dataset {t4_copy}: annotation/ lacks table\(s\) ego_pose.json$"):
        T4Dataset(t4_copy)


def test_dangling_token_names_table(t4_copy):
    p = t4_copy / "annotation/sample_annotation.json"
    rows = json.loads(p.read_text())
    rows[0]["visibility_token"] = "bogus"
    p.write_text(json.dumps(rows))
    with pytest.raises(T4DatasetError, match=rf"^t4_dataset {t4_copy}: annotation/visibility.json: no record with "
                                             r"token 'bogus' \(referenced by sample_annotation ef63"):
        T4Dataset(t4_copy).ground_truth_at(TS)


@pytest.mark.parametrize("key, value", [("translation", [1.0, float("nan"), 0.0]), ("size", [1.0, 2.0]),
                                        ("rotation", "upright")])
def test_a_malformed_box_names_its_annotation(t4_copy, key, value):
    p = t4_copy / "annotation/sample_annotation.json"
    rows = json.loads(p.read_text())
    rows[0][key] = value
    p.write_text(json.dumps(rows))  # json writes NaN, as Python's own writers do
    with pytest.raises(T4DatasetError, match=rf"^t4_dataset {t4_copy}: annotation/sample_annotation.json: "
                                             rf"record 'ef63.*': {key} should be \d finite numbers, found"):
        T4Dataset(t4_copy).ground_truth_at(TS)


def test_bad_json_and_category_via_instance(t4_copy):
    p = t4_copy / "annotation/sample_annotation.json"
    rows = json.loads(p.read_text())
    del rows[0]["category_name"]  # t4 tables: category only through instance
    p.write_text(json.dumps(rows))
    assert T4Dataset(t4_copy).ground_truth_at(TS).category_names.tolist() == ["human.pedestrian.adult"]
    (t4_copy / "annotation/scene.json").write_text("{not json")
    with pytest.raises(T4DatasetError, match=rf"^t4_dataset {t4_copy}: annotation/scene.json: invalid JSON"):
        T4Dataset(t4_copy).table("scene")


def test_optional_paths(t4_copy):
    (t4_copy / "input_bag").mkdir()
    (t4_copy / "input_bag/input_bag.mcap").write_bytes(b"")  # no metadata.yaml: still the input bag
    (t4_copy / "map").mkdir()
    (t4_copy / "map/lanelet2_map.osm").write_text("<osm/>")
    ds = T4Dataset(t4_copy)
    assert ds.input_bag == t4_copy / "input_bag" and ds.lanelet2_map.name == "lanelet2_map.osm"


def test_empty_sample(t4_copy):
    (t4_copy / "annotation/sample_annotation.json").write_text("[]")
    gt = T4Dataset(t4_copy).ground_truth_at(TS)
    assert len(gt) == 0 and gt.centers.shape == (0, 3) and gt.to_base_link().rotations.shape == (0, 4)
    assert gt.yaws.shape == (0,)


def test_a_missing_sweep_names_dataset_sample_and_file(t4_copy):
    ds = T4Dataset(t4_copy)
    (token,) = ds.sample_tokens
    sd = ds.lidar_sample_data(token)
    (t4_copy / sd["filename"]).unlink()
    with pytest.raises(T4DatasetError) as exc:
        ds.read_lidar(token)
    assert str(exc.value) == (f"t4_dataset {t4_copy}: sample {token!r} (sample_data {sd['token']!r}, timestamp {TS} "
                              f"us): lidar sweep {sd['filename']} does not exist")


def test_a_truncated_sweep_names_dataset_and_sample(t4_copy):
    ds = T4Dataset(t4_copy)
    (token,) = ds.sample_tokens
    path = t4_copy / ds.lidar_sample_data(token)["filename"]
    path.write_bytes(path.read_bytes()[:-3])
    with pytest.raises(T4DatasetError, match=rf"^t4_dataset {t4_copy}: sample '{token}' \(.*\): "
                                             rf"{re.escape(str(path.relative_to(t4_copy)))}: size 693757 bytes is "
                                             r"not a multiple of 5 float32 fields"):
        ds.read_lidar(token)


def test_a_generated_dataset_without_a_sweep(tmp_path):
    t4gen = pytest.importorskip("pytest_driveeval.synth.t4gen")
    m = t4gen.generate_t4_dataset(tmp_path / "gen", num_frames=2, seed=1)
    (m.root / "data/LIDAR_TOP/00001.pcd.bin").unlink()
    ds = T4Dataset(m.root)
    assert ds.read_lidar(ds.sample_tokens[0]).size > 0
    with pytest.raises(T4DatasetError, match=rf"^t4_dataset {m.root}: sample '{ds.sample_tokens[1]}' \(sample_data "
                                             r"'\w+', timestamp \d+ us\): lidar sweep data/LIDAR_TOP/00001.pcd.bin "
                                             r"does not exist$"):
        ds.read_lidar(ds.sample_tokens[1])
