"""The Lyft Level 5 semantic map (``semantic_map.pb`` + ``meta.json``), read and written without l5kit.

The map is a protobuf ``MapFragment`` (l5kit's ``road_network.proto``; the
fields used here are listed in ``l5_semantic_map.proto`` beside this module).
Each element's geometry is a list of centimetre deltas in an east-north-up
frame at the element's own latitude/longitude; l5kit takes the cumulative sum,
goes ENU -> ECEF on WGS84 and then through the inverse of ``meta.json``'s
``world_to_ecef`` into the zarr's world frame.  This module does the same for
every element at once and keeps the x, y of the result.

What is kept, with l5kit's meaning (``MapAPI``):

* lanes: left/right boundaries, traffic control ids (``get_lane_traffic_control_ids``,
  in file order);
* crosswalks: traffic control elements that are pedestrian crosswalks with
  points (``is_crosswalk``, ``get_crosswalk_coords``);
* faces: traffic control elements that ``is_traffic_face`` accepts (plain and
  arrow faces, red/yellow/green; not u-turn or flashing signals) and their
  colour (``get_color_for_face``);
* traffic lights (``is_traffic_light``) and the faces each lists.

Why a hand-written codec (protowire.py, ~150 lines) and not the protobuf
package: on a generated 15,000-lane map (30 vertices a boundary, 5.0 MB,
benchmarks/bench_semantic_map.py, one core) this module reads it in 0.31 s,
0.16 s of it walking fields in Python.  protobuf 7.36's C parser (upb) parses
it in 0.014 s, but getting the fields out of its messages into lists took
0.16 s and the lists into numpy 0.06 s more, before any geometry: the same
total, for a dependency plus generated code tied to protobuf's runtime versions.

Bounds queries follow l5kit's ``indices_in_bounds``: an element is returned
when its axis-aligned box overlaps the query box with positive area.
"""
from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pytest_driveeval.core.atomic import write_bytes_atomic
from pytest_driveeval.core.errors import DataError
from pytest_driveeval.io.l5 import wgs84
from pytest_driveeval.io.l5.protowire import (FIXED32, LENGTH, VARINT, WireError, decode_sint32_spans, encode_sint32,
                                           fields, length_field, sfixed32, sfixed32_field, varint_field)

__all__ = ["FACE_COLOUR_NAMES", "GREEN", "RED", "UNKNOWN", "YELLOW", "Polylines", "SemanticMap",
           "encode_semantic_map", "read_meta", "read_semantic_map", "write_meta",
           "write_semantic_map"]

UNKNOWN, RED, YELLOW, GREEN = 0, 1, 2, 3
FACE_COLOUR_NAMES = ("unknown", "red", "yellow", "green")

# TrafficControlElement's ``Type`` oneof: the faces l5kit's is_traffic_face_color
# looks for (signal_*_face, left/right/upper-left/upper-right arrows) by colour.
_FACE_FIELDS = {11: RED, 30: RED, 32: RED, 38: RED, 41: RED,
                12: YELLOW, 36: YELLOW, 37: YELLOW, 39: YELLOW, 42: YELLOW,
                13: GREEN, 31: GREEN, 33: GREEN, 40: GREEN, 43: GREEN}
_PLAIN_FACE_FIELD = {RED: 11, YELLOW: 12, GREEN: 13}
_TRAFFIC_LIGHT, _CROSSWALK = 29, 16
_TYPE_ONEOF = frozenset([7, 8, 47, 29, 9, 10, 15, 34, 16, 17, 18, 19, 20, 21, 22, 23, 24, 25, 35, 27]
                        + list(_FACE_FIELDS) + list(range(44, 47)) + list(range(49, 74)))
# MapElement.Element's oneof: 3 lane, 4 traffic control element, the rest unused here.
_ELEMENT_ONEOF = frozenset([1, 2, 3, 4, 5, 6, 8])
_LANE, _TCE = 3, 4
_POLYGON = 4  # TrafficControlElement.GeometryType


def _no_str() -> np.ndarray:
    return np.zeros(0, dtype=str)


@dataclass(frozen=True)
class Polylines:
    """A ragged set of world-frame polylines; element ``i`` is ``points[offsets[i]:offsets[i+1]]``."""

    points: np.ndarray  # (P, 2) float64, metres
    offsets: np.ndarray  # (N+1,) int64
    bounds: np.ndarray  # (N, 4) xmin, ymin, xmax, ymax; NaN for an empty polyline

    @classmethod
    def from_arrays(cls, points: np.ndarray, offsets: np.ndarray) -> Polylines:
        points = np.asarray(points, np.float64).reshape(-1, 2)
        offsets = np.asarray(offsets, np.int64)
        if offsets.ndim != 1 or offsets.size == 0 or offsets[0] != 0 or offsets[-1] != len(points) \
                or np.any(np.diff(offsets) < 0):
            raise ValueError(f"offsets must rise from 0 to {len(points)}, got {offsets[:5]}...")
        bounds = np.full((offsets.size - 1, 4), np.nan)
        filled = np.diff(offsets) > 0
        if filled.any():
            # Empty polylines hold no points, so each filled one runs up to the next filled start.
            starts = offsets[:-1][filled]
            bounds[filled, :2] = np.minimum.reduceat(points, starts)
            bounds[filled, 2:] = np.maximum.reduceat(points, starts)
        return cls(points, offsets, bounds)

    @classmethod
    def from_list(cls, lines) -> Polylines:
        lines = [np.asarray(line, np.float64).reshape(-1, 2) for line in lines]
        offsets = np.concatenate([[0], np.cumsum([len(line) for line in lines], dtype=np.int64)])
        return cls.from_arrays(np.concatenate(lines) if lines else np.zeros((0, 2)), offsets)

    def __len__(self) -> int:
        return self.offsets.size - 1

    def __getitem__(self, i: int) -> np.ndarray:
        return self.points[self.offsets[i]:self.offsets[i + 1]]


def _within(bounds: np.ndarray, xmin: float, ymin: float, xmax: float, ymax: float) -> np.ndarray:
    return np.flatnonzero((xmax > bounds[:, 0]) & (ymax > bounds[:, 1]) & (xmin < bounds[:, 2]) & (ymin < bounds[:, 3]))


@dataclass(frozen=True)
class SemanticMap:
    lane_ids: np.ndarray  # (N,) str
    lanes_left: Polylines
    lanes_right: Polylines
    lane_control_offsets: np.ndarray  # (N+1,) int64 into lane_control_ids
    lane_control_ids: np.ndarray  # (K,) str, traffic control element ids of each lane
    crosswalk_ids: np.ndarray  # (M,) str
    crosswalks: Polylines
    face_ids: np.ndarray  # (F,) str
    face_colours: np.ndarray  # (F,) int8: UNKNOWN, RED, YELLOW, GREEN
    world_to_ecef: np.ndarray  # (4, 4)
    traffic_light_ids: np.ndarray = field(default_factory=_no_str)  # (L,) str
    face_light_index: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))  # (F,) into traffic_light_ids, -1: none

    def __post_init__(self):
        n, f = len(self.lane_ids), len(self.face_ids)
        if len(self.face_light_index) == 0 and f:
            object.__setattr__(self, "face_light_index", np.full(f, -1, np.int64))
        problems = [what for what, bad in [
            ("lanes_left/lanes_right need one polyline per lane id", len(self.lanes_left) != n or len(self.lanes_right) != n),
            ("lane_control_offsets must be (N+1,) from 0 to len(lane_control_ids)",
             len(self.lane_control_offsets) != n + 1 or self.lane_control_offsets[0] != 0
             or self.lane_control_offsets[-1] != len(self.lane_control_ids)),
            ("crosswalks need one polygon per crosswalk id", len(self.crosswalks) != len(self.crosswalk_ids)),
            ("face_colours and face_light_index need one entry per face id",
             len(self.face_colours) != f or len(self.face_light_index) != f),
            ("world_to_ecef must be 4x4", np.shape(self.world_to_ecef) != (4, 4)),
        ] if bad]
        if problems:
            raise ValueError("inconsistent SemanticMap: " + "; ".join(problems))

    def lane_controls(self, i: int) -> np.ndarray:
        return self.lane_control_ids[self.lane_control_offsets[i]:self.lane_control_offsets[i + 1]]

    @property
    def lane_bounds(self) -> np.ndarray:
        """(N, 4) box around both boundaries of each lane (l5kit's lane bounds)."""
        left, right = self.lanes_left.bounds, self.lanes_right.bounds
        return np.concatenate([np.fmin(left[:, :2], right[:, :2]), np.fmax(left[:, 2:], right[:, 2:])], axis=1)

    def lanes_within(self, xmin: float, ymin: float, xmax: float, ymax: float) -> np.ndarray:
        return _within(self.lane_bounds, xmin, ymin, xmax, ymax)

    def crosswalks_within(self, xmin: float, ymin: float, xmax: float, ymax: float) -> np.ndarray:
        return _within(self.crosswalks.bounds, xmin, ymin, xmax, ymax)


# ---------------------------------------------------------------- meta.json

def read_meta(meta_path: str | os.PathLike) -> np.ndarray:
    """``world_to_ecef`` (4, 4) from an l5kit ``meta.json``."""
    meta_path = Path(meta_path)
    try:
        text = meta_path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise DataError(f"{meta_path}: meta.json not found (l5kit ships it with the map: it holds the "
                        "world_to_ecef transform that places the map in the zarr's world frame)") from None
    try:
        meta = json.loads(text)
    except json.JSONDecodeError as e:
        raise DataError(f"{meta_path}:{e.lineno}: not valid JSON: {e.msg}") from None
    if not isinstance(meta, dict) or "world_to_ecef" not in meta:
        raise DataError(f"{meta_path}: no 'world_to_ecef' key")
    try:
        matrix = np.array(meta["world_to_ecef"], dtype=np.float64)
    except (TypeError, ValueError):
        raise DataError(f"{meta_path}: world_to_ecef is not a 4x4 array of numbers") from None
    if matrix.shape != (4, 4) or not np.isfinite(matrix).all() or abs(np.linalg.det(matrix)) < 1e-9:
        raise DataError(f"{meta_path}: world_to_ecef must be a finite, invertible 4x4 matrix, "
                        f"got shape {matrix.shape}")
    return matrix


def write_meta(meta_path: str | os.PathLike, world_to_ecef: np.ndarray) -> None:
    text = json.dumps({"world_to_ecef": np.asarray(world_to_ecef, np.float64).tolist()}, indent=1)
    write_bytes_atomic(Path(meta_path), (text + "\n").encode())


# ---------------------------------------------------------------- reading

class _Scan:
    """What one pass over the file collects; coordinates stay as byte spans until the end."""

    def __init__(self):
        self.frames: list[tuple[int, int]] = []  # per polyline: lat_e7, lng_e7
        self.span_line: list[int] = []
        self.span_axis: list[int] = []
        self.span_start: list[int] = []
        self.span_end: list[int] = []
        self.lane_ids: list[str] = []
        self.lane_controls: list[list[str]] = []
        self.crosswalk_ids: list[str] = []
        self.crosswalk_lines: list[int] = []
        self.face_ids: list[str] = []
        self.face_colours: list[int] = []
        self.lights: dict[str, list[str]] = {}

    def add_line(self, frame: tuple[int, int], spans: list[tuple[int, int, int]]) -> int:
        line = len(self.frames)
        self.frames.append(frame)
        for axis, start, end in spans:
            self.span_line.append(line)
            self.span_axis.append(axis)
            self.span_start.append(start)
            self.span_end.append(end)
        return line


def _global_id(buf: bytes, start: int, end: int) -> str:
    value = b""
    for f, w, a, b in fields(buf, start, end):
        if f == 1 and w == LENGTH:
            value = buf[a:b]
    try:
        return value.decode("utf-8")
    except UnicodeDecodeError:
        raise WireError(start, f"element id ({len(value)} bytes) is not UTF-8") from None


def _geo_frame(buf: bytes, start: int, end: int, lat: int, lng: int) -> tuple[int, int]:
    for f, w, a, b in fields(buf, start, end):
        if f == 1 and w == LENGTH:  # origin: GeoLocation
            for g, wg, c, _ in fields(buf, a, b):
                if wg == FIXED32 and g == 1:
                    lat = sfixed32(buf, c)
                elif wg == FIXED32 and g == 2:
                    lng = sfixed32(buf, c)
    return lat, lng


def _deltas(buf: bytes, start: int, end: int, first_field: int, out: list) -> None:
    """Spans of the x/y/z delta fields (numbers first_field..first_field+2), packed or not."""
    for f, w, a, b in fields(buf, start, end):
        axis = f - first_field
        if 0 <= axis < 3 and (w == LENGTH or w == VARINT):
            out.append((axis, a, b))


def _lane(buf: bytes, spans: list, eid: str, scan: _Scan) -> None:
    lat = lng = 0
    left: list = []
    right: list = []
    controls: list[str] = []
    for s, e in spans:  # a message field given twice is merged, repeated fields concatenated
        for f, w, a, b in fields(buf, s, e):
            if w != LENGTH:
                continue
            if f == 2:
                lat, lng = _geo_frame(buf, a, b, lat, lng)
            elif f == 3:
                _deltas(buf, a, b, 1, left)
            elif f == 4:
                _deltas(buf, a, b, 1, right)
            elif f == 8:
                controls.append(_global_id(buf, a, b))
    scan.add_line((lat, lng), left)
    scan.add_line((lat, lng), right)
    scan.lane_ids.append(eid)
    scan.lane_controls.append(controls)


def _traffic_control(buf: bytes, spans: list, eid: str, scan: _Scan) -> None:
    lat = lng = 0
    points: list = []
    kind, kind_spans = None, []
    for s, e in spans:
        for f, w, a, b in fields(buf, s, e):
            if f in _TYPE_ONEOF:
                if f != kind:  # setting another member of a oneof clears the previous one
                    kind, kind_spans = f, []
                kind_spans.append((a, b))
            elif f == 2 and w == LENGTH:
                lat, lng = _geo_frame(buf, a, b, lat, lng)
            elif 3 <= f <= 5 and (w == LENGTH or w == VARINT):
                points.append((f - 3, a, b))
    if kind == _CROSSWALK and any(axis == 0 and b > a for axis, a, b in points):
        scan.crosswalk_ids.append(eid)
        scan.crosswalk_lines.append(scan.add_line((lat, lng), points))
    elif kind in _FACE_FIELDS:
        scan.face_ids.append(eid)
        scan.face_colours.append(_FACE_FIELDS[kind])
    elif kind == _TRAFFIC_LIGHT:
        faces = scan.lights.setdefault(eid, [])
        for a, b in kind_spans:
            faces += [_global_id(buf, c, d) for g, w, c, d in fields(buf, a, b) if g == 3 and w == LENGTH]


def _map_element(buf: bytes, start: int, end: int, scan: _Scan) -> None:
    eid_span = None
    kind, kind_spans = None, []
    for f, w, a, b in fields(buf, start, end):
        if w != LENGTH:
            continue
        if f == 1:
            eid_span = (a, b)
        elif f == 2:
            for g, wg, c, d in fields(buf, a, b):
                if g in _ELEMENT_ONEOF and wg == LENGTH:
                    if g != kind:
                        kind, kind_spans = g, []
                    kind_spans.append((c, d))
    if kind not in (_LANE, _TCE):
        return
    eid = _global_id(buf, *eid_span) if eid_span else ""
    (_lane if kind == _LANE else _traffic_control)(buf, kind_spans, eid, scan)


def _scan(buf: bytes) -> _Scan:
    scan = _Scan()
    for f, w, a, b in fields(buf, 0, len(buf)):
        if f == 2 and w == LENGTH:  # MapFragment.elements
            _map_element(buf, a, b, scan)
    return scan


def _world_points(buf: bytes, scan: _Scan, ecef_to_world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """All polylines' world x, y (P, 2) and their offsets (L+1,)."""
    num_lines = len(scan.frames)
    line = np.asarray(scan.span_line, np.int64)
    axis = np.asarray(scan.span_axis, np.int64)
    order = np.lexsort((np.arange(line.size), axis, line))  # group by polyline, then axis, file order kept
    starts = np.asarray(scan.span_start, np.int64)[order]
    ends = np.asarray(scan.span_end, np.int64)[order]
    values, counts = decode_sint32_spans(np.frombuffer(buf, np.uint8), starts, ends)
    per_axis = np.zeros((num_lines, 3), np.int64)
    np.add.at(per_axis, (line[order], axis[order]), counts)
    n = per_axis[:, 0]
    bad = np.flatnonzero((per_axis[:, 1] != n) | ((per_axis[:, 2] != n) & (per_axis[:, 2] != 0)))
    if bad.size:
        raise WireError(int(starts[np.searchsorted(line[order], bad[0])]) if starts.size else 0,
                        f"an element has {per_axis[bad[0]].tolist()} x/y/z deltas; they must match")
    value_axis = np.repeat(axis[order], counts)
    offsets = np.concatenate([[0], np.cumsum(n)])
    cm = np.zeros((int(offsets[-1]), 3), np.int64)
    cm[:, 0] = values[value_axis == 0]
    cm[:, 1] = values[value_axis == 1]
    has_z = np.repeat(per_axis[:, 2] > 0, n)
    cm[has_z, 2] = values[value_axis == 2]
    # Deltas -> positions: a cumulative sum restarted at each polyline's first point.
    total = np.cumsum(cm, axis=0)
    before = np.vstack([np.zeros((1, 3), np.int64), total])[offsets[:-1]]
    enu = (total - np.repeat(before, n, axis=0)) / 100.0
    # ENU -> ECEF -> world is affine per element: compose it once per polyline, not per point.
    lat, lng = (np.asarray(scan.frames, np.float64).reshape(-1, 2) / 1e7).T
    rotation, shift = ecef_to_world[:2, :3], ecef_to_world[:2, 3]
    linear = np.einsum("ij,lkj->lik", rotation, wgs84.enu_axes(lat, lng))  # (L, 2, 3)
    origin = wgs84.geodetic_to_ecef(lat, lng) @ rotation.T + shift
    world = np.einsum("pij,pj->pi", np.repeat(linear, n, axis=0), enu) + np.repeat(origin, n, axis=0)
    return world, offsets


def read_semantic_map(pb_path: str | os.PathLike, meta_path: str | os.PathLike) -> SemanticMap:
    """Read an l5kit ``semantic_map.pb`` into world-frame arrays, with ``meta.json``'s transform."""
    pb_path = Path(pb_path)
    world_to_ecef = read_meta(meta_path)
    try:
        buf = pb_path.read_bytes()
    except FileNotFoundError:
        raise DataError(f"{pb_path}: semantic map not found") from None
    try:
        scan = _scan(buf)
        points, offsets = _world_points(buf, scan, np.linalg.inv(world_to_ecef))
    except WireError as e:
        raise DataError(f"{pb_path}: corrupt or truncated semantic map ({len(buf)} bytes): {e}") from None
    lines = Polylines.from_arrays(points, offsets)

    def pick(indices) -> Polylines:
        indices = np.asarray(indices, np.int64)
        sizes = np.diff(offsets)[indices]
        take = np.repeat(offsets[indices] - np.cumsum(sizes) + sizes, sizes) + np.arange(int(sizes.sum()))
        return Polylines(points[take], np.concatenate([[0], np.cumsum(sizes)]), lines.bounds[indices])

    lane_lines = np.flatnonzero(np.isin(np.arange(len(scan.frames)), scan.crosswalk_lines, invert=True))
    face_index = {fid: i for i, fid in enumerate(scan.face_ids)}
    light_of = np.full(len(scan.face_ids), -1, np.int64)
    for j, faces in enumerate(scan.lights.values()):
        for fid in faces:
            if fid in face_index:
                light_of[face_index[fid]] = j
    sizes = [len(c) for c in scan.lane_controls]
    return SemanticMap(
        lane_ids=np.array(scan.lane_ids, dtype=str),
        lanes_left=pick(lane_lines[0::2]),
        lanes_right=pick(lane_lines[1::2]),
        lane_control_offsets=np.concatenate([[0], np.cumsum(sizes, dtype=np.int64)]),
        lane_control_ids=np.array([c for cs in scan.lane_controls for c in cs], dtype=str),
        crosswalk_ids=np.array(scan.crosswalk_ids, dtype=str),
        crosswalks=pick(scan.crosswalk_lines),
        face_ids=np.array(scan.face_ids, dtype=str),
        face_colours=np.array(scan.face_colours, np.int8),
        world_to_ecef=world_to_ecef,
        traffic_light_ids=np.array(list(scan.lights), dtype=str),
        face_light_index=light_of,
    )


# ---------------------------------------------------------------- writing

def _id(value: str) -> bytes:
    return length_field(1, str(value).encode("utf-8"))


def _geo_frame_field(lat_e7: int, lng_e7: int) -> bytes:
    """Field 2 of a Lane or TrafficControlElement: a GeoFrame with only its origin."""
    return length_field(2, length_field(1, sfixed32_field(1, lat_e7) + sfixed32_field(2, lng_e7)))


def _encoded_deltas(smap: SemanticMap, lines: list[np.ndarray], anchors: np.ndarray) -> tuple[np.ndarray, list]:
    """Per polyline: its frame (lat_e7, lng_e7), at the world point ``anchors[i]``, and its packed x, y, z deltas.

    Points are placed at world z = 0.
    """
    w2e = np.asarray(smap.world_to_ecef, np.float64)
    sizes = np.array([len(line) for line in lines], np.int64)
    starts = np.concatenate([[0], np.cumsum(sizes)])[:-1]
    world = np.concatenate([np.asarray(line, np.float64).reshape(-1, 2) for line in lines] + [np.zeros((0, 2))])

    def to_ecef(xy: np.ndarray) -> np.ndarray:
        return np.c_[xy, np.zeros(len(xy))] @ w2e[:3, :3].T + w2e[:3, 3]

    lat, lng = wgs84.ecef_to_geodetic(to_ecef(np.asarray(anchors, np.float64).reshape(-1, 2)))
    frames = np.stack([np.round(lat * 1e7), np.round(lng * 1e7)], 1).astype(np.int64)
    per_point = np.repeat(frames, sizes, axis=0) / 1e7
    # Round positions, not deltas, so rounding errors do not add up along a polyline.
    cm = np.round(wgs84.ecef_to_enu(to_ecef(world), per_point[:, 0], per_point[:, 1]) * 100).astype(np.int64)
    deltas = np.diff(cm, axis=0, prepend=np.zeros((1, 3), np.int64))
    deltas[starts[sizes > 0]] = cm[starts[sizes > 0]]
    data, ends = encode_sint32(deltas.T.reshape(-1))  # x of every point, then y, then z
    ends = np.concatenate([[0], ends])
    total = len(cm)
    encoded = [[data[ends[axis * total + start]:ends[axis * total + start + size]] for axis in range(3)]
               for start, size in zip(starts.tolist(), sizes.tolist())]
    return frames, encoded


def _first_points(*sets: Polylines) -> np.ndarray:
    """Per element, the first point of the first non-empty polyline among ``sets`` (else the world origin)."""
    out = np.zeros((len(sets[0]), 2))
    found = np.zeros(len(sets[0]), bool)
    for lines in sets:
        here = ~found & (np.diff(lines.offsets) > 0)
        out[here] = lines.points[lines.offsets[:-1][here]]
        found |= here
    return out


def _element(eid: str, kind: int, body: bytes) -> bytes:
    return length_field(2, length_field(1, _id(eid)) + length_field(2, length_field(kind, body)))


def encode_semantic_map(smap: SemanticMap, name: str = "") -> bytes:
    """The ``MapFragment`` bytes of ``smap`` (lanes, crosswalks, traffic lights, faces)."""
    bad = np.flatnonzero(~np.isin(smap.face_colours, (RED, YELLOW, GREEN)))
    if bad.size:
        raise ValueError(f"face {str(smap.face_ids[bad[0]])!r}: colour {smap.face_colours[bad[0]]} cannot be written "
                         "(a face element is red, yellow or green)")
    n = len(smap.lane_ids)
    lines = [smap.lanes_left[i] for i in range(n)] + [smap.lanes_right[i] for i in range(n)] \
        + [smap.crosswalks[i] for i in range(len(smap.crosswalks))]
    # An element has one frame: a lane's right boundary is stored in its left's.
    lane_anchor = _first_points(smap.lanes_left, smap.lanes_right)
    anchors = np.concatenate([lane_anchor, lane_anchor, _first_points(smap.crosswalks)])
    frames, deltas = _encoded_deltas(smap, lines, anchors)
    def packed(line: int, first_field: int) -> bytes:
        return b"".join(length_field(first_field + axis, deltas[line][axis]) for axis in range(3))

    out = [length_field(1, name.encode("utf-8"))] if name else []
    for i, eid in enumerate(smap.lane_ids.tolist()):
        body = (_geo_frame_field(*frames[i]) + length_field(3, packed(i, 1)) + length_field(4, packed(n + i, 1))
                + b"".join(length_field(8, _id(c)) for c in smap.lane_controls(i).tolist()))
        out.append(_element(eid, _LANE, body))
    for j, eid in enumerate(smap.crosswalk_ids.tolist()):
        body = (_geo_frame_field(*frames[2 * n + j]) + packed(2 * n + j, 3)
                + length_field(_CROSSWALK, b"") + varint_field(48, _POLYGON))
        out.append(_element(eid, _TCE, body))
    for k, light in enumerate(smap.traffic_light_ids.tolist()):
        faces = smap.face_ids[smap.face_light_index == k].tolist()
        out.append(_element(light, _TCE, length_field(_TRAFFIC_LIGHT, b"".join(length_field(3, _id(f)) for f in faces))))
    for fid, colour in zip(smap.face_ids.tolist(), smap.face_colours.tolist()):
        out.append(_element(fid, _TCE, length_field(_PLAIN_FACE_FIELD[colour], b"")))
    return b"".join(out)


def write_semantic_map(pb_path: str | os.PathLike, meta_path: str | os.PathLike, semantic_map: SemanticMap,
                       name: str = "") -> None:
    """Write ``semantic_map.pb`` and ``meta.json`` (each atomically), as l5kit reads them.

    Coordinates are stored in whole centimetres, as the format does; lanes get
    plain red/yellow/green faces.
    """
    data = encode_semantic_map(semantic_map, name)
    write_bytes_atomic(Path(pb_path), data)
    write_meta(meta_path, semantic_map.world_to_ecef)
