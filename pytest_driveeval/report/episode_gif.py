"""An animated episode of the policy benchmark with its graph drawn over the
scene, as in seed 002's figure: the ego red, the others blue, the visibility
zone around the ego, the goal green, and the observation's edges.

Arrays in, a GIF out (drawn as :mod:`.canvas` says); the caller passes the
road as polygons, so this module knows nothing of the simulator.
"""
from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np

from ..geometry import box_corners
from .canvas import frames_to_show, pixel_mapper, save_gif

BACKGROUND = (250, 250, 250)
ROAD = (224, 224, 224)
ROAD_EDGE = (189, 189, 189)
EGO = (211, 47, 47)
OTHER = (30, 136, 229)
EDGE = (121, 134, 203)
ZONE = (255, 236, 179)
GOAL = (67, 160, 71)
TEXT = (33, 33, 33)


def graph_edges(xy: np.ndarray, valid: np.ndarray, agent_limit: int, radius: float) -> list[tuple[int, int]]:
    """Pairs (i, j), i < j, of the nodes the observation keeps (the ego and
    its nearest valid others, up to the limit) that lie within ``radius``."""
    others = np.flatnonzero(valid[1:]) + 1
    order = others[np.argsort(np.linalg.norm(xy[others] - xy[0], axis=1), kind="stable")][: agent_limit - 1]
    nodes = np.concatenate([[0], order])
    d = np.linalg.norm(xy[nodes][:, None] - xy[nodes][None], axis=-1)
    i, j = np.nonzero(np.triu(d <= radius, k=1))
    return [(int(nodes[a]), int(nodes[b])) for a, b in zip(i, j)]


def render_episode_gif(
    path: Path,
    xy: np.ndarray,               # (T, A, 2), agent 0 the ego
    yaw: np.ndarray,              # (T, A)
    valid: np.ndarray,            # (T, A) bool
    size_lw: Sequence[float],     # vehicle (length, width), or (A, 2): one per agent
    road: Sequence[np.ndarray],   # drivable polygons (N_i, 2)
    goal_corners: np.ndarray,     # (4, 2)
    agent_limit: int = 12,
    radius: float = 50.0,
    title: str = "",
    pixels: int = 360,
    meters: float = 120.0,
    max_frames: int = 80,
    frame_ms: int = 120,
) -> Path:
    from PIL import Image, ImageDraw

    shown = frames_to_show(len(xy), max_frames, always=[len(xy) - 1])  # the end is what the verdict is about
    scale = pixels / meters
    corners = box_corners(xy, yaw, np.broadcast_to(np.asarray(size_lw, float)[..., :2], xy.shape))
    images = []
    for t in shown:
        px = pixel_mapper(xy[t, 0], scale, pixels)
        image = Image.new("RGB", (pixels, pixels), BACKGROUND)
        draw = ImageDraw.Draw(image)
        for polygon in road:
            draw.polygon(px(polygon), fill=ROAD, outline=ROAD_EDGE)
        r = radius * scale
        draw.ellipse((pixels / 2 - r, pixels / 2 - r, pixels / 2 + r, pixels / 2 + r), outline=ZONE, width=3)
        draw.polygon(px(goal_corners), outline=GOAL, width=3)
        for a, b in graph_edges(xy[t], valid[t], agent_limit, radius):
            draw.line(px(xy[t, [a, b]]), fill=EDGE, width=1)
        for a in np.flatnonzero(valid[t, 1:]) + 1:
            draw.polygon(px(corners[t, a]), fill=OTHER)
        draw.polygon(px(corners[t, 0]), fill=EGO)
        draw.text((4, 4), f"{title}  step {t}", fill=TEXT)
        images.append(image)
    return save_gif(path, images, frame_ms, colors=32)
