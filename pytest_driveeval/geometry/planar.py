"""Planar rigid transforms, vectorised over leading axes.

Conventions (shared with l5kit so logged data can be used unchanged): yaw is
the heading in radians, counter-clockwise from the world x axis; transforms
are (..., 3, 3) homogeneous matrices.  Every function broadcasts over leading
dimensions, so a whole scene (scenes, frames, agents) goes through in one call.
"""
from __future__ import annotations

import numpy as np


def norm2d(v: np.ndarray) -> np.ndarray:
    """(..., 2) -> (...) Euclidean length.

    Not np.hypot: that is ~10x slower and its overflow safety is moot at
    driving scales.
    """
    v = np.asarray(v, dtype=np.float64)
    x, y = v[..., 0], v[..., 1]
    return np.sqrt(x * x + y * y)


def wrap_angle(angle: np.ndarray) -> np.ndarray:
    """Wrap angles to [-pi, pi)."""
    return (np.asarray(angle, dtype=np.float64) + np.pi) % (2.0 * np.pi) - np.pi


def arc_lengths(line: np.ndarray) -> np.ndarray:
    """(K,) distance along a polyline (K, 2) from its first point to each of its points."""
    return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(line, axis=0), axis=1))])


def resampled(line: np.ndarray, count: int) -> np.ndarray:
    """(count, 2) points at equal distances along a polyline (K, 2), its ends kept (a line of one
    repeated point stays that point)."""
    along = arc_lengths(line)
    at = np.linspace(0.0, along[-1], count)
    return np.stack([np.interp(at, along, line[:, 0]), np.interp(at, along, line[:, 1])], axis=1)


def yaw_as_rotation33(yaw: np.ndarray) -> np.ndarray:
    """(...) yaw -> (..., 3, 3) homogeneous rotation."""
    yaw = np.asarray(yaw, dtype=np.float64)
    c, s = np.cos(yaw), np.sin(yaw)
    out = np.zeros(yaw.shape + (3, 3))
    out[..., 0, 0], out[..., 0, 1] = c, -s
    out[..., 1, 0], out[..., 1, 1] = s, c
    out[..., 2, 2] = 1.0
    return out


def yaw_from_rotation33(matrix: np.ndarray) -> np.ndarray:
    """(..., 3, 3) (or (..., 2, 2)) rotation -> (...) yaw in [-pi, pi]."""
    matrix = np.asarray(matrix)
    return np.arctan2(matrix[..., 1, 0], matrix[..., 0, 0])


def world_from_agent(centroid: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """(..., 2) centroid, (...) yaw -> (..., 3, 3) mapping agent frame to world."""
    yaw = np.asarray(yaw, dtype=np.float64)
    centroid = np.asarray(centroid, dtype=np.float64)
    lead = np.broadcast_shapes(yaw.shape, centroid.shape[:-1])
    out = np.broadcast_to(yaw_as_rotation33(yaw), lead + (3, 3)).copy()
    out[..., :2, 2] = centroid
    return out


def agent_from_world(centroid: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """Inverse of :func:`world_from_agent`, in closed form (R^T, -R^T t)."""
    m = world_from_agent(centroid, yaw)
    rt = np.swapaxes(m[..., :2, :2], -1, -2)
    out = np.zeros_like(m)
    out[..., :2, :2] = rt
    out[..., :2, 2] = -np.einsum("...ij,...j->...i", rt, m[..., :2, 2])
    out[..., 2, 2] = 1.0
    return out


def transform_points(points: np.ndarray, matrix: np.ndarray) -> np.ndarray:
    """Apply (..., 3, 3) homogeneous transforms to (..., N, 2) points."""
    points = np.asarray(points, dtype=np.float64)
    matrix = np.asarray(matrix, dtype=np.float64)
    return points @ np.swapaxes(matrix[..., :2, :2], -1, -2) + matrix[..., None, :2, 2]
