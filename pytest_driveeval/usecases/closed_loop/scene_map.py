"""The map a scene's bird's-eye GIF draws under its boxes, from the dataset's own map.

A ScenarioNet scenario carries its map: lane surfaces (each lane's polygon, or its measured
boundaries, as :func:`~pytest_driveeval.io.scenarionet.scenarionet_map.scenario_map` builds them), road lines,
road edges and crosswalks.  An L5 zarr carries none (its semantic map is a separate file a raster
model reads), so its GIFs stay on a blank background.  Built here, not in ``io``: the report's
:class:`DrawnMap` is what the renderer takes, and ``io`` does not import the report.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from pytest_driveeval.io.scenarionet.scenarionet import ScenarioNetScene
from pytest_driveeval.io.scenarionet.scenarionet_l5 import ScenarioNetDataset
from pytest_driveeval.io.scenarionet.scenarionet_map import scenario_map
from pytest_driveeval.report.map_layers import DrawnMap

__all__ = ["drawn_map", "drawn_map_of"]


def _outline(feature: Any) -> np.ndarray | None:
    points = feature.polygon if feature.polygon is not None else feature.polyline
    return None if points is None else np.asarray(points, float)[:, :2]


def drawn_map(scene: ScenarioNetScene, made: Any = None) -> DrawnMap:
    """The scenario's map as the GIF draws it, in the scenario's world frame (the unroll's);
    ``made``: its io.scenarionet.scenarionet_map.ScenarioMap when the caller has one (measuring lanes costs)."""
    surfaces = (made if made is not None else scenario_map(scene)).surfaces

    def group(name: str) -> list[np.ndarray]:
        # A road line or edge is a line: its polyline, else the outline it was given as.
        return [line for f in scene.map_features if f.group == name
                for line in [f.polyline[:, :2] if f.polyline is not None else _outline(f)] if line is not None]

    return DrawnMap(
        lane_surfaces=[surfaces[i] for i in range(len(surfaces)) if len(surfaces[i]) >= 3],
        road_lines=group("road_line"),
        road_edges=group("road_edge"),
        crosswalks=[p for f in scene.map_features if f.type == "CROSSWALK" for p in [_outline(f)]
                    if p is not None and len(p) >= 3])


def drawn_map_of(dataset: Any, scene: int) -> DrawnMap | None:
    """Scene ``scene``'s map to draw, or None when the dataset has none to give (an L5 zarr)."""
    if not isinstance(dataset, ScenarioNetDataset):
        return None
    return drawn_map(dataset.source(scene), dataset.scenario_map(scene))
