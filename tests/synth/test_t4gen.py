"""Synthetic t4_dataset generator: reads back, is deterministic, defects land where claimed."""
from __future__ import annotations

import xml.etree.ElementTree as ET

import numpy as np
import pytest

from pytest_driveeval.io.ros.rosbag import Bag
from pytest_driveeval.io.t4.t4dataset import T4Dataset
from pytest_driveeval.geometry import points_in_boxes
from pytest_driveeval.synth.t4gen import DIAG_NAME, TARGET_TOKEN, generate_t4_dataset

from conftest import REPO_ROOT as REPO

N_FRAMES, RAYS = 6, 8000


def _gen(tmp_path_factory, name, **kw):
    kw = {"num_frames": N_FRAMES, "points_per_frame": RAYS, **kw}
    return generate_t4_dataset(tmp_path_factory.mktemp(name) / "ds", **kw)


@pytest.fixture(scope="module")
def clean(tmp_path_factory):
    return _gen(tmp_path_factory, "clean")


@pytest.fixture(scope="module")
def datasets(tmp_path_factory, clean):
    return {None: clean,
            "missed_object": _gen(tmp_path_factory, "missed", defect="missed_object"),
            "ghost_points": _gen(tmp_path_factory, "ghost", defect="ghost_points")}


def _frames(m):
    """(gt in base_link, xyz float64, points-in-box matrix) per cloud of the bag."""
    ds = T4Dataset(m.root)
    out = []
    with Bag(m.input_bag) as bag:
        for fr in bag.pointclouds(m.pointcloud_topic):
            gt = ds.ground_truth_at(fr.stamp_ns // 1000).to_base_link()
            xyz = np.column_stack([fr.points[c] for c in "xyz"]).astype(np.float64)
            out.append((gt, xyz, points_in_boxes(xyz, gt.centers, gt.yaws, gt.sizes[:, [1, 0, 2]]).mask))
    return out


def _in_area(xyz, inbox):
    x, y, z = xyz.T
    return (x >= 0) & (x <= 10) & (np.abs(y) <= 1.5) & (z >= 0) & (z <= 1.5) & ~inbox.any(1)


def _raw(m):
    with Bag(m.input_bag) as bag:
        return {t: [raw for *_, raw in bag.raw_messages(t)] for t in sorted(bag.topics)}


@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
def test_reads_back(tmp_path_factory, storage):
    m = _gen(tmp_path_factory, storage, storage=storage)
    assert len(list(m.input_bag.glob("*.db3" if storage == "sqlite3" else "*.mcap"))) == 1
    ds = T4Dataset(m.root)
    assert len(ds) == N_FRAMES
    assert ds.sample_timestamps_us.tolist() == [s // 1000 for s in m.frame_stamps_ns]
    assert ds.lanelet2_map == m.lanelet2_map and ds.input_bag == m.input_bag
    with Bag(m.input_bag) as bag:
        assert bag.topics == {m.pointcloud_topic: "sensor_msgs/msg/PointCloud2",
                              "/tf": "tf2_msgs/msg/TFMessage",
                              "/tf_static": "tf2_msgs/msg/TFMessage",
                              "/diagnostics_agg": "diagnostic_msgs/msg/DiagnosticArray"}
        assert [bag.message_count(t) for t in (m.pointcloud_topic, "/tf", "/diagnostics_agg")] \
            == [N_FRAMES] * 3
        tf = bag.read_tf()
        diag = bag.read_diagnostics("/diagnostics_agg")
        clouds = list(bag.pointclouds(m.pointcloud_topic))
    assert [c.stamp_ns for c in clouds] == m.frame_stamps_ns
    assert {c.frame_id for c in clouds} == {"base_link"}
    assert clouds[0].points.dtype.itemsize == 16  # Autoware PointXYZIRC
    assert diag.levels_at(DIAG_NAME, m.frame_stamps_ns).tolist() == [0] * N_FRAMES
    for tok, stamp in zip(ds.sample_tokens, m.frame_stamps_ns):
        assert np.allclose(tf.lookup("map", "base_link", stamp), ds.ego_pose(tok), atol=1e-6)
        assert tf.lookup("base_link", "LIDAR_TOP", stamp)[2, 3] == pytest.approx(2.0)
        sweep = ds.read_lidar(tok)
        assert sweep.size > RAYS // 3 and set(np.unique(sweep["ring"])) <= set(range(32))


def test_clean_passes_detection_and_non_detection(clean):
    for gt, xyz, inbox in _frames(clean):
        n = inbox.sum(0)
        assert (n == gt.num_lidar_pts).all()
        assert (n[gt.visibility != "v0-40"] > 0).all()
        target = n[gt.instance_tokens == TARGET_TOKEN]
        assert target.size == 1 and target[0] >= 10
        assert not _in_area(xyz, inbox).any()
        # ground removed: nothing low on the road but object returns (range noise
        # scatters those a few cm outside their boxes)
        near_box = points_in_boxes(xyz, gt.centers, gt.yaws, gt.sizes[:, [1, 0, 2]], margin=0.1).mask.any(1)
        low = (xyz[:, 2] < 0.15) & (np.abs(xyz[:, 1]) < 5.0) & (np.abs(xyz[:, 0]) < 30)
        assert not (low & ~near_box).any()


def test_occluded_object(clean):
    assert clean.occluded_frames and set(clean.occluded_frames) <= set(clean.occluded_tokens)
    tok, frames = next(iter(clean.occluded_frames.items()))
    per_frame = _frames(clean)
    for i in frames:
        gt, _, inbox = per_frame[i]
        k = list(gt.instance_tokens).index(tok)
        assert gt.visibility[k] == "v0-40" and gt.num_lidar_pts[k] == 0 and inbox[:, k].sum() == 0
    # the hidden pedestrian stays hidden for a whole short run
    assert any(len(f) == N_FRAMES for f in clean.occluded_frames.values())


def test_determinism(tmp_path_factory, clean):
    again = _gen(tmp_path_factory, "again")
    for p in sorted((clean.root / "annotation").glob("*.json")):
        assert p.read_bytes() == (again.root / "annotation" / p.name).read_bytes(), p.name
    assert _raw(clean) == _raw(again)
    other = _gen(tmp_path_factory, "seed1", seed=1)
    assert _raw(other)[clean.pointcloud_topic] != _raw(clean)[clean.pointcloud_topic]


def test_missed_object(datasets):
    m, clean = datasets["missed_object"], datasets[None]
    assert m.defect_token == TARGET_TOKEN and m.defect_frames == [1, 3, 5]
    raw_m, raw_c = _raw(m), _raw(clean)
    for i, (gt, _, inbox) in enumerate(_frames(m)):
        n = inbox[:, list(gt.instance_tokens).index(TARGET_TOKEN)].sum()
        assert (n == 0) == (i in m.defect_frames)
        same = raw_m[m.pointcloud_topic][i] == raw_c[m.pointcloud_topic][i]
        assert same == (i not in m.defect_frames)
    assert (m.root / "annotation/sample_annotation.json").read_bytes() == \
        (clean.root / "annotation/sample_annotation.json").read_bytes()


def test_ghost_points(datasets):
    m = datasets["ghost_points"]
    for i, (_, xyz, inbox) in enumerate(_frames(m)):
        ghost = xyz[_in_area(xyz, inbox)]
        assert (len(ghost) > 0) == (i in m.defect_frames)
        if len(ghost):
            assert ghost[:, 0].min() >= 3 and ghost[:, 0].max() <= 8
            assert ghost[:, 2].min() >= 0.2 - 1e-6 and ghost[:, 2].max() <= 1.2 + 1e-6


def test_lanelet2_map(clean):
    root = ET.parse(clean.lanelet2_map).getroot()
    nodes = {n.get("id"): n for n in root.iter("node")}
    ways = {w.get("id"): w for w in root.iter("way")}
    lanelets = [r for r in root.iter("relation")
                if any(t.get("k") == "type" and t.get("v") == "lanelet" for t in r.iter("tag"))]
    assert lanelets
    for rel in lanelets:
        roles = {m.get("role"): m.get("ref") for m in rel.iter("member")}
        assert set(roles) == {"left", "right"} and all(r in ways for r in roles.values())
    xy = np.array([[float(t.get("v")) for t in n.iter("tag") if t.get("k") in ("local_x", "local_y")]
                   for n in nodes.values()])
    assert xy.shape == (len(nodes), 2)
    for w in ways.values():
        assert all(nd.get("ref") in nodes for nd in w.iter("nd"))
    # the ego drives inside the mapped road: a lane boundary node within 4 m of every pose
    ds = T4Dataset(clean.root)
    for tok in ds.sample_tokens:
        ego = ds.ego_pose(tok)[:2, 3]
        assert np.hypot(*(xy - ego).T).min() < 4.0


def test_bad_defect(tmp_path):
    with pytest.raises(ValueError, match="defect"):
        generate_t4_dataset(tmp_path, defect="bogus")


def test_demo_fixture_is_current(tmp_path):
    demo = REPO / "fixtures" / "t4" / "clean"
    if not demo.is_dir():
        pytest.skip(f"{demo} is absent: python examples/make_obstacle_demo_data.py makes it")
    m = generate_t4_dataset(tmp_path / "clean", points_per_frame=12000)
    for p in sorted((demo / "annotation").glob("*.json")):
        assert p.read_bytes() == (m.root / "annotation" / p.name).read_bytes(), p.name
