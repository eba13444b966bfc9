"""l5kit's semantic map layers (the last three channels of ``py_semantic``).

What l5kit's SemanticRasterizer draws, restated:

* An RGB image starting white (255).  Its channels go to the model in that
  order (R, G, B), as ``uint8 / 255``.
* Which elements: lanes and crosswalks whose bounding box, grown by
  ``|raster_size * pixel_size| / 2`` metres each side, strictly contains the
  world point under the raster's middle pixel (not the ego), in map order.
* A lane is its left boundary then its right boundary reversed, each
  resampled to 20 points evenly spaced along its length
  (``np.linspace`` over the cumulative distance, ``np.interp`` per axis).
  Each lane is filled on its own (a 40-point fillPoly) in road colour
  (17, 17, 31).
* Then both boundaries of every lane are drawn as open polylines in the
  lane's colour: yellow-ish (255, 217, 82) without an active light, else
  the colour of an active face among the lane's traffic controls: red
  (255, 0, 0), yellow (255, 255, 0), green (0, 255, 0).  Colours are drawn
  one after the other in the order they first occur among the lanes.
* Crosswalks: closed polylines (255, 117, 69).
* A face is active at a frame when its ``traffic_light_face_status[0]``
  (ACTIVE) is > 0 in that frame's faces; the current frame's faces count.

Where we differ: l5kit measures the lane length in 3-D (the map's z); the
map here is 2-D, so resampled points on sloped lanes sit slightly
differently.  When a lane has several active faces of different colours,
l5kit keeps whichever its Python set yields last; red beats yellow beats
green here.  An active face of unknown colour (l5kit raises) leaves the lane
uncoloured.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Sequence

import numpy as np

from ..geometry.planar import resampled
from ..io.l5.l5kit_zarr import L5Scene
from .draw import compiled, fill_polygons, polylines

if TYPE_CHECKING:
    from ..io.l5.l5_semantic_map import SemanticMap

__all__ = ["COLOURS", "INTERPOLATION_POINTS", "ActiveFaces", "PreparedMap", "active_faces", "draw_semantic",
           "draw_semantic_batch"]

INTERPOLATION_POINTS = 20
# Rows: lane without light, red, yellow, green (the map's face colour codes 1..3), road, crosswalk.
COLOURS = np.array([(255, 217, 82), (255, 0, 0), (255, 255, 0), (0, 255, 0), (17, 17, 31), (255, 117, 69)], np.int64)
ROAD, CROSSWALK = 4, 5
# polylines' ``closed`` as booleans, not the literals True and False, which numba would compile it for
# twice (its most costly step on a cold start, as each frame kernel is)
OPEN, CLOSED = np.bool_(False), np.bool_(True)
_RANK = np.array([0, 3, 2, 1], np.int64)  # unknown, red, yellow, green: which colour wins


@dataclass(frozen=True)
class ActiveFaces:
    """Active traffic-light face ids per (scene row, frame): those of (s, t) are
    ``ids[offsets[s * n_frames + t]:offsets[s * n_frames + t + 1]]``."""

    n_frames: int
    offsets: np.ndarray  # (S * n_frames + 1,) int64
    ids: np.ndarray  # (K,) str


def active_faces(scenes: Sequence[L5Scene], n_frames: int) -> ActiveFaces:
    """The faces l5kit treats as on, per frame, for log rows ``scenes`` padded to ``n_frames``."""
    counts, ids = [], []
    for scene in scenes:
        if scene.num_frames > n_frames:
            raise ValueError(f"active_faces: scene {scene.index} of {scene.source or 'memory'} has "
                             f"{scene.num_frames} frames, more than the {n_frames} asked for")
        faces = scene.traffic_light_faces
        intervals = scene.frames["traffic_light_faces_index_interval"].astype(np.int64)
        if len(intervals) and (intervals.min() < 0 or intervals.max() > len(faces)):
            raise ValueError(f"active_faces: scene {scene.index} of {scene.source or 'memory'}: a frame's face "
                             f"interval leaves its {len(faces)} faces")
        on = faces["traffic_light_face_status"][:, 0] > 0 if len(faces) else np.zeros(0, bool)
        for t in range(n_frames):
            if t < scene.num_frames:
                start, end = intervals[t]
                picked = faces["face_id"][start:end][on[start:end]]
            else:
                picked = np.zeros(0, faces["face_id"].dtype if len(faces) else "<U16")
            counts.append(len(picked))
            ids.append(picked)
    offsets = np.concatenate([[0], np.cumsum(counts, dtype=np.int64)])
    return ActiveFaces(n_frames, offsets, np.concatenate(ids) if ids else np.zeros(0, "<U16"))


class PreparedMap:
    """A SemanticMap in the arrays the kernel reads, lane polygons resampled lazily."""

    def __init__(self, smap: "SemanticMap"):
        self.map = smap
        n = len(smap.lane_ids)
        self.lane_bounds = np.ascontiguousarray(smap.lane_bounds)
        empty = (np.diff(smap.lanes_left.offsets) == 0) | (np.diff(smap.lanes_right.offsets) == 0)
        self.lane_bounds[empty] = np.nan  # never inside any query, so never drawn
        self.lane_polygons = np.zeros((n, 2 * INTERPOLATION_POINTS, 2))
        self._resampled = np.zeros(n, bool)
        face_index = {face: i for i, face in enumerate(smap.face_ids.tolist())}
        self.face_index = face_index
        self.lane_face_offsets = np.asarray(smap.lane_control_offsets, np.int64)
        self.lane_faces = np.array([face_index.get(c, -1) for c in smap.lane_control_ids.tolist()], np.int64)
        self.face_rank = _RANK[np.clip(np.asarray(smap.face_colours, np.int64), 0, 3)]
        self.face_colour = np.clip(np.asarray(smap.face_colours, np.int64), 0, 3)
        self.crosswalk_bounds = np.ascontiguousarray(smap.crosswalks.bounds)
        self.crosswalk_points = np.ascontiguousarray(smap.crosswalks.points)
        self.crosswalk_offsets = np.asarray(smap.crosswalks.offsets, np.int64)

    def ensure_polygons(self, lanes: np.ndarray) -> None:
        n = INTERPOLATION_POINTS
        for i in lanes[~self._resampled[lanes]].tolist():
            self.lane_polygons[i, :n] = resampled(self.map.lanes_left[i], n)
            self.lane_polygons[i, n:] = resampled(self.map.lanes_right[i], n)[::-1]
            self._resampled[i] = True

    def face_indices(self, faces: ActiveFaces) -> np.ndarray:
        """``faces.ids`` as indices into the map's faces, -1 for faces the map lacks."""
        return np.array([self.face_index.get(f, -1) for f in faces.ids.tolist()], np.int64)


@compiled
def _inside(bounds, k, cx, cy, half):
    return (cx > bounds[k, 0] - half and cy > bounds[k, 1] - half
            and cx < bounds[k, 2] + half and cy < bounds[k, 3] + half)


@compiled
def _to_raster(points, matrix, verts, at):
    for v in range(points.shape[0]):
        px, py = points[v, 0], points[v, 1]
        verts[at + v, 0] = int((px * matrix[0, 0] + py * matrix[0, 1] + matrix[0, 2]) * 512.0)
        verts[at + v, 1] = int((px * matrix[1, 0] + py * matrix[1, 1] + matrix[1, 2]) * 512.0)


@compiled
def draw_semantic(out, lut, img, matrix, cx, cy, half, lanes, lane_bounds, lane_polygons, lane_face_offsets,
                  lane_faces, face_on, face_rank, face_colour, crosswalks, cw_bounds, cw_points, cw_offsets):
    """One row's semantic layers into ``out`` (3, H, W).  ``lanes``/``crosswalks``:
    candidate indices in map order; ``face_on`` (F,) marks the active faces;
    ``img`` (H, W, 3) uint8 scratch."""
    img[:] = 255
    n_pts = lane_polygons.shape[1]
    half_pts = n_pts // 2
    picked = np.empty(lanes.size, np.int64)
    kind = np.empty(lanes.size, np.int64)
    n = 0
    for k in range(lanes.size):
        lane = lanes[k]
        if _inside(lane_bounds, lane, cx, cy, half):
            picked[n] = lane
            best, colour = 0, 0
            for f in range(lane_face_offsets[lane], lane_face_offsets[lane + 1]):
                face = lane_faces[f]
                if face >= 0 and face_on[face] and face_rank[face] > best:
                    best, colour = face_rank[face], face_colour[face]
            kind[n] = colour
            n += 1
    verts = np.empty((max(n, 1) * n_pts, 2), np.int64)
    for k in range(n):
        _to_raster(lane_polygons[picked[k]], matrix, verts, k * n_pts)
    one = np.zeros(2, np.int64)
    one[1] = n_pts
    for k in range(n):
        fill_polygons(img, verts[k * n_pts:(k + 1) * n_pts], one, COLOURS[ROAD])
    # Boundaries, a colour at a time in order of first appearance: left, then right reversed, per lane.
    seen = np.zeros(4, np.bool_)
    starts = np.empty(2 * n + 1, np.int64)
    for first in range(n):
        colour = kind[first]
        if seen[colour]:
            continue
        seen[colour] = True
        m = 0
        starts[0] = 0
        line_verts = np.empty((2 * n * half_pts, 2), np.int64)
        for k in range(first, n):
            if kind[k] == colour:
                line_verts[m * half_pts:(m + 2) * half_pts] = verts[k * n_pts:(k + 1) * n_pts]
                starts[m + 1] = (m + 1) * half_pts
                starts[m + 2] = (m + 2) * half_pts
                m += 2
        polylines(img, line_verts[:m * half_pts], starts[:m + 1], OPEN, COLOURS[colour])
    m = 0
    total = 0
    for k in range(crosswalks.size):
        if _inside(cw_bounds, crosswalks[k], cx, cy, half):
            total += cw_offsets[crosswalks[k] + 1] - cw_offsets[crosswalks[k]]
    cw_verts = np.empty((total, 2), np.int64)
    cw_starts = np.zeros(crosswalks.size + 1, np.int64)
    for k in range(crosswalks.size):
        c = crosswalks[k]
        if _inside(cw_bounds, c, cx, cy, half):
            a, b = cw_offsets[c], cw_offsets[c + 1]
            _to_raster(cw_points[a:b], matrix, cw_verts, cw_starts[m])
            cw_starts[m + 1] = cw_starts[m] + (b - a)
            m += 1
    polylines(img, cw_verts, cw_starts[:m + 1], CLOSED, COLOURS[CROSSWALK])
    for y in range(img.shape[0]):
        for x in range(img.shape[1]):
            for c in range(3):
                out[c, y, x] = lut[img[y, x, c]]


@compiled
def draw_semantic_batch(out, lut, channel, matrices, centres, half, rows, frames, n_frames, lane_offsets, lanes,
                        lane_bounds, lane_polygons, lane_face_offsets, lane_faces, face_rank, face_colour,
                        face_offsets, face_ids, cw_offsets_by_scene, crosswalks, cw_bounds, cw_points, cw_offsets):
    """The semantic layers of every row into ``out[b, channel:channel + 3]``.

    Candidates come per scene row (``lanes[lane_offsets[s]:lane_offsets[s + 1]]``,
    likewise crosswalks); active faces per (scene row, frame) cell."""
    img = np.empty((out.shape[2], out.shape[3], 3), np.uint8)
    face_on = np.zeros(face_rank.size, np.bool_)
    for b in range(rows.size):
        s = rows[b]
        cell = s * n_frames + frames[b]
        for k in range(face_offsets[cell], face_offsets[cell + 1]):
            if face_ids[k] >= 0:
                face_on[face_ids[k]] = True
        draw_semantic(out[b, channel:channel + 3], lut, img, matrices[b], centres[b, 0], centres[b, 1], half,
                      lanes[lane_offsets[s]:lane_offsets[s + 1]], lane_bounds, lane_polygons, lane_face_offsets,
                      lane_faces, face_on, face_rank, face_colour,
                      crosswalks[cw_offsets_by_scene[s]:cw_offsets_by_scene[s + 1]], cw_bounds, cw_points, cw_offsets)
        for k in range(face_offsets[cell], face_offsets[cell + 1]):
            if face_ids[k] >= 0:
                face_on[face_ids[k]] = False
