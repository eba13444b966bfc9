"""The score's map of an L5 scene from the Lyft semantic map (``semantic_map.pb``, io.l5.l5_semantic_map).

Each lane of the semantic map has both boundaries, so its surface is the data's own: the polygon
between its left boundary and its right boundary walked back.  The drivable area is those surfaces
(the map has no other road polygon: its junctions and segments are lists of lanes).  A lane's baseline
is the midline of its boundaries, each resampled to the same fractions of its length (l5kit's
interpolated midline).  The map holds no speed limits, and this reader keeps no lane successors.
Only lanes near the scene's logged ego path are kept (:data:`MARGIN`).
"""
from __future__ import annotations

from typing import Any

import numpy as np

from pytest_driveeval.geometry.planar import resampled
from pytest_driveeval.metrics.nuplan_score import ScoreMap

#: metres around the logged ego path within which lanes are kept (the drift bound is 10 m by default)
MARGIN = 150.0
REASON = "drivable area: the L5 semantic map's lanes, each between its left and right boundary"


def semantic_score_map(semantic: Any, ego_xy: np.ndarray) -> ScoreMap | None:
    """The score's map of the lanes of ``semantic`` (io.l5.l5_semantic_map.SemanticMap) near ``ego_xy``
    (the scene's logged ego positions, (T, 2)); None where no lane is near."""
    lo, hi = ego_xy.min(axis=0) - MARGIN, ego_xy.max(axis=0) + MARGIN
    near = semantic.lanes_within(lo[0], lo[1], hi[0], hi[1])
    ids, polygons, baselines = [], [], []
    for n in near.tolist():
        left, right = semantic.lanes_left[n][:, :2], semantic.lanes_right[n][:, :2]
        if len(left) < 2 or len(right) < 2:
            continue
        count = max(len(left), len(right))
        ids.append(str(semantic.lane_ids[n]))
        polygons.append(np.concatenate([left, right[::-1]]))
        baselines.append((resampled(left, count) + resampled(right, count)) / 2)
    if not ids:
        return None
    return ScoreMap(lane_ids=ids, polygons=polygons, baselines=baselines, speed_limits=np.full(len(ids), np.nan),
                    connector=np.zeros(len(ids), bool), outgoing=[[] for _ in ids], drivable=list(polygons),
                    no_limits_reason="the L5 semantic map gives none", drivable_reason=REASON)


def scene_ego_xy(dataset: Any, scene: int) -> np.ndarray:
    """(T, 2) scene ``scene``'s logged ego positions, from the zarr's frames alone."""
    start, stop = (int(v) for v in dataset.scenes["frame_index_interval"][scene])
    return np.asarray(dataset.read_array("frames", start, stop)["ego_translation"][:, :2], dtype=np.float64)
