"""What each type string in a ScenarioNet scenario means here: map features, tracks and light states.

The one table of them.  Its source: the types ScenarioNet's converters write (metadriverse/scenarionet
@ cebcbe6, ``scenarionet/converter/{waymo,nuplan,nuscenes,argoverse2}/``, Lyft through the nuScenes
converter, ``documentation/lyft.rst``) and MetaDrive's type table they write them from
(metadriverse/metadrive @ 85e5dad, ``metadrive/type.py``, ``MetaDriveType``).

Who writes what (as read in those converters):

- map features: Waymo: the lane types, every road line, ``UNKNOWN`` / ``ROAD_EDGE_BOUNDARY`` /
  ``ROAD_EDGE_MEDIAN``, ``STOP_SIGN`` (a ``position``), ``CROSSWALK`` / ``SPEED_BUMP`` / ``DRIVEWAY``
  (polygons); nuScenes and Lyft: ``LANE_SURFACE_STREET`` / ``LANE_SURFACE_UNSTRUCTURE``, the
  drivable area's outline as ``ROAD_LINE_SOLID_SINGLE_WHITE``, dividers as ``ROAD_LINE_BROKEN_SINGLE_WHITE``
  / ``ROAD_LINE_SOLID_SINGLE_YELLOW``, ``CROSSWALK`` and walkways as ``ROAD_EDGE_SIDEWALK`` (polygons);
  nuPlan: the same two lane types, ``ROAD_LINE_BROKEN_SINGLE_WHITE`` / ``ROAD_LINE_SOLID_SINGLE_WHITE``
  / ``UNKNOWN_LINE``, ``ROAD_EDGE_SIDEWALK``, ``CROSSWALK``; Argoverse 2: ``LANE_SURFACE_STREET`` /
  ``LANE_BIKE_LANE``, its lane marks as road lines (``UNKNOWN_LINE`` for none or unknown),
  ``CROSSWALK``.
- tracks: ``VEHICLE``, ``PEDESTRIAN``, ``CYCLIST`` (all), ``OTHER`` / ``UNSET`` (Waymo, Argoverse 2),
  ``TRAFFIC_CONE`` / ``TRAFFIC_BARRIER`` (nuScenes, nuPlan); MetaDrive adds ``TRAFFIC_OBJECT``.
- light states: Waymo's nine ``LANE_STATE_*``; nuPlan's four ``TRAFFIC_LIGHT_*``; a step where Waymo
  lists no state for the light is ``None``.

Waymo writes ``UNKNOWN`` both for a road line and for a road edge of unknown type; MetaDrive takes
it as a road edge (``BOUNDARY_UNKNOWN``), and so does this table.
"""
from __future__ import annotations

#: map feature type -> what it is here: "lane", "road_line", "road_edge", "area" (a surface one
#: drives over or stops before: crosswalk, speed bump, driveway) or "point" (a stop sign)
FEATURE_GROUPS: dict[str, str] = {
    **dict.fromkeys(("LANE_SURFACE_STREET", "LANE_SURFACE_UNSTRUCTURE", "LANE_UNKNOWN", "LANE_FREEWAY",
                     "LANE_BIKE_LANE"), "lane"),
    **dict.fromkeys(("UNKNOWN_LINE", "ROAD_LINE_BROKEN_SINGLE_WHITE", "ROAD_LINE_SOLID_SINGLE_WHITE",
                     "ROAD_LINE_SOLID_DOUBLE_WHITE", "ROAD_LINE_BROKEN_SINGLE_YELLOW", "ROAD_LINE_BROKEN_DOUBLE_YELLOW",
                     "ROAD_LINE_SOLID_SINGLE_YELLOW", "ROAD_LINE_SOLID_DOUBLE_YELLOW",
                     "ROAD_LINE_PASSING_DOUBLE_YELLOW"), "road_line"),
    # a sidewalk is a polygon (nuScenes', nuPlan's walkways), the others lines; MetaDrive's GUARDRAIL
    # is "a thickened sidewalk" no object passes
    **dict.fromkeys(("UNKNOWN", "ROAD_EDGE_BOUNDARY", "ROAD_EDGE_MEDIAN", "ROAD_EDGE_SIDEWALK", "GUARDRAIL"),
                    "road_edge"),
    **dict.fromkeys(("CROSSWALK", "SPEED_BUMP", "DRIVEWAY"), "area"),
    "STOP_SIGN": "point",
}

#: track type -> the l5kit perception label the engine gives it (l5kit feeds labels CAR .. ANIMAL
#: to models; static objects and objects of no known kind stay UNKNOWN: collided with, never fed)
TRACK_LABELS: dict[str, str] = {
    "VEHICLE": "CAR", "PEDESTRIAN": "PEDESTRIAN", "CYCLIST": "CYCLIST",
    "OTHER": "UNKNOWN", "UNSET": "UNKNOWN",
    "TRAFFIC_CONE": "UNKNOWN", "TRAFFIC_BARRIER": "UNKNOWN", "TRAFFIC_OBJECT": "UNKNOWN",
}
#: the label of a track whose type is none of the above (kept: it is still a box one can hit)
UNKNOWN_TRACK_LABEL = "UNKNOWN"

#: light state -> the face it lights ("red", "yellow", "green") or None (lights none).  As MetaDrive
#: simplifies them: a flashing red and an unknown state light none.
LIGHT_FACES: dict[str, str | None] = {
    "LANE_STATE_STOP": "red", "LANE_STATE_ARROW_STOP": "red", "TRAFFIC_LIGHT_RED": "red",
    "LANE_STATE_CAUTION": "yellow", "LANE_STATE_ARROW_CAUTION": "yellow", "LANE_STATE_FLASHING_CAUTION": "yellow",
    "TRAFFIC_LIGHT_YELLOW": "yellow",
    "LANE_STATE_GO": "green", "LANE_STATE_ARROW_GO": "green", "TRAFFIC_LIGHT_GREEN": "green",
    "LANE_STATE_UNKNOWN": None, "LANE_STATE_FLASHING_STOP": None, "TRAFFIC_LIGHT_UNKNOWN": None,
}
#: the state of a step for which the file gives none (Waymo's None)
NO_LIGHT_STATE = "LANE_STATE_UNKNOWN"


def feature_group(kind: str) -> str:
    """lane, road_line, road_edge, area, point, or "other": a type no converter writes."""
    return FEATURE_GROUPS.get(kind, "other")
