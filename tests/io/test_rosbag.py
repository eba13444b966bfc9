"""ROS 2 bag reading/writing: PointCloud2 streaming, TF, diagnostics, error paths."""
from __future__ import annotations

import re
import shlex
import shutil
import sqlite3
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from pytest_driveeval.io.ros.pointcloud2 import (
    XYZI_FIELDS,
    XYZIRC_FIELDS,
    Field,
    PointCloud2Error,
    decode_pointcloud2,
    encode_pointcloud2,
    make_cloud,
)
from pytest_driveeval.io.ros.rosbag import (
    POINTCLOUD2,
    Bag,
    BagError,
    BagWriter,
    DiagnosticsLog,
    default_typestore,
    diagnostic_array,
    iter_pointclouds,
    read_diagnostics,
    read_tf,
    tf_message,
)

# a fast reader / score / report check: CI runs these at the lowest declared versions (-m smoke)
pytestmark = pytest.mark.smoke

T0 = 1_700_000_000_000_000_000
STORAGES = ["sqlite3", "mcap"]


def write_demo_bag(path, storage, frames=5, n=100):
    clouds = [make_cloud(n, XYZIRC_FIELDS, rng=np.random.default_rng(i)) for i in range(frames)]
    with BagWriter(path, storage) as w:
        for i, c in enumerate(clouds):
            stamp = T0 + i * 100_000_000
            w.write("/points", encode_pointcloud2(c, "base_link", stamp), log_time_ns=stamp + 5_000_000)
            w.write("/tf", tf_message([("map", "base_link", stamp, (i, 0, 0), (0, 0, 0, 1))]))
            w.write("/diagnostics", diagnostic_array(stamp, [
                ("topic_state_monitor: /points", 0 if i < 3 else 1, "OK" if i < 3 else "rate low",
                 {"rate": 10.0})]))
        w.write("/tf_static", tf_message([("base_link", "lidar", T0, (1, 0, 2), (0, 0, 0, 1))]),
                log_time_ns=T0)
    return clouds


@pytest.mark.parametrize("storage", STORAGES)
def test_pointcloud_stream_roundtrip(tmp_path, storage):
    clouds = write_demo_bag(tmp_path / "bag", storage)
    frames = list(iter_pointclouds(tmp_path / "bag", "/points"))
    assert len(frames) == len(clouds)
    for i, (stamp, frame_id, pts) in enumerate(frames):
        assert stamp == T0 + i * 100_000_000  # header stamp, not the log time
        assert frame_id == "base_link"
        assert pts.dtype == clouds[i].dtype and np.array_equal(pts, clouds[i])
        assert pts.dtype["channel"] == np.uint16 and pts.dtype.itemsize == 16


@pytest.mark.parametrize("storage", STORAGES)
def test_tf_and_diagnostics_from_generated_bag(tmp_path, storage):
    write_demo_bag(tmp_path / "bag", storage)
    tf = read_tf(tmp_path / "bag")
    m = tf.lookup("map", "lidar", T0 + 150_000_000)
    assert np.allclose(m[:3, 3], [2.5, 0, 2])  # halfway between x=1 and x=2, plus static offset
    diag = read_diagnostics(tmp_path / "bag")
    assert len(diag) == 5 and diag.status_names() == ["topic_state_monitor: /points"]
    rec = diag.status_at("topic_state_monitor: /points", T0 + 350_000_000)
    assert rec.level == DiagnosticsLog.WARN and rec.message == "rate low"
    assert rec.values == {"rate": "10.0"}
    assert diag.status_at("topic_state_monitor: /points", T0 - 1) is None
    levels = diag.levels_at("topic_state_monitor: /points", T0 + np.arange(6) * 100_000_000 - 1)
    assert levels.tolist() == [-1, 0, 0, 0, 1, 1]
    assert diag.levels_at("other", [T0]).tolist() == [-1]


def test_missing_topic_lists_available(tmp_path):
    write_demo_bag(tmp_path / "bag", "sqlite3", frames=1)
    with pytest.raises(BagError, match=r"'/lidar' not in bag; available: /diagnostics .*/points"):
        list(iter_pointclouds(tmp_path / "bag", "/lidar"))
    with Bag(tmp_path / "bag") as bag:
        with pytest.raises(BagError, match="expected sensor_msgs/msg/PointCloud2"):
            next(bag.pointclouds("/tf"))
        assert bag.message_count("/points") == 1


def test_missing_bag(tmp_path):
    with pytest.raises(BagError, match="nowhere"):
        Bag(tmp_path / "nowhere")


@pytest.mark.parametrize("storage, suffix", [("sqlite3", ".db3"), ("mcap", ".mcap")])
def test_truncated_bag_names_file(tmp_path, storage, suffix):
    write_demo_bag(tmp_path / "bag", storage, frames=20, n=2000)
    (f,) = (tmp_path / "bag").glob("*" + suffix)
    raw = f.read_bytes()
    f.write_bytes(raw[: len(raw) // 2])
    with pytest.raises(BagError, match=rf"bag.*{suffix}") as exc:
        list(iter_pointclouds(tmp_path / "bag", "/points"))
    if storage == "sqlite3":
        assert "malformed; the .db3 file is damaged (bytes missing or overwritten): `sqlite3 <file>.db3 .recover" \
            in str(exc.value)


def test_unknown_message_type(tmp_path):
    from rosbags.rosbag2 import Writer
    with Writer(tmp_path / "bag", version=8) as w:
        conn = w.add_connection("/custom", "my_msgs/msg/Unknown", msgdef="", rihs01="RIHS01_" + "0" * 64)
        w.write(conn, T0, b"\x00\x01\x00\x00")
    with Bag(tmp_path / "bag") as bag, \
            pytest.raises(BagError, match=r"'/custom': unknown message type 'my_msgs/msg/Unknown'"):
        list(bag.messages("/custom"))


def test_custom_type_registered_from_bag_definition(tmp_path):
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore
    ts = get_typestore(Stores.ROS2_HUMBLE)
    ts.register(get_types_from_msg("int32 a\nstring b", "my_msgs/msg/Thing"))
    msg = ts.types["my_msgs/msg/Thing"](a=7, b="x")
    with Writer(tmp_path / "bag", version=8) as w:
        conn = w.add_connection("/thing", "my_msgs/msg/Thing", typestore=ts)
        w.write(conn, T0, ts.serialize_cdr(msg, "my_msgs/msg/Thing"))
    with Bag(tmp_path / "bag") as bag:  # default typestore lacks the type
        ((_, m),) = list(bag.messages("/thing"))
        assert (m.a, m.b) == (7, "x")


def test_real_tf_bag_topics(shared_data):
    with Bag(shared_data / "rosbag/tf_example") as bag:
        assert bag.topics == {"/tf": "tf2_msgs/msg/TFMessage", "/tf_static": "tf2_msgs/msg/TFMessage"}
        assert bag.message_count("/tf") == 517
        with pytest.raises(BagError, match="no diagnostics|'/diagnostics' not in bag"):
            bag.read_diagnostics()


# --- PointCloud2 decoding details -----------------------------------------
class Msg:
    def __init__(self, **kw):
        self.__dict__.update(kw)


def test_decode_is_zero_copy_view():
    cloud = make_cloud(1000, XYZIRC_FIELDS)
    msg = encode_pointcloud2(cloud, "lidar", T0)
    pts = decode_pointcloud2(msg)
    assert np.shares_memory(pts, msg.data) and np.array_equal(pts, cloud)


def test_decode_float_intensity_padded_points():
    cloud = make_cloud(10, XYZI_FIELDS, point_step=32)  # like pcl::PointXYZI
    pts = decode_pointcloud2(encode_pointcloud2(cloud, "l", 0))
    assert pts.dtype.itemsize == 32 and pts.dtype["intensity"] == np.float32
    assert np.array_equal(pts["intensity"], cloud["intensity"])


def test_decode_row_padding_and_bigendian():
    h, w, step, row = 3, 4, 8, 40  # 8 bytes of padding at the end of each row
    vals = np.arange(h * w, dtype=">f4")
    data = np.zeros(h * row, np.uint8)
    for r in range(h):
        block = np.zeros(w, dtype=[("x", ">f4"), ("c", ">u2"), ("p", "V2")])
        block["x"] = vals[r * w:(r + 1) * w]
        block["c"] = np.arange(w) + 100 * r
        data[r * row:r * row + w * step] = block.view(np.uint8)
    msg = Msg(height=h, width=w, point_step=step, row_step=row, is_bigendian=True, data=data,
              fields=[Field("x", 0, 7), Field("c", 4, 4)])
    pts = decode_pointcloud2(msg)
    assert pts.shape == (12,) and pts["x"].tolist() == vals.tolist()
    assert pts["c"].reshape(h, w)[2].tolist() == [200, 201, 202, 203]


def test_decode_count_subarray_and_errors():
    data = np.arange(4 * 3, dtype="<f4").view(np.uint8)
    msg = Msg(height=1, width=4, point_step=12, row_step=48, is_bigendian=False, data=data,
              fields=[Field("xyz", 0, 7, 3)])
    assert decode_pointcloud2(msg)["xyz"].shape == (4, 3)
    msg.data = data[:-1]
    with pytest.raises(PointCloud2Error, match="47 bytes"):
        decode_pointcloud2(msg, where="b.db3 /p message #3")
    msg.data, msg.fields = data, [Field("x", 10, 7)]
    with pytest.raises(PointCloud2Error, match="exceeds point_step"):
        decode_pointcloud2(msg)
    msg.fields = [Field("x", 0, 9)]
    with pytest.raises(PointCloud2Error, match="unknown datatype 9"):
        decode_pointcloud2(msg)


def test_encode_uses_typestore_message():
    msg = encode_pointcloud2(make_cloud(5), "lidar", T0 + 123)
    raw = default_typestore().serialize_cdr(msg, "sensor_msgs/msg/PointCloud2")
    back = default_typestore().deserialize_cdr(raw, "sensor_msgs/msg/PointCloud2")
    assert back.header.stamp.nanosec == 123 and [f.name for f in back.fields] == \
        ["x", "y", "z", "intensity", "return_type", "channel"]


# --- issue 11: every bad bag is a BagError that says which bag, what is wrong and how to fix it ------
def _ros1_bag(path, stamp_ns=T0):
    """A one-cloud ROS 1 bag, as rosbag record in ROS 1 writes it."""
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC)
    T = ts.types
    cloud = make_cloud(10)
    ros2 = encode_pointcloud2(cloud, "base_link", stamp_ns)
    sec, nsec = divmod(stamp_ns, 1_000_000_000)
    msg = T["sensor_msgs/msg/PointCloud2"](
        header=T["std_msgs/msg/Header"](seq=0, stamp=T["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec),
                                        frame_id="base_link"),
        height=1, width=cloud.size, is_bigendian=False, point_step=ros2.point_step, row_step=ros2.row_step,
        data=ros2.data, is_dense=True,
        fields=[T["sensor_msgs/msg/PointField"](name=f.name, offset=f.offset, datatype=f.datatype, count=f.count)
                for f in ros2.fields])
    with Writer(path) as w:
        conn = w.add_connection("/points", "sensor_msgs/msg/PointCloud2", typestore=ts)
        w.write(conn, stamp_ns, ts.serialize_ros1(msg, "sensor_msgs/msg/PointCloud2"))
    return cloud


@pytest.mark.parametrize("storage", STORAGES)
def test_a_folder_without_metadata_yaml_is_read_through_its_storage_file(tmp_path, storage):
    clouds = write_demo_bag(tmp_path / "input_bag", storage)
    (tmp_path / "input_bag/metadata.yaml").unlink()
    frames = list(iter_pointclouds(tmp_path / "input_bag", "/points"))
    assert [f.stamp_ns for f in frames] == [T0 + i * 100_000_000 for i in range(5)]
    assert all(np.array_equal(f.points, c) for f, c in zip(frames, clouds))
    assert read_tf(tmp_path / "input_bag").lookup("map", "lidar", T0)[0, 3] == 1.0


def writable_copy(src, dst):
    """A copy of shared (read-only) data that a test may damage."""
    shutil.copytree(src, dst)
    for p in [dst, *dst.rglob("*")]:
        p.chmod(0o755 if p.is_dir() else 0o644)
    return dst


def test_the_real_tf_bag_without_metadata_yaml(shared_data, tmp_path):
    writable_copy(shared_data / "rosbag/tf_example", tmp_path / "bag")
    (tmp_path / "bag/metadata.yaml").unlink()
    with Bag(tmp_path / "bag") as bag:
        assert bag.message_count("/tf") == 517 and set(bag.topics) == {"/tf", "/tf_static"}
        assert bag.read_tf().frames == {"odom", "base_footprint", "base_link"}


def test_a_folder_without_metadata_yaml_and_several_or_no_storage_files(tmp_path):
    write_demo_bag(tmp_path / "bag", "sqlite3", frames=1)
    (tmp_path / "bag/metadata.yaml").unlink()
    shutil.copy(tmp_path / "bag/bag.db3", tmp_path / "bag/bag_1.db3")
    with pytest.raises(BagError, match=r"bag: no metadata.yaml, and 2 storage files \(bag.db3, bag_1.db3\); a bag "
                                       r"split over several files is read through its metadata.yaml: recreate it "
                                       r"with `ros2 bag reindex .*bag`$"):
        Bag(tmp_path / "bag")
    (tmp_path / "empty").mkdir()
    (tmp_path / "empty/notes.txt").write_text("")
    with pytest.raises(BagError, match=r"empty: not a ROS 2 bag: no metadata.yaml and no .db3 or .mcap file "
                                       r"\(found: notes.txt\)"):
        Bag(tmp_path / "empty")


def test_a_ros1_bag_says_how_to_convert_it_and_the_advice_works(tmp_path):
    cloud = _ros1_bag(tmp_path / "run.bag")
    with pytest.raises(BagError) as exc:
        Bag(tmp_path / "run.bag")
    assert str(exc.value) == (f"{tmp_path}/run.bag: a ROS 1 bag, and only ROS 2 bags (.db3 or .mcap storage) can "
                              f"be read; convert it with `rosbags-convert --src {tmp_path}/run.bag --dst "
                              f"{tmp_path}/run` (from the rosbags package) and read that folder instead")
    (tmp_path / "input_bag").mkdir()
    shutil.move(tmp_path / "run.bag", tmp_path / "input_bag/run.bag")
    with pytest.raises(BagError, match=rf"input_bag: holds a ROS 1 bag \(run.bag\), .* `rosbags-convert --src "
                                       rf"{tmp_path}/input_bag/run.bag --dst {tmp_path}/input_bag_ros2` .* and put "
                                       rf"that folder in place of {tmp_path}/input_bag$") as exc:
        Bag(tmp_path / "input_bag")
    command = shlex.split(re.search(r"`(rosbags-convert [^`]+)`", str(exc.value)).group(1))
    convert = shutil.which("rosbags-convert") or str(Path(sys.executable).parent / "rosbags-convert")
    subprocess.run([convert, *command[1:]], check=True, capture_output=True)
    (frame,) = iter_pointclouds(tmp_path / "input_bag_ros2", "/points")
    assert frame.stamp_ns == T0 and np.array_equal(frame.points, cloud)


def test_a_pointcloud_topic_without_messages_names_it_and_lists_the_bag(tmp_path):
    from rosbags.rosbag2 import Writer
    with Writer(tmp_path / "bag", version=8) as w:
        w.add_connection("/points", POINTCLOUD2, typestore=default_typestore())
        conn = w.add_connection("/tf", "tf2_msgs/msg/TFMessage", typestore=default_typestore())
        w.write(conn, T0, default_typestore().serialize_cdr(
            tf_message([("map", "base_link", T0, (0, 0, 0), (0, 0, 0, 1))]), "tf2_msgs/msg/TFMessage"))
    with pytest.raises(BagError) as exc:
        list(iter_pointclouds(tmp_path / "bag", "/points"))
    assert str(exc.value) == (f"{tmp_path}/bag: topic '/points' has no messages; the bag holds: "
                              "/points [sensor_msgs/msg/PointCloud2] x0, /tf [tf2_msgs/msg/TFMessage] x1")
    write_demo_bag(tmp_path / "demo", "mcap", frames=2)
    with pytest.raises(BagError, match=r"demo: topic '/points' has no messages with log time in "
                                       r"\[1700000001.000000000, inf\); the bag holds: /diagnostics "):
        list(iter_pointclouds(tmp_path / "demo", "/points", start_ns=T0 + 10**9))


def test_a_cloud_longer_than_its_layout_names_bag_message_stamp_and_frame(tmp_path):
    cloud = make_cloud(20)
    good, bad = encode_pointcloud2(cloud, "lidar", T0), encode_pointcloud2(cloud, "lidar", T0 + 10**8)
    bad = replace(bad, height=3, width=5, row_step=bad.point_step * 5)  # 4 rows of 5 points are there
    with BagWriter(tmp_path / "bag", "mcap") as w:
        w.write("/points", good)
        w.write("/points", bad)
    frames = iter_pointclouds(tmp_path / "bag", "/points")
    assert next(frames).points.size == 20
    with pytest.raises(BagError) as exc:
        next(frames)
    assert str(exc.value) == (f"{tmp_path}/bag: /points message #1 (stamp 1700000000.100000000, frame 'lidar'): "
                              "data has 320 bytes, the layout needs 240 (height 3 x row_step 80): "
                              "1 row(s) more than height 3")


def test_messages_deleted_from_a_bag_are_missing_not_a_shorter_run(tmp_path):
    write_demo_bag(tmp_path / "bag", "sqlite3", frames=10, n=10)
    db = tmp_path / "bag/bag.db3"
    with sqlite3.connect(db) as con:
        con.execute("DELETE FROM messages WHERE topic_id = (SELECT id FROM topics WHERE name = '/points') "
                    "AND timestamp BETWEEN ? AND ?", (T0 + 300_000_000, T0 + 600_000_000))
    con.close()
    with pytest.raises(BagError) as exc:
        list(iter_pointclouds(tmp_path / "bag", "/points"))
    assert str(exc.value) == (
        f"{tmp_path}/bag: topic '/points': metadata.yaml lists 10 messages, but only 7 can be read (storage files "
        "bag.db3): 3 are missing (deleted, or lost with a damaged part of the file); the longest gap, 0.400 s, is "
        "between message #2 (log time 1700000000.205000000) and #3 (log time 1700000000.605000000)")


def test_rows_deleted_from_the_real_tf_bag(shared_data, tmp_path):
    writable_copy(shared_data / "rosbag/tf_example", tmp_path / "bag")
    (db,) = (tmp_path / "bag").glob("*.db3")
    with sqlite3.connect(db) as con:
        (first,) = con.execute("SELECT MIN(timestamp) FROM messages").fetchone()
        con.execute("DELETE FROM messages WHERE timestamp BETWEEN ? AND ?", (first + 10**10, first + 2 * 10**10))
    con.close()
    with pytest.raises(BagError, match=r"topic '/tf': metadata.yaml lists 517 messages, but only \d+ can be read "
                                       r".*the longest gap, 10\.\d+ s, is between message #\d+ "):
        read_tf(tmp_path / "bag")


def test_messages_deleted_at_the_end_say_where_they_stop(tmp_path):
    write_demo_bag(tmp_path / "bag", "sqlite3", frames=10, n=10)
    with sqlite3.connect(tmp_path / "bag/bag.db3") as con:
        con.execute("DELETE FROM messages WHERE topic_id = (SELECT id FROM topics WHERE name = '/points') "
                    "AND timestamp > ?", (T0 + 650_000_000,))
    con.close()
    with pytest.raises(BagError, match=r"only 7 can be read .*: 3 are missing .*; the messages stop at #6 \(log time "
                                       r"1700000000.605000000\), 0.300 s before the bag ends \(log time "
                                       r"1700000000.905000000\)$"):
        list(iter_pointclouds(tmp_path / "bag", "/points"))
