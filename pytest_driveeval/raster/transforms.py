"""Matrices between the world, the ego's frame and the raster, with l5kit's numbers.

l5kit's RenderContext builds ``raster_from_local`` = scale by 1 / pixel_size
and move the origin to ``ego_center * raster_size`` pixels; with
``set_origin_to_bottom`` it then flips y (``diag(1, -1, 1)`` on the left) and
adds the raster height to the y offset, so +y in the ego frame (its left)
points up the image.  ``raster_from_world`` is that times the inverse of the
ego pose ``[[cos, -sin, x], [sin, cos, y], [0, 0, 1]]``, inverted with
``np.linalg.inv`` as l5kit does (not transposed), so the values match to
the last bit.  Points are transformed as row vectors:
``p @ M[:2, :2].T + M[:2, 2]``.
"""
from __future__ import annotations

import numpy as np

from ..geometry import transform_points, world_from_agent
from .params import RasterParams

__all__ = ["raster_centre_in_world", "raster_from_local", "raster_from_world", "world_matrices"]


def raster_from_local(params: RasterParams) -> np.ndarray:
    size = np.array(params.raster_size)
    scaling = 1.0 / np.array(params.pixel_size)
    centre = np.array(params.ego_center) * size
    matrix = np.array([[scaling[0], 0, centre[0]], [0, scaling[1], centre[1]], [0, 0, 1]])
    if params.set_origin_to_bottom:
        flip = np.eye(3)
        flip[1, 1] = -1
        matrix = np.matmul(flip, matrix)
        matrix[1, 2] += size[1]
    return matrix


def raster_from_world(params: RasterParams, xy: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """(B, 3, 3) for ego positions ``xy`` (B, 2) and yaws (B,) in the world."""
    return world_matrices(raster_from_local(params), xy, yaw)


def world_matrices(local: np.ndarray, xy: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """``raster_from_world`` with ``raster_from_local`` given (a caller's, made once)."""
    xy = np.asarray(xy, np.float64).reshape(-1, 2)
    yaw = np.asarray(yaw, np.float64).reshape(-1)
    return local @ np.linalg.inv(world_from_agent(xy, yaw))


def raster_centre_in_world(params: RasterParams, raster_from_world_: np.ndarray) -> np.ndarray:
    """(B, 2): where the raster's middle (size / 2 pixels) lies in the world; l5kit
    queries map elements around it, not around the ego."""
    world_from_raster = np.linalg.inv(raster_from_world_)
    centre = np.asarray(params.raster_size, np.float64) * (0.5, 0.5)
    return transform_points(np.broadcast_to(centre, (world_from_raster.shape[0], 1, 2)), world_from_raster)[:, 0]
