"""Quaternions and 3-D rigid transforms, vectorised over leading axes.

Two orders meet in our data: ROS messages (TF, PointCloud2 poses) write
(x, y, z, w); t4_dataset / nuScenes tables write (w, x, y, z).  Functions say
which they take in their names; the plain ones are ROS order.
"""
from __future__ import annotations

import numpy as np


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """(..., 4) quaternions (x, y, z, w) -> (..., 3, 3) rotation matrices."""
    q = np.asarray(q, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    x, y, z, w = np.moveaxis(q, -1, 0)
    m = np.empty(q.shape[:-1] + (3, 3))
    m[..., 0, 0] = 1 - 2 * (y * y + z * z)
    m[..., 0, 1] = 2 * (x * y - z * w)
    m[..., 0, 2] = 2 * (x * z + y * w)
    m[..., 1, 0] = 2 * (x * y + z * w)
    m[..., 1, 1] = 1 - 2 * (x * x + z * z)
    m[..., 1, 2] = 2 * (y * z - x * w)
    m[..., 2, 0] = 2 * (x * z - y * w)
    m[..., 2, 1] = 2 * (y * z + x * w)
    m[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return m


def matrix_to_quat(m: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotation matrices -> (..., 4) quaternions (x, y, z, w), w >= 0."""
    m = np.asarray(m, dtype=np.float64)[..., :3, :3]
    # Squared magnitudes from the diagonal; signs from the off-diagonal terms.
    tr = np.stack([1 + m[..., 0, 0] - m[..., 1, 1] - m[..., 2, 2],
                   1 - m[..., 0, 0] + m[..., 1, 1] - m[..., 2, 2],
                   1 - m[..., 0, 0] - m[..., 1, 1] + m[..., 2, 2],
                   1 + m[..., 0, 0] + m[..., 1, 1] + m[..., 2, 2]], axis=-1)
    mag = 0.5 * np.sqrt(np.clip(tr, 0, None))
    x = np.copysign(mag[..., 0], m[..., 2, 1] - m[..., 1, 2])
    y = np.copysign(mag[..., 1], m[..., 0, 2] - m[..., 2, 0])
    z = np.copysign(mag[..., 2], m[..., 1, 0] - m[..., 0, 1])
    q = np.stack([x, y, z, mag[..., 3]], axis=-1)
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def transform_matrix(translation, rotation_xyzw) -> np.ndarray:
    """(..., 4, 4) homogeneous transforms."""
    t = np.asarray(translation, dtype=np.float64)
    r = quat_to_matrix(rotation_xyzw)
    out = np.zeros(r.shape[:-2] + (4, 4))
    out[..., :3, :3] = r
    out[..., :3, 3] = t
    out[..., 3, 3] = 1.0
    return out


def slerp(q0: np.ndarray, q1: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Vectorised spherical interpolation of (N, 4) unit quaternions at fractions (N,)."""
    q0 = np.asarray(q0, dtype=np.float64)
    q1 = np.asarray(q1, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64)[..., None]
    dot = np.sum(q0 * q1, axis=-1, keepdims=True)
    q1 = np.where(dot < 0, -q1, q1)  # take the short way round
    dot = np.abs(dot)
    theta = np.arccos(np.clip(dot, -1.0, 1.0))
    sin = np.sin(theta)
    near = sin < 1e-9  # (almost) identical: slerp degenerates to lerp
    safe = np.where(near, 1.0, sin)
    w0 = np.where(near, 1 - t, np.sin((1 - t) * theta) / safe)
    w1 = np.where(near, t, np.sin(t * theta) / safe)
    q = w0 * q0 + w1 * q1
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def rigid_inverse(m: np.ndarray) -> np.ndarray:
    """Inverse of (..., 4, 4) rigid transforms: exact, unlike a general matrix inverse."""
    out = np.zeros_like(m)
    rt = np.swapaxes(m[..., :3, :3], -1, -2)
    out[..., :3, :3] = rt
    out[..., :3, 3] = -(rt @ m[..., :3, 3, None])[..., 0]
    out[..., 3, 3] = 1.0
    return out


def quat_wxyz_to_matrix(q) -> np.ndarray:
    """(..., 4) quaternions (w, x, y, z), the t4/nuScenes order -> (..., 3, 3)."""
    return quat_to_matrix(np.asarray(q, dtype=np.float64)[..., [1, 2, 3, 0]])


def matrix_to_quat_wxyz(m: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotations -> (..., 4) quaternions (w, x, y, z)."""
    return matrix_to_quat(m)[..., [3, 0, 1, 2]]


def yaw_from_quat_wxyz(q) -> np.ndarray:
    """Heading (rotation about z) of (..., 4) quaternions (w, x, y, z)."""
    q = np.asarray(q, dtype=np.float64)
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))


def quat_wxyz_from_yaw(yaw) -> list[float]:
    """The (w, x, y, z) quaternion of a rotation by ``yaw`` about z, as plain floats."""
    return [float(np.cos(yaw / 2)), 0.0, 0.0, float(np.sin(yaw / 2))]


def matrix_to_rpy(m: np.ndarray) -> tuple[float, float, float]:
    """Roll, pitch, yaw (ZYX Euler angles, as ROS's tf2 gives them) of one 3x3 rotation."""
    return (float(np.arctan2(m[2, 1], m[2, 2])), float(-np.arcsin(np.clip(m[2, 0], -1, 1))),
            float(np.arctan2(m[1, 0], m[0, 0])))
