"""Rasters for many (scene, frame) rows in one call, as l5kit's EgoDataset hands them to a model.

The image is (B, C, H, W) float32 in [0, 1]: l5kit's ``rasterize()`` returns
(H, W, C) ``uint8 / 255`` and EgoDataset transposes it to (C, H, W);
``to_rgb`` is only for looking at it.  Channels: ``box_debug`` agents at
t .. t-H then the ego at t .. t-H; ``py_semantic`` the same followed by the
semantic map's R, G, B.

As in the vector inputs (``sim.logreplay.inputs.build_batch``), the ego's
history is the one it drove: ``ego_xy`` (S, T, 2) / ``ego_yaw`` (S, T) give
its pose at every frame, the log gives everything else.  The raster is
centred on the ego's pose at the row's frame.
"""
from __future__ import annotations

import sys
from typing import TYPE_CHECKING, Sequence

import numpy as np

from ..io.l5.l5kit_zarr import L5Scene
from .boxes import BoxTable, agent_keep, draw_box_channels, ego_corners
from .draw import compiled
from .params import RasterParams
from .semantic import ActiveFaces, PreparedMap, active_faces, draw_semantic_batch
from .transforms import raster_centre_in_world, raster_from_local, world_matrices

if TYPE_CHECKING:
    from ..io.l5.l5_semantic_map import SemanticMap
    from ..sim.logreplay.logarrays import LogArrays

__all__ = ["LUT", "Canvas", "Rasterizer", "rasterize"]

LUT = np.arange(256, dtype=np.uint8).astype(np.float32) / 255  # l5kit's astype(float32) / 255, value by value
# How far past a scene's logged path its map candidates reach: a driven ego
# rarely strays further, and when it does the scene's candidates are rebuilt.
_REACH = 30.0


@compiled
def _prepare(rows, frames, num_frames, ego_xy, ego_yaw, history, pose_xy, pose_yaw):
    """Each row's channel frames (``history`` (B, H+1), -1 before the scene) and the ego's
    pose at each (clipped to frame 0), gathered flat; returns the first row b whose scene
    row or frame is out of range, else -1.  One call instead of a dozen small numpy ones."""
    n_scenes = num_frames.size
    n_hist = history.shape[1]
    for b in range(rows.size):
        s, t = rows[b], frames[b]
        if s < 0 or s >= n_scenes or t < 0 or t >= num_frames[s]:
            return b
        for i in range(n_hist):
            f = t - i
            history[b, i] = f if f >= 0 else -1
            f = max(f, 0)
            pose_xy[b * n_hist + i, 0] = ego_xy[s, f, 0]
            pose_xy[b * n_hist + i, 1] = ego_xy[s, f, 1]
            pose_yaw[b * n_hist + i] = ego_yaw[s, f]
    return -1


class Canvas:
    """An image that a :class:`Rasterizer` draws into again and again (``out=``).

    ``image`` is (capacity, C, H, W) float32; a draw of B rows returns
    ``image[:B]``, and clears first only the box pixels the previous draws set
    there (``rects``/``n_rects``: per slot and box channel, the rectangles drawn),
    instead of zeroing or allocating the whole image; the semantic channels are
    drawn whole every time.  So whoever still holds an earlier result sees it
    change: draw again only when :attr:`free`.
    """

    def __init__(self, params: RasterParams, capacity: int, most: int):
        self.image = np.zeros((capacity, params.num_channels, params.height, params.width), np.float32)
        self.rects = np.empty((capacity, params.box_channels, most, 4), np.int64)
        self.n_rects = np.zeros((capacity, params.box_channels), np.int64)

    @property
    def capacity(self) -> int:
        return self.image.shape[0]

    @property
    def free(self) -> bool:
        """No earlier result (nor a torch tensor made from one, nor a view of either)
        is alive: each holds a reference to ``image``, directly or through its base."""
        return sys.getrefcount(self.image) <= 2  # the attribute and the argument


class Rasterizer:
    """Rasters of one log, with what does not change between steps prepared once.

    ``keep`` (S, T, C) says which agent cells are drawn; by default it is
    l5kit's per-row label filter read from ``scenes`` (aligned with the log's
    rows), and without scenes the log's own ``relevant`` (each track's most
    frequent label among l5kit's agent classes, the threshold unused).
    ``py_semantic`` needs ``semantic_map`` and the active faces, given as
    ``faces`` or read from ``scenes``.
    """

    def __init__(self, params: RasterParams, log: "LogArrays", *, scenes: Sequence[L5Scene] | None = None,
                 keep: np.ndarray | None = None, semantic_map: "SemanticMap | PreparedMap | None" = None,
                 faces: ActiveFaces | None = None):
        self.params = params
        self.log = log
        if keep is None:
            keep = agent_keep(scenes, log, params.filter_agents_threshold) if scenes is not None else log.relevant
        self.boxes = BoxTable(log, keep)
        self._local = raster_from_local(params)
        self._num_frames = np.ascontiguousarray(log.num_frames, np.int64)
        self.semantic = params.map_type == "py_semantic"
        if not self.semantic:
            return
        if semantic_map is None:
            raise ValueError("Rasterizer: map_type 'py_semantic' needs semantic_map")
        if faces is None:
            if scenes is None:
                raise ValueError("Rasterizer: map_type 'py_semantic' needs faces (active_faces(...)) or scenes")
            faces = active_faces(scenes, log.shape[1])
        if faces.n_frames != log.shape[1] or faces.offsets.size != log.shape[0] * log.shape[1] + 1:
            raise ValueError(f"Rasterizer: faces cover {faces.offsets.size - 1} cells of {faces.n_frames} frames, "
                             f"the log has {log.shape[0]} rows of {log.shape[1]} frames")
        self.map = semantic_map if isinstance(semantic_map, PreparedMap) else PreparedMap(semantic_map)
        self.face_offsets = faces.offsets.astype(np.int64)
        self.face_ids = self.map.face_indices(faces)
        self.half = float(np.linalg.norm(np.asarray(params.raster_size) * np.asarray(params.pixel_size))) / 2
        n_scenes = log.shape[0]
        self._regions = np.empty((n_scenes, 4))
        self._lanes: list[np.ndarray] = [np.zeros(0, np.int64)] * n_scenes
        self._crosswalks: list[np.ndarray] = [np.zeros(0, np.int64)] * n_scenes
        for s in range(n_scenes):
            path = log.ego_xy[s, :max(int(log.num_frames[s]), 1)]
            self._cover(s, np.concatenate([path.min(axis=0), path.max(axis=0)]))
        self._pack()

    def _cover(self, s: int, region: np.ndarray) -> None:
        """Candidates of scene row ``s`` for any raster centre inside ``region`` (grown by _REACH)."""
        region = region + np.array([-_REACH, -_REACH, _REACH, _REACH])
        self._regions[s] = region
        h = self.half

        def near(bounds: np.ndarray) -> np.ndarray:
            return np.flatnonzero((bounds[:, 0] - h <= region[2]) & (bounds[:, 2] + h >= region[0])
                                  & (bounds[:, 1] - h <= region[3]) & (bounds[:, 3] + h >= region[1]))

        self._lanes[s] = near(self.map.lane_bounds)
        self._crosswalks[s] = near(self.map.crosswalk_bounds)
        self.map.ensure_polygons(self._lanes[s])

    def _pack(self) -> None:
        self.lane_offsets = np.concatenate([[0], np.cumsum([a.size for a in self._lanes])]).astype(np.int64)
        self.lanes = np.concatenate(self._lanes).astype(np.int64)
        self.cw_offsets = np.concatenate([[0], np.cumsum([a.size for a in self._crosswalks])]).astype(np.int64)
        self.crosswalks = np.concatenate(self._crosswalks).astype(np.int64)

    def _check(self, rows: np.ndarray, frames: np.ndarray, ego_xy: np.ndarray, ego_yaw: np.ndarray) -> None:
        n_scenes, n_frames = self.log.shape[:2]
        if ego_xy.shape != (n_scenes, n_frames, 2) or ego_yaw.shape != (n_scenes, n_frames):
            raise ValueError(f"ego_xy {ego_xy.shape} / ego_yaw {ego_yaw.shape} must be ({n_scenes}, {n_frames}, 2) "
                             f"/ ({n_scenes}, {n_frames}), like the log")
        if rows.shape != frames.shape or rows.ndim != 1:
            raise ValueError(f"rows {rows.shape} and frames {frames.shape} must be two equal 1-D arrays")

    def _bad_row(self, rows: np.ndarray, frames: np.ndarray, b: int) -> Exception:
        s, t = int(rows[b]), int(frames[b])
        if not 0 <= s < self.log.shape[0]:
            return IndexError(f"row {s} outside the log's {self.log.shape[0]} scenes")
        return IndexError(f"scene {int(self.log.scene_ids[s])}: frame {t} outside [0, {int(self.log.num_frames[s])})")

    def canvas(self, capacity: int) -> Canvas:
        """A :class:`Canvas` for up to ``capacity`` rows per call."""
        return Canvas(self.params, capacity, self.boxes.most)

    def __call__(self, rows, frames, ego_xy: np.ndarray, ego_yaw: np.ndarray, out: Canvas | None = None) -> np.ndarray:
        """(B, C, H, W) rasters of ``(rows[b], frames[b])``, a new array, or ``out.image[:B]``
        redrawn in place when ``out`` is given (see :class:`Canvas`)."""
        rows = np.ascontiguousarray(rows, np.int64).reshape(-1)
        frames = np.ascontiguousarray(frames, np.int64).reshape(-1)
        ego_xy, ego_yaw = np.asarray(ego_xy, np.float64), np.asarray(ego_yaw, np.float64)
        self._check(rows, frames, ego_xy, ego_yaw)
        p = self.params
        n_hist = p.history_num_frames + 1
        history = np.empty((rows.size, n_hist), np.int64)
        pose_xy, pose_yaw = np.empty((rows.size * n_hist, 2)), np.empty(rows.size * n_hist)
        bad = _prepare(rows, frames, self._num_frames, ego_xy, ego_yaw, history, pose_xy, pose_yaw)
        if bad >= 0:
            raise self._bad_row(rows, frames, bad)
        # The current frame's pose is channel 0's.
        matrices = np.ascontiguousarray(world_matrices(self._local, pose_xy[::n_hist], pose_yaw[::n_hist]))
        ego = ego_corners(pose_xy, pose_yaw)
        fresh = out is None
        if fresh:
            out = Canvas(p, rows.size, self.boxes.most)
        elif out.image.shape[1:] != (p.num_channels, p.height, p.width) or out.rects.shape[2] < self.boxes.most:
            raise ValueError(f"out: a canvas of {out.image.shape[1:]} images for {out.rects.shape[2]} boxes a cell, "
                             f"this rasterizer draws {(p.num_channels, p.height, p.width)} and up to "
                             f"{self.boxes.most}: make it with Rasterizer.canvas")
        elif rows.size > out.capacity:
            raise ValueError(f"out: {rows.size} rows for a canvas of {out.capacity}")
        draw_box_channels(out.image, LUT, matrices, rows, history, self.boxes.offsets, self.boxes.n_frames,
                          self.boxes.corners, ego.reshape(rows.size, n_hist, 4, 2), p.render_ego_history, out.rects,
                          out.n_rects)
        out = out.image if fresh else out.image[:rows.size]
        if self.semantic:
            self._draw_semantic(out, matrices, rows, frames)
        return out

    def _draw_semantic(self, out: np.ndarray, matrices: np.ndarray, rows: np.ndarray, frames: np.ndarray) -> None:
        centres = np.ascontiguousarray(raster_centre_in_world(self.params, matrices))
        region = self._regions[rows]
        outside = np.flatnonzero((centres[:, 0] < region[:, 0]) | (centres[:, 1] < region[:, 1])
                                 | (centres[:, 0] > region[:, 2]) | (centres[:, 1] > region[:, 3]))
        if outside.size:  # the driven ego left the area prepared from its log: widen that scene's
            for b in outside.tolist():
                s = int(rows[b])
                r = self._regions[s] + np.array([_REACH, _REACH, -_REACH, -_REACH])
                self._cover(s, np.concatenate([np.minimum(r[:2], centres[b]), np.maximum(r[2:], centres[b])]))
            self._pack()
        m = self.map
        draw_semantic_batch(out, LUT, self.params.box_channels, matrices, centres, self.half, rows, frames,
                            self.log.shape[1], self.lane_offsets, self.lanes, m.lane_bounds, m.lane_polygons,
                            m.lane_face_offsets, m.lane_faces, m.face_rank, m.face_colour, self.face_offsets,
                            self.face_ids, self.cw_offsets, self.crosswalks, m.crosswalk_bounds, m.crosswalk_points,
                            m.crosswalk_offsets)


def rasterize(params: RasterParams, log: "LogArrays", rows, frames, ego_xy: np.ndarray, ego_yaw: np.ndarray, *,
              scenes: Sequence[L5Scene] | None = None, keep: np.ndarray | None = None,
              semantic_map: "SemanticMap | PreparedMap | None" = None, faces: ActiveFaces | None = None) -> np.ndarray:
    """(B, C, H, W) float32 rasters of rows ``(rows[b], frames[b])`` in one call.

    Builds a :class:`Rasterizer` each time; a loop that rasterizes every step
    should keep one."""
    return Rasterizer(params, log, scenes=scenes, keep=keep, semantic_map=semantic_map, faces=faces)(
        rows, frames, ego_xy, ego_yaw)
