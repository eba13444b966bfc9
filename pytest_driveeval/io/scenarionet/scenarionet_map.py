"""A ScenarioNet scenario's map as the semantic map model the L5 map feeds (lanes as left and right
boundaries, crosswalks, traffic-light faces), plus the drivable surfaces map-based terms need.

ScenarioNet gives a lane as its centre line, with a surface polygon in some datasets (nuScenes) and
not in others (Waymo gives boundaries by reference, Argoverse 2 / nuPlan their own); the L5 model
wants its two boundaries.  Each lane's boundaries are its centre line moved half the lane's width to
each side.  The width is measured where the lane has a polygon (twice the median distance from the
centre line's inner points to the polygon's outline); where the converter measured each point's
distances to the lane's left and right boundary lines (Waymo's ``width``, (K, 2)), the boundaries are
the centre line moved by those; else the width is :data:`DEFAULT_LANE_WIDTH`.  The drivable area is
built from the map's own surfaces and edges (:mod:`.scenarionet_drivable`).  A traffic light
becomes three faces (red, yellow, green) on the lane it controls, as an L5 light has.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...geometry.planar import arc_lengths
from ...geometry.polygons import outline_distance
from ..l5.l5_semantic_map import GREEN, RED, YELLOW, Polylines, SemanticMap
from .scenarionet import ScenarioNetScene
from .scenarionet_drivable import DrivableArea, drivable_area
from .scenarionet_types import LIGHT_FACES

#: metres: a typical urban lane, for lanes whose data gives no surface to measure
DEFAULT_LANE_WIDTH = 3.7
#: widths measured outside this range are taken as a polygon that is not the lane's own surface
WIDTH_RANGE = (2.0, 8.0)
#: a ScenarioNet light state -> the face it lights (None: none); the table is scenarionet_types'
FACE_OF_STATE = LIGHT_FACES
FACES = (("red", RED), ("yellow", YELLOW), ("green", GREEN))


@dataclass(frozen=True)
class ScenarioMap:
    semantic: SemanticMap
    lane_widths: np.ndarray  # (N,) metres, per lane of ``semantic``
    #: where each lane's width came from: "polygon", "boundaries" (the converter's measured distances) or "default"
    width_sources: tuple[str, ...]
    #: the drivable surfaces: each lane's own polygon where given, else its boundaries as one outline
    surfaces: Polylines
    #: the drivable area from the map's own surfaces and edges (None: not made)
    drivable: DrivableArea | None = None
    #: each lane's centre line as read (repeated points dropped): the midline of its boundaries only where
    #: they are the same distance off it
    centres: Polylines | None = None


def _normals(line: np.ndarray) -> np.ndarray:
    """Unit left normals at each point of a polyline (from the neighbouring segments)."""
    # np.gradient's and np.linalg.norm's arithmetic, bit for bit, without their per-call overhead
    # (a few hundred lanes per scene): central differences inside, one-sided at the ends
    d = np.empty_like(line)
    d[1:-1] = (line[2:] - line[:-2]) / 2.0
    d[0] = line[1] - line[0]
    d[-1] = line[-1] - line[-2]
    d /= np.maximum(np.sqrt(np.add.reduce(d * d, axis=1, keepdims=True)), 1e-9)
    return np.stack([-d[:, 1], d[:, 0]], axis=1)


def lane_width(centre: np.ndarray, polygon: np.ndarray | None) -> tuple[float, str]:
    if polygon is not None and len(polygon) >= 3:
        # Measured along the lane's inside: its ends touch the polygon's end caps, at distance 0.
        along = arc_lengths(centre)
        at = np.linspace(0.0, along[-1], 21)[1:-1]
        inside = np.stack([np.interp(at, along, centre[:, 0]), np.interp(at, along, centre[:, 1])], axis=1)
        width = 2.0 * float(np.median(outline_distance(inside, polygon[:, :2])))
        if WIDTH_RANGE[0] <= width <= WIDTH_RANGE[1]:
            return width, "polygon"
    return DEFAULT_LANE_WIDTH, "default"


def boundary_widths(given, keep: np.ndarray) -> np.ndarray | None:
    """(K, 2) each kept point's distances to the lane's left and right boundaries, from the converter's
    ``width`` (Waymo's: 0 on a side without a boundary line, the other side's distance copied where one
    side has none); None where it gives no usable distance (absent, another shape, not finite, no point
    with a boundary).  A point with neither boundary takes the lane's median."""
    if not isinstance(given, np.ndarray) or given.ndim != 2 or given.shape != (len(keep), 2):
        return None
    sides = given.astype(np.float64)[keep]
    if not np.isfinite(sides).all() or (sides < 0).any():
        return None
    known = (sides > 0).all(axis=1) & (sides.sum(axis=1) >= WIDTH_RANGE[0]) & (sides.sum(axis=1) <= WIDTH_RANGE[1])
    if not known.any():
        return None
    sides[~known] = np.median(sides[known], axis=0)
    return sides


def face_id(scene_index: int, light_index: int, colour: str) -> str:
    """A face's id: l5kit's face table holds 16 characters, so ids are made, not the light's own."""
    return f"{scene_index}:{light_index}:{colour[0]}"


def scenario_map(scene: ScenarioNetScene, index: int = 0) -> ScenarioMap:
    lanes = [f for f in scene.map_features if f.group == "lane" and f.polyline is not None]
    ids, lefts, rights, widths, sources, surfaces, centres = [], [], [], [], [], [], []
    for lane in lanes:
        centre = lane.polyline[:, :2]  # nuScenes' third column is the heading, not a height
        keep = np.concatenate([[True], np.linalg.norm(np.diff(centre, axis=0), axis=1) > 1e-6])
        centre = centre[keep]
        if len(centre) < 2:
            continue
        width, source = lane_width(centre, lane.polygon)
        normals = _normals(centre)
        sides = boundary_widths(lane.extra.get("width"), keep) if source == "default" else None
        if sides is not None:
            width, source = float(np.median(sides.sum(axis=1))), "boundaries"
            left, right = centre + normals * sides[:, :1], centre - normals * sides[:, 1:]
        else:
            left, right = centre + normals * (width / 2), centre - normals * (width / 2)
        ids.append(lane.id)
        centres.append(centre)
        lefts.append(left)
        rights.append(right)
        widths.append(width)
        sources.append(source)
        surfaces.append(lane.polygon[:, :2] if lane.polygon is not None and source == "polygon"
                        else np.concatenate([left, right[::-1]]))
    controls: dict[str, list[str]] = {lane_id: [] for lane_id in ids}
    face_ids, colours, light_ids, light_index = [], [], [], []
    for number, light in enumerate(scene.lights):
        light_ids.append(light.id)
        for name, colour in FACES:
            face = face_id(index, number, name)
            face_ids.append(face)
            colours.append(colour)
            light_index.append(len(light_ids) - 1)
            if light.lane in controls:
                controls[light.lane].append(face)
    crosswalks = [f for f in scene.map_features if f.type == "CROSSWALK" and (f.polygon is not None or f.polyline
                                                                              is not None)]
    semantic = SemanticMap(
        lane_ids=np.array(ids, dtype=str),
        lanes_left=Polylines.from_list(lefts),
        lanes_right=Polylines.from_list(rights),
        lane_control_offsets=np.concatenate([[0], np.cumsum([len(controls[i]) for i in ids])]).astype(np.int64),
        lane_control_ids=np.array([c for i in ids for c in controls[i]], dtype=str),
        crosswalk_ids=np.array([f.id for f in crosswalks], dtype=str),
        crosswalks=Polylines.from_list([(f.polygon if f.polygon is not None else f.polyline)[:, :2]
                                        for f in crosswalks]),
        face_ids=np.array(face_ids, dtype=str),
        face_colours=np.array(colours, np.int8),
        world_to_ecef=np.eye(4),
        traffic_light_ids=np.array(light_ids, dtype=str),
        face_light_index=np.array(light_index, np.int64),
    )
    return ScenarioMap(semantic, np.array(widths), tuple(sources), Polylines.from_list(surfaces),
                       drivable_area(scene, tuple(sources)), Polylines.from_list(centres))


def active_faces(scene: ScenarioNetScene, step: int, index: int = 0) -> list[str]:
    """The face ids lit at ``step``: one per light whose state names a colour."""
    out = []
    for number, light in enumerate(scene.lights):
        name = FACE_OF_STATE.get(light.states[step]) if step < len(light.states) else None
        if name is not None:
            out.append(face_id(index, number, name))
    return out


def merged(maps: list[ScenarioMap]) -> SemanticMap:
    """One semantic map of several scenes' maps (of the same place: the caller checks)."""
    parts = [m.semantic for m in maps]

    def lines(name: str) -> Polylines:
        return Polylines.from_list([getattr(p, name)[i] for p in parts for i in range(len(getattr(p, name)))])

    lights = np.cumsum([0] + [len(p.traffic_light_ids) for p in parts[:-1]])
    controls = [p.lane_controls(i) for p in parts for i in range(len(p.lane_ids))]
    return SemanticMap(
        lane_ids=np.concatenate([p.lane_ids for p in parts]) if parts else np.zeros(0, str),
        lanes_left=lines("lanes_left"), lanes_right=lines("lanes_right"),
        lane_control_offsets=np.concatenate([[0], np.cumsum([len(c) for c in controls])]).astype(np.int64),
        lane_control_ids=np.concatenate(controls) if controls else np.zeros(0, str),
        crosswalk_ids=np.concatenate([p.crosswalk_ids for p in parts]) if parts else np.zeros(0, str),
        crosswalks=lines("crosswalks"),
        face_ids=np.concatenate([p.face_ids for p in parts]) if parts else np.zeros(0, str),
        face_colours=np.concatenate([p.face_colours for p in parts]).astype(np.int8) if parts else np.zeros(0, np.int8),
        world_to_ecef=np.eye(4),
        traffic_light_ids=np.concatenate([p.traffic_light_ids for p in parts]) if parts else np.zeros(0, str),
        face_light_index=np.concatenate([p.face_light_index + k for p, k in zip(parts, lights)]).astype(np.int64)
        if parts else np.zeros(0, np.int64),
    )
