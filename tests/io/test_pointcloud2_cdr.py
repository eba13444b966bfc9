"""The PointCloud2 CDR reader (io.pointcloud2_cdr) agrees with rosbags' deserializer, or leaves the message to it."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from pytest_driveeval.io.ros.pointcloud2_cdr import read_pointcloud2_cdr, standard_layout
from pytest_driveeval.io.ros.rosbag import POINTCLOUD2, default_typestore

pytest.importorskip("rosbags")

u32 = st.integers(0, 2**32 - 1)
small = st.integers(0, 70)
names = st.text(max_size=6)  # any unicode, empty included
fields = st.lists(st.tuples(names, u32, st.integers(0, 255), u32), max_size=5)


def serialize(frame_id, sec, nanosec, height, width, layout, bigendian, point_step, row_step, data, dense,
              little_endian=True):
    ts = default_typestore()
    T = ts.types
    msg = T[POINTCLOUD2](
        header=T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec),
                                        frame_id=frame_id),
        height=height, width=width,
        fields=[T["sensor_msgs/msg/PointField"](name=n, offset=o, datatype=d, count=c) for n, o, d, c in layout],
        is_bigendian=bigendian, point_step=point_step, row_step=row_step,
        data=np.frombuffer(data, dtype=np.uint8), is_dense=dense)
    return bytes(ts.serialize_cdr(msg, POINTCLOUD2, little_endian=little_endian))


def rosbags_reading(raw):
    try:
        return default_typestore().deserialize_cdr(raw, POINTCLOUD2)
    except Exception:
        return None


def same(ours, msg):
    h = msg.header
    return ((ours.sec, ours.nanosec, ours.frame_id, ours.height, ours.width, ours.is_bigendian, ours.point_step,
             ours.row_step, ours.is_dense) == (h.stamp.sec, h.stamp.nanosec, h.frame_id, msg.height, msg.width,
                                               msg.is_bigendian, msg.point_step, msg.row_step, msg.is_dense)
            and [tuple(f) for f in ours.fields] == [(f.name, f.offset, f.datatype, f.count) for f in msg.fields]
            and ours.data.dtype == msg.data.dtype and ours.data.tobytes() == msg.data.tobytes())


message = st.tuples(names, st.integers(-2**31, 2**31 - 1), u32, small, small, fields, st.booleans(), small, small,
                    st.binary(max_size=40), st.booleans())


@given(message)
def test_every_little_endian_cloud_reads_as_rosbags_reads_it(m):
    raw = serialize(*m)
    ours = read_pointcloud2_cdr(raw)
    assert ours is not None and same(ours, rosbags_reading(raw))
    assert not ours.data.flags.writeable  # a view over the message, as rosbags gives it
    assert not ours.data.size or np.shares_memory(ours.data, np.frombuffer(raw, np.uint8))


@given(message, st.data())
def test_a_damaged_message_reads_as_rosbags_reads_it_or_is_left_to_rosbags(m, data):
    raw = bytearray(serialize(*m))
    how = data.draw(st.sampled_from(["cut", "byte", "append"]))
    if how == "cut":
        raw = raw[:data.draw(st.integers(0, len(raw) - 1))]
    elif how == "byte":
        raw[data.draw(st.integers(0, len(raw) - 1))] = data.draw(st.integers(0, 255))
    else:
        raw += data.draw(st.binary(min_size=1, max_size=12))
    raw = bytes(raw)
    ours, theirs = read_pointcloud2_cdr(raw), rosbags_reading(raw)
    if theirs is None:
        assert ours is None  # rosbags raises: the caller lets it, for its message
    elif ours is not None:
        assert same(ours, theirs)


def test_big_endian_messages_and_long_sequences_are_left_to_rosbags():
    m = ("lidar", 5, 6, 1, 2, [("x", 0, 7, 1)], False, 4, 8, bytes(8), True)
    assert read_pointcloud2_cdr(serialize(*m, little_endian=False)) is None
    raw = serialize(*m)
    assert read_pointcloud2_cdr(raw) is not None
    assert read_pointcloud2_cdr(raw, max_sequence=7) is None  # as a typestore with that limit refuses it


def test_only_a_typestore_with_the_standard_cloud_types_is_read_here():
    from rosbags.typesys import Stores, get_typestore, get_types_from_msg

    ref = default_typestore()
    assert standard_layout(ref, ref) and standard_layout(get_typestore(Stores.ROS2_JAZZY), ref)
    other = get_typestore(Stores.EMPTY)
    other.register(get_types_from_msg("uint32 height", POINTCLOUD2))
    assert not standard_layout(other, ref)
