"""TF buffer: interpolation, composition, error cases, and the real tf_example bag."""
from __future__ import annotations

import numpy as np
import pytest

from pytest_driveeval.io.ros.rosbag import Bag, read_tf
from pytest_driveeval.geometry import matrix_to_quat, quat_to_matrix, slerp, transform_matrix
from pytest_driveeval.io.ros.tf import TFBuffer, TransformError


def yaw_quat(yaw):
    return (0.0, 0.0, np.sin(yaw / 2), np.cos(yaw / 2))


@pytest.fixture
def buf():
    b = TFBuffer(tolerance_ns=5)
    b.add_transforms("map", "odom", [0, 100], [(0, 0, 0), (10, 0, 0)], [yaw_quat(0), yaw_quat(np.pi / 2)])
    b.add_transform("odom", "base_link", 50, (1, 0, 0), yaw_quat(0), static=True)
    b.add_transform("base_link", "lidar", 0, (0, 0, 2), yaw_quat(np.pi), static=True)
    b.add_transforms("map", "car2", [0, 100], [(0, 5, 0), (0, 5, 0)], [yaw_quat(0)] * 2)
    return b


def test_interpolation_and_chain(buf):
    m = buf.lookup("map", "base_link", 50)
    # odom halfway: x=5, yaw=45 deg; base_link 1 m ahead along odom's x axis
    assert np.allclose(m[:3, 3], [5 + np.cos(np.pi / 4), np.sin(np.pi / 4), 0])
    assert np.allclose(matrix_to_quat(m), yaw_quat(np.pi / 4))
    inv = buf.lookup("base_link", "map", 50)
    assert np.allclose(inv @ m, np.eye(4))


def test_sibling_path_and_vectorised(buf):
    stamps = np.array([0, 25, 50, 100])
    many = buf.lookup("car2", "lidar", stamps)
    assert many.shape == (4, 4, 4)
    for s, m in zip(stamps, many):
        expect = np.linalg.inv(buf.lookup("map", "car2", s)) @ buf.lookup("map", "lidar", s)
        assert np.allclose(m, expect)
    p = buf.transform_points(np.zeros((1, 3)), "map", "lidar", 0)
    assert np.allclose(p, [[1, 0, 2]])


def test_out_of_range_and_tolerance(buf):
    buf.lookup("map", "odom", 104)  # within 5 ns tolerance: holds the last sample
    with pytest.raises(TransformError, match=r"'odom' -> 'map' at stamp 106.*\[0, 100\]"):
        buf.lookup("map", "odom", 106)
    with pytest.raises(TransformError, match="stamp -10"):
        buf.lookup("map", "base_link", np.array([0, -10]))


def test_unknown_and_unconnected(buf):
    buf.add_transform("world", "other", 0, (0, 0, 0), (0, 0, 0, 1), static=True)
    with pytest.raises(TransformError, match="not connected"):
        buf.lookup("map", "other", 0)
    with pytest.raises(TransformError, match="'nope' unknown"):
        buf.lookup("nope", "map", 0)
    assert not buf.can_transform("map", "other", 0)
    assert np.allclose(buf.lookup("map", "map", 12345), np.eye(4))


def test_structure_errors(buf):
    with pytest.raises(TransformError, match="already has parent"):
        buf.add_transform("world", "odom", 0, (0, 0, 0), (0, 0, 0, 1))
    with pytest.raises(TransformError, match="cycle"):
        buf.add_transform("lidar", "map", 0, (0, 0, 0), (0, 0, 0, 1))
    assert buf.can_transform("map", "lidar", 10)  # failed adds leave the tree intact


def test_unsorted_and_duplicate_samples():
    b = TFBuffer()
    b.add_transforms("a", "b", [30, 10, 20, 20], [(3, 0, 0), (1, 0, 0), (9, 0, 0), (2, 0, 0)],
                     [(0, 0, 0, 1)] * 4)
    assert b.lookup("a", "b", 25)[0, 3] == pytest.approx(2.5)  # last write of stamp 20 wins


def test_slerp_and_quaternion_helpers():
    rng = np.random.default_rng(1)
    q = rng.normal(size=(50, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    back = matrix_to_quat(quat_to_matrix(q))
    assert np.allclose(np.abs(np.sum(back * q, axis=1)), 1)
    mid = slerp(np.tile(yaw_quat(0), (3, 1)), np.tile(yaw_quat(-0.5), (3, 1)), [0, 0.5, 1])
    assert np.allclose(mid[1], yaw_quat(-0.25)) and np.allclose(mid[2], yaw_quat(-0.5))
    # antipodal representation of the same rotation takes the short path
    assert np.allclose(slerp([yaw_quat(0)], [-np.array(yaw_quat(0.2))], [0.5])[0], yaw_quat(0.1))
    assert np.allclose(transform_matrix((1, 2, 3), (0, 0, 0, 1))[:3, 3], [1, 2, 3])


def test_real_bag_interpolation_by_hand(shared_data):
    path = shared_data / "rosbag/tf_example"
    tf = read_tf(path)
    assert ("base_footprint", "base_link", True) in tf.edges()
    with Bag(path) as bag:
        msgs = [m.transforms[0] for _, m in bag.messages("/tf")]
        (static,) = [m.transforms[0] for _, m in bag.messages("/tf_static")]
    assert (static.header.frame_id, static.child_frame_id) == ("base_footprint", "base_link")
    a, b = msgs[200], msgs[201]
    sa = a.header.stamp.sec * 10**9 + a.header.stamp.nanosec
    sb = b.header.stamp.sec * 10**9 + b.header.stamp.nanosec
    stamp = sa + (sb - sa) // 3
    f = (stamp - sa) / (sb - sa)
    ta = np.array([a.transform.translation.x, a.transform.translation.y, a.transform.translation.z])
    tb = np.array([b.transform.translation.x, b.transform.translation.y, b.transform.translation.z])
    qa = np.array([getattr(a.transform.rotation, k) for k in "xyzw"])
    qb = np.array([getattr(b.transform.rotation, k) for k in "xyzw"])
    if qa @ qb < 0:
        qb = -qb
    theta = np.arccos(np.clip(qa @ qb, -1, 1))
    q = qa if theta < 1e-12 else (np.sin((1 - f) * theta) * qa + np.sin(f * theta) * qb) / np.sin(theta)
    st = static.transform
    static_m = transform_matrix([st.translation.x, st.translation.y, st.translation.z],
                                [st.rotation.x, st.rotation.y, st.rotation.z, st.rotation.w])
    expect = transform_matrix(ta + f * (tb - ta), q) @ static_m
    got = tf.lookup("odom", "base_link", stamp)
    assert np.allclose(got, expect, atol=1e-9)
    assert not np.allclose(got, np.eye(4))
    lo, hi = tf.time_range("odom", "base_footprint")
    assert (hi - lo) / 1e9 == pytest.approx(51.6, abs=0.2)
    assert tf.lookup("base_link", "odom", np.linspace(lo, hi, 1000).astype(np.int64)).shape == (1000, 4, 4)
    with pytest.raises(TransformError, match=r"'base_link' -> 'odom' at stamp"):
        tf.lookup("odom", "base_link", hi + 10**9)
