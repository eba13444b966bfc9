"""nuPlan's lane graph from a ScenarioNet map: which lanes are connectors, which lane leads into which,
and which lanes form one roadblock, from what each converter of metadriverse/scenarionet writes.

* **Lanes and connectors.**  nuPlan's converter writes its lanes as ``LANE_SURFACE_STREET`` and its lane
  connectors as ``LANE_SURFACE_UNSTRUCTURE``, both with outlines.  nuScenes' converter writes a map
  ``lane`` with its outline and a ``lane_connector`` with its centre line only (the outline is commented
  out in the converter; older versions also type it ``LANE_SURFACE_STREET``).  So a lane feature with an
  outline of at least 3 points that is not ``LANE_SURFACE_UNSTRUCTURE`` is a lane, any other a connector:
  nuPlan's route extractor takes the one lane holding a point, else every connector holding it, and
  lanes of these maps do not overlap where connectors do (at junctions).  Waymo's lanes have no outlines:
  all connectors, so a point on several is on all of them.
* **Lane graph.**  ``exit_lanes`` where the file gives any entry or exit lanes; else (the nuScenes files)
  A leads into B where A's centre line ends within :data:`JOIN_TOLERANCE` of B's start: nuScenes' lanes
  and connectors share their end nodes, so every join of the real files is closer than 0.01 m.
* **Roadblocks.**  A lane and its ``left_neighbor`` / ``right_neighbor`` lanes (nuPlan's converter writes a
  roadblock's other lanes there) are one roadblock; each connector, and each lane of a file without
  neighbours, its own.
"""
from __future__ import annotations

from typing import Any, Sequence

import numpy as np

#: metres: a centre line ending this close to where another starts leads into it (nuScenes)
JOIN_TOLERANCE = 0.05
CONNECTOR_TYPE = "LANE_SURFACE_UNSTRUCTURE"


def _ids(value: Any) -> list[str]:
    return [str(v) for v in np.atleast_1d(value if value is not None else []).tolist()]


def is_connector(feature: Any) -> bool:
    polygon = getattr(feature, "polygon", None)
    return feature is None or str(feature.type) == CONNECTOR_TYPE or polygon is None or len(polygon) < 3


def lane_graph(ids: Sequence[str], features: dict[str, Any], baselines: Sequence[np.ndarray]
               ) -> tuple[np.ndarray, list[list[int]], np.ndarray, str | None]:
    """(connector (N,) bool, outgoing per lane, roadblock (N,) int, a note on how the graph was made or
    None) of the lanes ``ids`` (their map features by id; their centre lines, ``baselines``)."""
    index = {lane: n for n, lane in enumerate(ids)}
    lanes = [features.get(i) for i in ids]
    connector = np.array([is_connector(f) for f in lanes], dtype=bool)
    given = any(_ids(f.extra.get("exit_lanes")) or _ids(f.extra.get("entry_lanes")) for f in lanes if f is not None)
    note = None
    if given or not len(ids):
        outgoing = [[index[o] for o in _ids(f.extra.get("exit_lanes")) if o in index] if f is not None else []
                    for f in lanes]
    else:
        starts = np.array([b[0, :2] for b in baselines])
        ends = np.array([b[-1, :2] for b in baselines])
        gaps = np.linalg.norm(ends[:, None, :] - starts[None, :, :], axis=-1)
        np.fill_diagonal(gaps, np.inf)
        joins = gaps <= JOIN_TOLERANCE
        outgoing = [np.flatnonzero(row).tolist() for row in joins]
        note = (f"no entry or exit lanes in the file: a centre line ending within {JOIN_TOLERANCE} m of another's "
                f"start leads into it ({int(joins.sum())} joins)")
    return connector, outgoing, _roadblocks(ids, lanes, connector, index), note


def _roadblocks(ids: Sequence[str], lanes: list[Any], connector: np.ndarray, index: dict[str, int]) -> np.ndarray:
    """Each lane's roadblock: the smallest index among the lanes its neighbours join it to (union-find)."""
    parent = list(range(len(ids)))

    def root(n: int) -> int:
        while parent[n] != n:
            parent[n] = parent[parent[n]]
            n = parent[n]
        return n

    for n, feature in enumerate(lanes):
        if connector[n] or feature is None:
            continue
        for other in _ids(feature.extra.get("left_neighbor")) + _ids(feature.extra.get("right_neighbor")):
            m = index.get(other)
            if m is not None and not connector[m]:
                a, b = root(n), root(m)
                parent[max(a, b)] = min(a, b)
    return np.array([root(n) for n in range(len(ids))], dtype=np.int64)
