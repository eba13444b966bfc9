"""Off the road in a CommonRoad scene: some corner of the ego's box outside every lanelet, decided by the
lanelets' own outlines wherever the raster could be wrong, so that we are never the stricter one.

The drivable raster (sim.blueprints.road, ``resolution`` m cells, a cell drivable when its centre is in
a lanelet) is fast but wrong within a cell of the road's edge: a corner 2 cm inside the edge can fall
in a cell whose centre is outside, and be off the road for us while commonroad-io, shapely and the
drivability checker all put it on.  So the raster decides only away from its edge; a corner in the
band of cells next to the edge (:func:`road_band`) is on the road when it lies in some lanelet's
outline or within :data:`~pytest_driveeval.io.commonroad.commonroad_geometry.ROAD_TOLERANCE` of one
(the drivability checker's 1 mm buffer over the hairline gaps between lanelets).  Off the road then
holds only where the union of lanelets (commonroad-io's lanelet polygons) puts a corner outside by
more than that tolerance.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from pytest_driveeval.io.commonroad.commonroad_geometry import ROAD_TOLERANCE, on_road
from pytest_driveeval.metrics.episode_outcomes import cells_contain

__all__ = ["road_band", "corners_on_road"]


def road_band(grid: Any) -> np.ndarray:
    """(like ``grid.mask``) the cells whose 3 x 3 neighbourhood is not all drivable or all not: the band,
    two cells wide, along every edge of the raster's drivable area."""
    mask = grid.mask
    padded = np.pad(mask, 1, mode="edge")
    nx, ny = mask.shape
    any_on = np.zeros_like(mask)
    all_on = np.ones_like(mask)
    for dx in range(3):
        for dy in range(3):
            window = padded[dx:dx + nx, dy:dy + ny]
            any_on |= window
            all_on &= window
    return any_on & ~all_on


def corners_on_road(scene: Any, corners: np.ndarray) -> np.ndarray:
    """(E, 4) whether each corner (E, 4, 2) of the ego's box is on the road of the CommonRoad scene."""
    grid = scene.road.drivable
    inside = cells_contain(corners, grid.mask, grid.origin, grid.resolution)
    band = scene.road_band
    if band is not None:
        near = cells_contain(corners, band, grid.origin, grid.resolution)
        if near.any():
            points = corners[near]
            inside[near] = on_road(scene.scenario, points[:, 0], points[:, 1], tolerance=ROAD_TOLERANCE)
    return inside
