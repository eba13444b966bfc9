"""Bird's-eye animation of an unroll: agents as boxes, the ego, its logged and
driven trajectories, collisions marked (drawn as :mod:`.canvas` says)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..geometry import box_corners
from .canvas import frames_to_show, pixel_mapper, save_gif

BACKGROUND = (250, 250, 250)
AGENT = (120, 144, 156)
EGO = (25, 118, 210)
LOGGED = (160, 160, 160)
DRIVEN = (25, 118, 210)
COLLISION = (211, 47, 47)
TEXT = (33, 33, 33)


def frame_label(title: str, frame: int, collision: bool) -> str:
    """The caption of one frame of the animation."""
    return f"{title}  frame {frame}" + ("  COLLISION" if collision else "")


def render_unroll_gif(
    path: Path,
    ego_xy: np.ndarray,          # (T, 2) driven
    ego_yaw: np.ndarray,         # (T,)
    ego_extent: np.ndarray,      # (2,) length, width
    logged_xy: np.ndarray,       # (T, 2)
    agent_xy: np.ndarray,        # (T, A, 2)
    agent_yaw: np.ndarray,       # (T, A)
    agent_extent: np.ndarray,    # (T, A, 2) or (A, 2)
    agent_available: np.ndarray,  # (T, A) bool
    collision: np.ndarray,       # (T,) bool
    title: str = "",
    frame_numbers: np.ndarray | None = None,  # (T,) each row's frame as the findings name it; default 0..T-1
    size: int = 320,
    meters: float = 60.0,
    max_frames: int = 80,
    frame_ms: int = 100,
) -> Path:
    from PIL import Image, ImageDraw

    # Every collision frame stays visible even when subsampling skips it.
    shown = frames_to_show(len(ego_xy), max_frames, always=np.flatnonzero(collision))
    scale = size / meters
    agent_extent = np.broadcast_to(agent_extent, agent_xy.shape[:2] + (agent_extent.shape[-1],))[..., :2]
    ego_corners = box_corners(ego_xy, ego_yaw, np.broadcast_to(ego_extent[:2], ego_xy.shape))
    agent_corners = box_corners(agent_xy, agent_yaw, agent_extent)

    numbers = np.arange(len(ego_xy)) if frame_numbers is None else np.asarray(frame_numbers)
    images = []
    for t in shown:
        center = ego_xy[t]
        px = pixel_mapper(center, scale, size)
        image = Image.new("RGB", (size, size), BACKGROUND)
        draw = ImageDraw.Draw(image)
        draw.line(px(logged_xy), fill=LOGGED, width=2)
        draw.line(px(ego_xy[: t + 1]), fill=DRIVEN, width=2)
        visible = np.flatnonzero(agent_available[t] & (np.abs(agent_xy[t] - center).max(axis=-1) < meters))
        for a in visible:
            draw.polygon(px(agent_corners[t, a]), outline=AGENT, fill=(207, 216, 220))
        colour = COLLISION if collision[t] else EGO
        draw.polygon(px(ego_corners[t]), outline=colour, fill=colour)
        label = frame_label(title, int(numbers[t]), bool(collision[t]))
        draw.text((4, 4), label, fill=COLLISION if collision[t] else TEXT)
        images.append(image)
    return save_gif(path, images, frame_ms, colors=16)
