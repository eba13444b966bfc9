"""nuPlan's map layers from a ScenarioNet scenario's own map features, for the oracle (nuplan-devkit venv).

Imports nothing from pytest_driveeval: the point is a second reading of the raw file.  What each
converter of metadriverse/scenarionet writes, and what becomes of it here:

* **Lanes.**  nuScenes (``converter/nuscenes/utils.py``): a map ``lane`` becomes ``LANE_SURFACE_STREET``
  with its centre line (``polyline``, the arcline discretised every metre) and its outline
  (``polygon``); a ``lane_connector`` gets the centre line only (its polygon is commented out in the
  converter) and, in the converter version that wrote the shared files, the same type with
  ``speed_limit_kmh: 100`` (newer versions: ``LANE_SURFACE_UNSTRUCTURE``).  nuPlan
  (``converter/nuplan/utils.py``): lanes (``LANE_SURFACE_STREET``) and connectors
  (``LANE_SURFACE_UNSTRUCTURE``) both with outlines, ``entry_lanes`` / ``exit_lanes``, the roadblock's
  other lanes as ``left_neighbor`` / ``right_neighbor``, ``speed_limit_mps``.  Here a lane feature with
  an outline of at least 3 points that is not ``LANE_SURFACE_UNSTRUCTURE`` is a ``LANE``; the others
  are ``LANE_CONNECTOR`` s.  A connector without an outline gets its centre line widened by half the
  mean width (outline area / centre-line length) of the lanes it joins, with flat ends, or of all
  lanes when it joins none that has an outline.
* **Lane graph.**  ``entry_lanes`` / ``exit_lanes`` where the file has them; the shared nuScenes files
  have neither, so B follows A when A's centre line ends within ``JOIN_TOLERANCE`` of where B's starts
  (nuScenes lanes and connectors share their end nodes: in the six shared scenes every join is
  closer than 0.01 m).
* **Roadblocks.**  A lane and its ``left_neighbor`` / ``right_neighbor`` form one ROADBLOCK (nuPlan's
  files); without neighbours (nuScenes: the converter writes none) each lane is a roadblock of its
  own, each connector a ROADBLOCK_CONNECTOR of its own.  A roadblock's polygon is the union of its
  lanes' outlines.
* **Drivable area.**  Both converters write the outline of the drivable area as closed road lines
  named ``boundary_<n>`` (nuScenes: the union of the map's ``drivable_area`` polygons; nuPlan: the
  union of roadblocks and intersections), exterior and hole rings alike.  The DRIVABLE_AREA layer is
  rebuilt from those rings by the even-odd rule (the symmetric difference of the rings' polygons).
  Without such rings, it is the union of the lane and connector polygons (said in ``notes``).
* **Speed limits.**  ``speed_limit_mps``, else ``speed_limit_kmh`` / 3.6, as the file gives them, else
  none.
* **Intersections.**  Neither converter writes them as features: the layer is empty.
"""
from __future__ import annotations

from typing import Any, Dict, List, Optional

import numpy as np
from shapely.geometry import LineString, MultiPolygon, Polygon
from shapely.ops import unary_union

#: metres: a centre line ending this close to where another starts leads into it
JOIN_TOLERANCE = 0.05
LANE_TYPES = ("LANE_SURFACE_STREET", "LANE_SURFACE_UNSTRUCTURE", "LANE_BIKE_LANE", "LANE_UNKNOWN", "LANE_FREEWAY")
CONNECTOR_TYPE = "LANE_SURFACE_UNSTRUCTURE"


def _points(value: Any) -> Optional[np.ndarray]:
    if value is None:
        return None
    array = np.asarray(value, dtype=np.float64)
    if array.ndim != 2 or array.shape[1] < 2 or not len(array):
        return None
    return array[:, :2]


def _ids(value: Any) -> List[str]:
    return [str(v) for v in np.atleast_1d(value if value is not None else []).tolist()]


def _outline(geometry: Any) -> Dict[str, Any]:
    """A polygon as the case format holds it: the shell and any holes, without the closing vertex."""
    if isinstance(geometry, MultiPolygon):  # a union that fell apart: its largest piece
        geometry = max(geometry.geoms, key=lambda g: g.area)
    return {"shell": [list(p) for p in geometry.exterior.coords[:-1]],
            "holes": [[list(p) for p in ring.coords[:-1]] for ring in geometry.interiors]}


def _polygons(geometry: Any) -> List[Any]:
    if geometry.is_empty:
        return []
    return list(geometry.geoms) if isinstance(geometry, MultiPolygon) else [geometry]


def _speed_limit(feature: Dict[str, Any]) -> Optional[float]:
    for key, scale in (("speed_limit_mps", 1.0), ("speed_limit_kmh", 1 / 3.6)):
        value = feature.get(key)
        if value is not None and np.isfinite(float(value)) and float(value) > 0:
            return float(value) * scale
    return None


def scenario_map(scenario: Dict[str, Any]) -> Dict[str, Any]:
    """The case-format map (CASE_FORMAT.md, polygons as ``{"shell", "holes"}``) of a scenario dict, with
    ``notes``: what was skipped or stood in, and why."""
    notes: List[str] = []
    features = scenario.get("map_features") or {}
    lanes: Dict[str, Dict[str, Any]] = {}
    for fid, feature in features.items():
        if str(feature.get("type")) not in LANE_TYPES:
            continue
        line = _points(feature.get("polyline"))
        if line is None or len(line) < 2 or LineString(line).length == 0:
            notes.append(f"lane {fid}: its centre line has fewer than 2 distinct points; left out")
            continue
        outline = _points(feature.get("polygon"))
        polygon = Polygon(outline) if outline is not None and len(outline) >= 3 else None
        if polygon is not None and not polygon.is_valid:
            polygon = polygon.buffer(0)
        if polygon is not None and polygon.is_empty:
            polygon = None
        connector = str(feature["type"]) == CONNECTOR_TYPE or polygon is None
        lanes[str(fid)] = {"line": line, "polygon": polygon, "connector": connector,
                           "speed_limit": _speed_limit(feature),
                           "entry": _ids(feature.get("entry_lanes")), "exit": _ids(feature.get("exit_lanes")),
                           "neighbours": _ids(feature.get("left_neighbor")) + _ids(feature.get("right_neighbor"))}
    _join(lanes, notes)
    _widen_connectors(lanes, notes)
    roadblocks = _roadblocks(lanes)
    lane_specs = [{"id": lid, "polygon": _outline(lane["polygon"]), "baseline": lane["line"].tolist(),
                   "speed_limit": lane["speed_limit"], "roadblock": lane["roadblock"], "connector": lane["connector"],
                   "incoming": [i for i in lane["entry"] if i in lanes],
                   "outgoing": [o for o in lane["exit"] if o in lanes]}
                  for lid, lane in lanes.items()]
    return {"lanes": lane_specs, "roadblocks": roadblocks, "drivable_area": _drivable_area(features, lanes, notes),
            "intersections": [], "notes": notes}


def _join(lanes: Dict[str, Dict[str, Any]], notes: List[str]) -> None:
    """Entry and exit lanes from where centre lines meet, for a file that gives none."""
    if any(lane["entry"] or lane["exit"] for lane in lanes.values()):
        return
    ids = list(lanes)
    if not ids:
        return
    starts = np.array([lanes[i]["line"][0] for i in ids])
    ends = np.array([lanes[i]["line"][-1] for i in ids])
    gaps = np.linalg.norm(ends[:, None, :] - starts[None, :, :], axis=-1)
    np.fill_diagonal(gaps, np.inf)
    for a, b in zip(*np.nonzero(gaps <= JOIN_TOLERANCE)):
        lanes[ids[a]]["exit"].append(ids[b])
        lanes[ids[b]]["entry"].append(ids[a])
    notes.append(f"no entry or exit lanes in the file: the lane graph joins centre lines ending within "
                 f"{JOIN_TOLERANCE} m of another's start ({int(np.count_nonzero(gaps <= JOIN_TOLERANCE))} joins)")


def _width(lane: Dict[str, Any]) -> float:
    return float(lane["polygon"].area / LineString(lane["line"]).length)


def _widen_connectors(lanes: Dict[str, Dict[str, Any]], notes: List[str]) -> None:
    measured = [_width(lane) for lane in lanes.values() if lane["polygon"] is not None]
    typical = float(np.median(measured)) if measured else None
    widened = 0
    for lid, lane in lanes.items():
        if lane["polygon"] is not None:
            continue
        joined = [_width(lanes[o]) for o in lane["entry"] + lane["exit"] if lanes[o]["polygon"] is not None]
        width = float(np.mean(joined)) if joined else typical
        if width is None:
            notes.append(f"lane {lid}: no outline and no lane with one to take a width from; left out")
            continue
        lane["polygon"] = LineString(lane["line"]).buffer(width / 2, cap_style=2)  # 2: flat ends
        widened += 1
    if widened:
        notes.append(f"{widened} connector(s) without an outline: centre line widened by the mean width of the "
                     "lanes they join")
    for lid in [lid for lid, lane in lanes.items() if lane["polygon"] is None]:
        del lanes[lid]


def _roadblocks(lanes: Dict[str, Dict[str, Any]]) -> List[Dict[str, Any]]:
    """Lanes with their neighbours as one roadblock (union-find); each connector one of its own."""
    parent = {lid: lid for lid in lanes}

    def root(lid: str) -> str:
        while parent[lid] != lid:
            parent[lid] = parent[parent[lid]]
            lid = parent[lid]
        return lid

    for lid, lane in lanes.items():
        if lane["connector"]:
            continue
        for other in lane["neighbours"]:
            if other in lanes and not lanes[other]["connector"]:
                parent[root(other)] = root(lid)
    groups: Dict[str, List[str]] = {}
    for lid in lanes:
        groups.setdefault(root(lid), []).append(lid)
    blocks = []
    for members in groups.values():
        block_id = f"rb_{members[0]}"
        for lid in members:
            lanes[lid]["roadblock"] = block_id
        shape = unary_union([lanes[lid]["polygon"] for lid in members])
        blocks.append({"id": block_id, "polygon": _outline(shape), "connector": lanes[members[0]]["connector"]})
    return blocks


def _drivable_area(features: Dict[str, Any], lanes: Dict[str, Dict[str, Any]], notes: List[str]) -> List[Dict]:
    rings = []
    for fid, feature in features.items():
        if not str(fid).startswith("boundary_"):
            continue
        line = _points(feature.get("polyline"))
        if line is None or len(line) < 4 or not np.allclose(line[0], line[-1]):
            notes.append(f"{fid}: not a closed ring; left out of the drivable area")
            continue
        ring = Polygon(line)
        rings.append(ring if ring.is_valid else ring.buffer(0))
    if rings:
        area = rings[0]
        for ring in rings[1:]:
            area = area.symmetric_difference(ring)
        notes.append(f"drivable area: {len(rings)} boundary ring(s) of the file, even-odd")
    else:
        area = unary_union([lane["polygon"] for lane in lanes.values()])
        notes.append("no boundary_<n> rings in the file: the drivable area is the union of the lanes and connectors")
    return [_outline(p) for p in _polygons(area)]
