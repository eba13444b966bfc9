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

from ..io.l5.l5kit_zarr import L5Scene
from .draw import compiled, fill_polygons

if TYPE_CHECKING:
    from ..sim.logreplay.logarrays import LogArrays

__all__ = ["EGO_BOX", "BoxTable", "agent_keep", "box_corners", "draw_box_channels", "ego_corners"]

EGO_BOX = np.array([4.87, 1.85], np.float32)  # l5kit's rasterizer ego (length, width)
KEEP_LABELS = np.arange(3, 16)  # PERCEPTION_LABEL_CAR .. PERCEPTION_LABEL_ANIMAL
# Box channels are white.  A global, so that compiled code sees it as a read-only constant like
# semantic.py's COLOURS rows: fill_polygons and line_aa are then compiled once for both callers.
_WHITE = np.full(1, 255, np.int64)
_FAR = 1e9  # metres: a box there is off every raster (and its pixel coordinates still fit an int64)
_UNIT_CORNERS = np.asarray([[-1, -1], [-1, 1], [1, 1], [1, -1]]) * 0.5
_EGO_LOCAL = _UNIT_CORNERS * EGO_BOX  # what box_corners makes of the ego's extent, once


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
    return _place(_UNIT_CORNERS[None] * np.asarray(extent, np.float32)[:, None, :2], yaw, centroid)


def ego_corners(centroid: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """``box_corners`` of the rasterizer's ego box, to the last bit."""
    return _place(_EGO_LOCAL, yaw, centroid)


def _place(corners: np.ndarray, yaw: np.ndarray, centroid: np.ndarray) -> np.ndarray:
    yaw = np.asarray(yaw, np.float32)
    s, c = np.sin(yaw), np.cos(yaw)
    rotation = np.stack([c, s, -s, c], -1).reshape(-1, 2, 2)
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
        self.most = max(int(counts.max(initial=0)), 1)  # boxes of the fullest cell, at least the ego's one
        self.scene, self.column = s, c

    def refresh(self, log: "LogArrays", rows: np.ndarray, frame: int) -> None:
        """The corners of the kept boxes of (``rows``, ``frame``) again, from ``log``: a copy of
        the log these were prepared from in which agents moved (reactive agents).  A box whose
        cell is no longer available goes far off every raster."""
        cells = np.asarray(rows, np.int64) * self.n_frames + frame
        first, last = self.offsets[cells], self.offsets[cells + 1]
        counts = last - first
        idx = np.repeat(first - np.cumsum(counts) + counts, counts) + np.arange(int(counts.sum()))
        if idx.size == 0:
            return
        s, c = self.scene[idx], self.column[idx]
        corners = box_corners(log.agent_xy[s, frame, c], log.agent_yaw[s, frame, c], log.agent_extent[s, frame, c, :2])
        corners[~log.available[s, frame, c]] = _FAR
        self.corners[idx] = corners


@compiled
def _clear(out, rects, n):
    """Zero the rectangles ``rects[:n]`` (x0, y0, x1, y1 inclusive) of ``out`` (H, W)."""
    for r in range(n):
        for y in range(rects[r, 1], rects[r, 3] + 1):
            out[y, rects[r, 0]:rects[r, 2] + 1] = 0.0


@compiled
def _channel(out, lut, scratch, matrix, corners, first, last, colour, verts, starts, rects):
    """Draw boxes ``corners[first:last]`` in one fillPoly and write what they touched of
    ``scratch`` to ``out`` (H, W) through ``lut``, leaving ``scratch`` zero again.

    Returns how many boxes were drawn; ``rects`` gets their pixel rectangles (clipped to
    the image), which hold every pixel the fill and its outline can touch: an even-odd
    fill only paints points inside some box, and the outline stays within a pixel or
    two of an edge."""
    height, width = scratch.shape[0], scratch.shape[1]
    n = 0
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
        rects[n, 0], rects[n, 2] = max(int(xmin) - 3, 0), min(int(xmax) + 3, width - 1)
        rects[n, 1], rects[n, 3] = max(int(ymin) - 3, 0), min(int(ymax) + 3, height - 1)
        n += 1
        starts[n] = 4 * n
    if n == 0:
        return 0
    fill_polygons(scratch, verts[:4 * n], starts[:n + 1], colour)
    # Copied whole, zeros too (the channel is zero where nothing is drawn), without a branch a pixel;
    # overlapping rectangles copy the same values, as the scratch is zeroed after all of them.
    for r in range(n):
        for y in range(rects[r, 1], rects[r, 3] + 1):
            for x in range(rects[r, 0], rects[r, 2] + 1):
                out[y, x] = lut[scratch[y, x, 0]]
    for r in range(n):
        for y in range(rects[r, 1], rects[r, 3] + 1):
            scratch[y, rects[r, 0]:rects[r, 2] + 1, 0] = 0
    return n


@compiled
def draw_box_channels(out, lut, matrices, rows, history, offsets, n_frames, corners, ego_corners, ego_history,
                      rects, n_rects):
    """Fill the 2 (H+1) box channels of ``out`` (B, C, height, width).

    ``history`` (B, H+1) holds the frame of each channel, -1 before the scene's
    start; ``ego_corners`` (B, H+1, 4, 2); ``ego_history`` False draws only the
    current ego.  ``rects`` (>= B, 2 (H+1), K, 4) int and ``n_rects`` (>= B, 2 (H+1)):
    on entry the rectangles drawn into ``out`` before, the only non-zero pixels of the
    box channels (these are cleared first); on return those drawn now.  K must hold
    the most boxes of any (scene, frame) cell, and at least one."""
    n_hist = history.shape[1]
    scratch = np.zeros((out.shape[2], out.shape[3], 1), np.uint8)
    most = rects.shape[2]
    verts = np.empty((4 * most, 2), np.int64)
    starts = np.zeros(most + 1, np.int64)
    # the ego's one box, as int64 values: literal 0 and 1 would compile _channel a second time
    zero, one = np.int64(0), np.int64(1)
    for b in range(rows.size):
        for ch in range(2 * n_hist):
            _clear(out[b, ch], rects[b, ch], n_rects[b, ch])
            n_rects[b, ch] = 0
        for i in range(n_hist):
            frame = history[b, i]
            if frame < 0:
                continue
            cell = rows[b] * n_frames + frame
            n_rects[b, i] = _channel(out[b, i], lut, scratch, matrices[b], corners, offsets[cell], offsets[cell + 1],
                                     _WHITE, verts, starts, rects[b, i])
            if ego_history or i == 0:
                n_rects[b, n_hist + i] = _channel(out[b, n_hist + i], lut, scratch, matrices[b],
                                                  ego_corners[b, i:i + 1], zero, one, _WHITE, verts, starts,
                                                  rects[b, n_hist + i])
