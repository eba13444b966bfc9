"""The drivable area of a ScenarioNet scenario, from the surfaces and edges its map holds, as each of
ScenarioNet's converters (metadriverse/scenarionet @ cebcbe6, ``scenarionet/converter/*/utils.py``)
writes them:

- **nuScenes**: the outline of the union of the map's ``drivable_area`` layer, each ring (outer outlines
  and holes alike) a closed ``ROAD_LINE_SOLID_SINGLE_WHITE`` polyline named ``boundary_<n>``; lanes with
  their own polygon (``LANE_SURFACE_STREET``); lane connectors as centre lines only.
- **nuPlan**: the outline of the union of its roadblocks and intersections, written the same way
  (car parks, which nuPlan's own drivable area includes, are not written); lanes and lane connectors
  with their polygons.
- **Argoverse 2**: the outline of the union of its drivable areas, each ring cut into pieces of 20
  points (``boundary_<ring><start>``), consecutive in the file; lanes as centre lines only.
- **Waymo**: no drivable polygon.  Road edges (``ROAD_EDGE_BOUNDARY``, ``ROAD_EDGE_MEDIAN``) with the
  road on their left, driveways (``DRIVEWAY`` polygons), and lanes as centre lines with ``width``, the
  converter's distances from each point to the lane's left and right boundary lines.

The drivable area is every outline taken even-odd, the driveways, the road side of the road edges
and the lanes' own surfaces (their polygon, or their centre line widened by its measured boundaries).
Only where the map holds none of the outlines or road edges do lanes widened by an assumed width
count as well: that stand-in is named in the drivable-area term's reason.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .scenarionet import ScenarioNetScene

#: how ScenarioNet names the pieces of the drivable area's outline, and their type
OUTLINE_PREFIX, OUTLINE_TYPE = "boundary_", "ROAD_LINE_SOLID_SINGLE_WHITE"
#: road edges with the road on their left (Waymo's convention); ROAD_EDGE_SIDEWALK is a walkway's polygon,
#: and "UNKNOWN" is also what the Waymo converter writes for a road line of unknown type
ROAD_EDGE_LINES = ("ROAD_EDGE_BOUNDARY", "ROAD_EDGE_MEDIAN")
#: metres: a ring is closed where its last piece ends this near its first point
CLOSING = 1e-3
#: lane width sources (io.scenarionet.scenarionet_map) that are the data's own surface
OWN_SURFACES = ("polygon", "boundaries")
STAND_IN = "lane centre lines widened by half their width"


@dataclass(frozen=True)
class DrivableArea:
    outlines: list[np.ndarray]    # closed rings (K, 2), taken even-odd
    polygons: list[np.ndarray]    # each drivable on its own (driveways)
    road_edges: list[np.ndarray]  # lines (K, 2), the road on their left
    #: (N,) per lane of the scenario map: its surface is part of the area
    lane_counts: np.ndarray
    #: what the area is made of, in words (the term's reason)
    reason: str
    #: lanes widened by an assumed width stand in for surfaces the map does not give
    stand_in: bool
    #: what was left out of the map's own outline and why (e.g. pieces that do not close into rings)
    skipped: str | None = None


def outline_rings(scene: ScenarioNetScene) -> tuple[list[np.ndarray], str | None]:
    """The drivable area's outline as closed rings, from the ``boundary_*`` pieces in file order; ([], why)
    when the pieces do not close into rings (a ring with a piece missing would turn inside out)."""
    pieces = [f.polyline[:, :2] for f in scene.map_features
              if f.id.startswith(OUTLINE_PREFIX) and f.type == OUTLINE_TYPE and f.polyline is not None]
    rings, current = [], []
    for piece in pieces:
        current.append(piece)
        if np.hypot(*(piece[-1] - current[0][0])) <= CLOSING and sum(len(p) for p in current) >= 4:
            rings.append(np.concatenate(current))
            current = []
    if current:
        return [], (f"{len(current)} of its {len(pieces)} {OUTLINE_PREFIX}* outline piece(s) do not close into a "
                    "ring; the outline is not used")
    return rings, None


def drivable_area(scene: ScenarioNetScene, width_sources: tuple[str, ...]) -> DrivableArea:
    """The scene's drivable area; ``width_sources``: per lane of its scenario map, where its width came from."""
    outlines, skipped = outline_rings(scene)
    edges = [f.polyline[:, :2] for f in scene.map_features if f.type in ROAD_EDGE_LINES and f.polyline is not None]
    driveways = [f.polygon[:, :2] for f in scene.map_features
                 if f.type == "DRIVEWAY" and f.polygon is not None and len(f.polygon) >= 3]
    own = np.array([source in OWN_SURFACES for source in width_sources], dtype=bool)
    parts = []
    if outlines:
        parts.append(f"the map's drivable-area outline ({len(outlines)} ring(s) of ScenarioNet's "
                     f"{OUTLINE_PREFIX}* lines)")
    if edges:
        parts.append(f"the road side of its {len(edges)} road edge(s)")
    if driveways:
        parts.append(f"{len(driveways)} driveway(s)")
    if own.any():
        parts.append(f"the own surfaces of {int(own.sum())} of its {len(own)} lane(s)")
    stand_in = not outlines and not edges and not own.all()
    if stand_in:
        why = "the scene's map has no drivable-area outline or road edges"
        parts.append(f"{STAND_IN} ({why}{'' if not skipped else '; ' + skipped})")
        counts = np.ones(len(own), dtype=bool)
    else:
        counts = own
    reason = "drivable area: " + (", ".join(parts) if parts else "none in the map")
    if skipped and not stand_in:
        reason += f" ({skipped})"
    return DrivableArea(outlines, driveways, edges, counts, reason, stand_in, skipped)
