"""l5kit's ``box_debug`` raster: agent and ego boxes, one channel per history frame.

What l5kit's BoxRasterizer draws (ego = the AV), restated:

* Channels: agents at t, t-1, .., t-H, then the ego at t, t-1, .., t-H.
  Frames before the scene's first leave their channels empty.  Every frame
  is drawn in the raster of the *current* ego pose.
* Agents of a frame: every agent row of that frame whose summed
  ``label_probabilities`` over CAR .. ANIMAL exceeds
  ``filter_agents_threshold`` (strictly), in the frame's row order.  The AV
  is not among the agents, so nothing else is excluded.
* The ego box is 4.87 m x 1.85 m (the rasterizer's Ford Fusion, not the
  4.869 x 1.852 of the vector inputs), centred on the ego position, its yaw
  stored as float32 like an agent's.  Without ``render_ego_history`` only
  the current ego channel is drawn.
* Corners (-l/2, -w/2), (-l/2, w/2), (l/2, w/2), (l/2, -w/2), rotated by the
  float32 yaw's float32 cos/sin, in float64.
* All boxes of a channel go to one ``fillPoly`` (value 255, shift 9,
  anti-aliased), so overlapping boxes cancel where they overlap; the image
  is ``uint8 / 255`` as float32.
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Sequence

import numpy as np

from ..io.l5kit_zarr import L5Scene
from .draw import AVAILABLE, fill_polygons

if TYPE_CHECKING:
    from ..sim.logreplay.logarrays import LogArrays

__all__ = ["EGO_BOX", "BoxTable", "agent_keep", "box_corners", "draw_box_channels"]

EGO_BOX = np.array([4.87, 1.85], np.float32)  # l5kit's rasterizer ego (length, width)
KEEP_LABELS = np.arange(3, 16)  # PERCEPTION_LABEL_CAR .. PERCEPTION_LABEL_ANIMAL
_UNIT_CORNERS = np.asarray([[-1, -1], [-1, 1], [1, 1], [1, -1]]) * 0.5


def _compiled(fn):
    if not AVAILABLE:
        return fn
    from numba import njit
    return njit(cache=True, nogil=True)(fn)


def agent_keep(scenes: Sequence[L5Scene], log: "LogArrays", threshold: float) -> np.ndarray:
    """(S, T, C) l5kit's per-row label filter on the log's cells.

    ``LogArrays`` keeps one label per track (``relevant``), while l5kit judges
    every row by its own probabilities, so this reads them from the scenes
    (``scenes[s]`` is the scene of log row s) through ``frame_row``.
    """
    if len(scenes) != log.shape[0]:
        raise ValueError(f"agent_keep: {len(scenes)} scenes for a log of {log.shape[0]} rows")
    keep = np.zeros(log.shape, bool)
    for s, scene in enumerate(scenes):
        probs = scene.agents["label_probabilities"]
        row_ok = np.sum(probs[:, KEEP_LABELS], axis=1) > threshold  # l5kit's float32 sum and comparison
        t, c = np.nonzero(log.frame_row[s] >= 0)
        if t.size and t.max() >= scene.num_frames:
            raise ValueError(f"agent_keep: scene {scene.index} of {scene.source or 'memory'} has "
                             f"{scene.num_frames} frames but log row {s} has agents at frame {int(t.max())}")
        rows = scene.frames["agent_index_interval"][t, 0] + log.frame_row[s, t, c]
        if rows.size and rows.max() >= len(probs):
            raise ValueError(f"agent_keep: log row {s} does not match scene {scene.index} "
                             f"(agent row {int(rows.max())} of {len(probs)})")
        keep[s, t, c] = row_ok[rows]
    return keep


def box_corners(centroid: np.ndarray, yaw: np.ndarray, extent: np.ndarray) -> np.ndarray:
    """(N, 4, 2) world corners with l5kit's arithmetic: yaw (N,) and extent (N, 2) float32."""
    yaw = np.asarray(yaw, np.float32)
    corners = _UNIT_CORNERS[None] * np.asarray(extent, np.float32)[:, None, :2]
    s, c = np.sin(yaw), np.cos(yaw)
    rotation = np.moveaxis(np.array(((c, s), (-s, c))), 2, 0)
    return corners @ rotation + np.asarray(centroid, np.float64)[:, None, :2]


class BoxTable:
    """The drawable agent boxes of a log, prepared once: per (scene, frame) the
    kept cells in the frame's row order (CSR ``offsets`` over S*T) and their
    world corners, which do not depend on the ego."""

    def __init__(self, log: "LogArrays", keep: np.ndarray):
        keep = np.asarray(keep, bool)
        if keep.shape != log.shape:
            raise ValueError(f"BoxTable: keep mask of shape {keep.shape} for a log of shape {log.shape}")
        s, t, c = np.nonzero(keep & log.available)
        order = np.lexsort((log.frame_row[s, t, c], t, s))
        s, t, c = s[order], t[order], c[order]
        n_scenes, n_frames, _ = log.shape
        counts = np.bincount(s * n_frames + t, minlength=n_scenes * n_frames)
        self.n_frames = n_frames
        self.offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
        self.corners = np.ascontiguousarray(
            box_corners(log.agent_xy[s, t, c], log.agent_yaw[s, t, c], log.agent_extent[s, t, c, :2]))


@_compiled
def _channel(out, lut, scratch, matrix, corners, first, last, colour, verts, starts):
    """Draw boxes ``corners[first:last]`` in one fillPoly and write the touched part of
    ``scratch`` to ``out`` (H, W) through ``lut``, leaving ``scratch`` zero again."""
    height, width = scratch.shape[0], scratch.shape[1]
    n = 0
    lo_x, lo_y, hi_x, hi_y = 1 << 40, 1 << 40, -(1 << 40), -(1 << 40)
    for k in range(first, last):
        xmin, ymin, xmax, ymax = np.inf, np.inf, -np.inf, -np.inf
        for v in range(4):
            px, py = corners[k, v, 0], corners[k, v, 1]
            rx = px * matrix[0, 0] + py * matrix[0, 1] + matrix[0, 2]
            ry = px * matrix[1, 0] + py * matrix[1, 1] + matrix[1, 2]
            verts[4 * n + v, 0] = int(rx * 512.0)
            verts[4 * n + v, 1] = int(ry * 512.0)
            xmin, xmax = min(xmin, rx), max(xmax, rx)
            ymin, ymax = min(ymin, ry), max(ymax, ry)
        # A box wholly off one side draws nothing, and leaves the even-odd fill of the others alone.
        if xmax < -1.0 or ymax < -1.0 or xmin > width + 1.0 or ymin > height + 1.0:
            continue
        lo_x, hi_x = min(lo_x, int(xmin) - 3), max(hi_x, int(xmax) + 3)
        lo_y, hi_y = min(lo_y, int(ymin) - 3), max(hi_y, int(ymax) + 3)
        n += 1
        starts[n] = 4 * n
    if n == 0:
        return
    fill_polygons(scratch, verts[:4 * n], starts[:n + 1], colour)
    for y in range(max(lo_y, 0), min(hi_y, height - 1) + 1):
        for x in range(max(lo_x, 0), min(hi_x, width - 1) + 1):
            value = scratch[y, x, 0]
            if value:
                out[y, x] = lut[value]
                scratch[y, x, 0] = 0


@_compiled
def draw_box_channels(out, lut, matrices, rows, history, offsets, n_frames, corners, ego_corners, ego_history):
    """Fill the 2 (H+1) box channels of ``out`` (B, C, height, width), zeros on entry.

    ``history`` (B, H+1) holds the frame of each channel, -1 before the scene's
    start; ``ego_corners`` (B, H+1, 4, 2); ``ego_history`` False draws only the
    current ego."""
    n_hist = history.shape[1]
    scratch = np.zeros((out.shape[2], out.shape[3], 1), np.uint8)
    most = 1
    for k in range(offsets.size - 1):
        most = max(most, offsets[k + 1] - offsets[k])
    verts = np.empty((4 * most, 2), np.int64)
    starts = np.zeros(most + 1, np.int64)
    colour = np.full(1, 255, np.int64)
    for b in range(rows.size):
        for i in range(n_hist):
            frame = history[b, i]
            if frame < 0:
                continue
            cell = rows[b] * n_frames + frame
            _channel(out[b, i], lut, scratch, matrices[b], corners, offsets[cell], offsets[cell + 1], colour,
                     verts, starts)
            if ego_history or i == 0:
                _channel(out[b, n_hist + i], lut, scratch, matrices[b], ego_corners[b, i:i + 1], 0, 1, colour,
                         verts, starts)
