"""Off the road in a CommonRoad scene: some corner of the ego's box outside every lanelet, decided by the
lanelets' own outlines wherever the raster could be wrong, so that we are never the stricter one.

The drivable raster (sim.blueprints.road, ``resolution`` m cells, a cell drivable when its centre is in
a lanelet) is fast but wrong within a cell of the road's edge: a corner 2 cm inside the edge can fall
in a cell whose centre is outside, and be off the road for us while commonroad-io, shapely and the
drivability checker all put it on.  So the raster decides only away from its edge; a corner in the
band of cells next to the edge (EDGE cells of :func:`road_cells`) is on the road when it lies in some lanelet's
outline or within :data:`~pytest_driveeval.io.commonroad.commonroad_geometry.ROAD_TOLERANCE` of one
(the drivability checker's 1 mm buffer over the hairline gaps between lanelets).  Off the road then
holds only where the union of lanelets (commonroad-io's lanelet polygons) puts a corner outside by
more than that tolerance.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from pytest_driveeval.io.commonroad.commonroad_geometry import ROAD_TOLERANCE, on_road

__all__ = ["road_cells", "corners_on_road", "OFF", "ON", "EDGE"]

#: a cell of :func:`road_cells`: off the road, on it, or within a cell of the raster's edge
OFF, ON, EDGE = 0, 1, 2


def road_cells(grid: Any) -> np.ndarray:
    """(like ``grid.mask``) int8: ON where the cell and its 8 neighbours are drivable, OFF where none is,
    EDGE in between: the band, two cells wide, along every edge of the raster's drivable area."""
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
    cells = np.full(mask.shape, OFF, np.int8)
    cells[all_on] = ON
    cells[any_on & ~all_on] = EDGE
    # the rim (the raster pads the road by metres) stays off: corners beyond the raster are clipped onto it
    cells[[0, -1], :] = OFF
    cells[:, [0, -1]] = OFF
    return cells


def corners_on_road(scene: Any, corners: np.ndarray) -> np.ndarray:
    """(E, 4) whether each corner (E, 4, 2) of the ego's box is on the road of the CommonRoad scene."""
    grid = scene.road.drivable
    cells = scene.road_cells
    # one raster lookup, fewer operations than the blueprints' off-road test: a corner beyond the
    # raster is clipped onto its rim, whose cells road_cells keeps OFF
    idx = np.floor((corners - grid.origin) / grid.resolution).astype(np.int64)
    nx, ny = cells.shape
    state = cells[np.clip(idx[..., 0], 0, nx - 1), np.clip(idx[..., 1], 0, ny - 1)]
    on = state == ON
    if state.max(initial=OFF) == EDGE:
        near = state == EDGE
        points = corners[near]
        on[near] = on_road(scene.scenario, points[:, 0], points[:, 1], tolerance=ROAD_TOLERANCE)
    return on
