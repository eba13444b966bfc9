"""Bird's-eye animation of an unroll: agents as boxes, the ego, its logged and
driven trajectories, collisions marked (drawn as :mod:`.canvas` says); given a map, it is
drawn under the boxes (:mod:`.map_layers`), and given markers, the places and frames where
a score term failed are marked and captioned (:mod:`.markers`), with a legend of both."""
from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np

from ..geometry import box_corners
from .canvas import blends, frames_to_show, pixel_mapper, save_gif
from .map_layers import COLOURS, DrawnMap, MapBackground, swatch
from .markers import KINDS, Marker, checked, draw_marker, failure_lines, first_rows

BACKGROUND = (250, 250, 250)
AGENT = (120, 144, 156)
EGO = (25, 118, 210)
LOGGED = (160, 160, 160)
DRIVEN = (25, 118, 210)
COLLISION = (211, 47, 47)
TEXT = (33, 33, 33)
AGENT_FILL = (207, 216, 220)
LEGEND_OUTLINE = (200, 200, 200)
MARKER_COLOURS = [colour for _, colour, _ in KINDS.values()]
#: every colour drawn, and the shades of the text's anti-aliased edges: a GIF keeps each exactly
PALETTE = list(dict.fromkeys([BACKGROUND, AGENT, AGENT_FILL, EGO, LOGGED, DRIVEN, COLLISION, TEXT, LEGEND_OUTLINE,
                              *COLOURS, *MARKER_COLOURS,
                              *blends([TEXT, COLLISION, *MARKER_COLOURS], BACKGROUND, steps=4)]))
#: pixels from one caption line to the next: the first stays in the top 16 rows, as it always was
LINE_HEIGHT = 13
#: metres: a marker's radius, so it rings a car-sized place
MARKER_RADIUS = 2.5


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
    drawn_map: DrawnMap | None = None,   # drawn under the boxes; None: a blank background
    markers: Sequence[Marker] | None = None,  # (frame number, x, y, kind): where a score term failed
) -> Path:
    from PIL import Image, ImageDraw

    numbers = np.arange(len(ego_xy)) if frame_numbers is None else np.asarray(frame_numbers)
    marks = checked(markers)
    first = first_rows(marks, numbers)
    # Every collision frame and every marker's first frame stays visible even when subsampling skips it.
    shown = frames_to_show(len(ego_xy), max_frames,
                           always=np.concatenate([np.flatnonzero(collision), first[first < len(ego_xy)]]))
    scale = size / meters
    background = MapBackground(drawn_map, scale, size, BACKGROUND) if drawn_map is not None else None
    key = legend(drawn_map.present() if drawn_map is not None else [], list(dict.fromkeys(m[3] for m in marks)))
    agent_extent = np.broadcast_to(agent_extent, agent_xy.shape[:2] + (agent_extent.shape[-1],))[..., :2]
    ego_corners = box_corners(ego_xy, ego_yaw, np.broadcast_to(ego_extent[:2], ego_xy.shape))
    agent_corners = box_corners(agent_xy, agent_yaw, agent_extent)
    images = []
    for t in shown:
        center = ego_xy[t]
        px = pixel_mapper(center, scale, size)
        image = background.under(center) if background is not None else Image.new("RGB", (size, size), BACKGROUND)
        draw = ImageDraw.Draw(image)
        draw.line(px(logged_xy), fill=LOGGED, width=2)
        draw.line(px(ego_xy[: t + 1]), fill=DRIVEN, width=2)
        visible = np.flatnonzero(agent_available[t] & (np.abs(agent_xy[t] - center).max(axis=-1) < meters))
        for a in visible:
            draw.polygon(px(agent_corners[t, a]), outline=AGENT, fill=AGENT_FILL)
        colour = COLLISION if collision[t] else EGO
        draw.polygon(px(ego_corners[t]), outline=colour, fill=colour)
        for (_, x, y, kind), row in zip(marks, first):
            if row <= t:
                draw_marker(draw, *px(np.array([x, y]))[0], kind, radius=max(5.0, MARKER_RADIUS * scale))
        if key is not None:
            image.paste(key, (4, size - key.height - 4))
        label = frame_label(title, int(numbers[t]), bool(collision[t]))
        caption(draw, [(label, COLLISION if collision[t] else TEXT)] + failure_lines(marks, first, t))
        images.append(image)
    return save_gif(path, images, frame_ms, colors=len(PALETTE), palette=PALETTE)


def caption(draw, lines: list[tuple[str, tuple[int, int, int]]]) -> None:
    """Lines of text at the top left, each on a patch of background so that it reads over the map."""
    for number, (text, colour) in enumerate(lines):
        at = (4, 4 + number * LINE_HEIGHT)
        x0, y0, x1, y1 = draw.textbbox(at, text)
        draw.rectangle((x0 - 1, y0 - 1, x1 + 1, y1 + 1), fill=BACKGROUND)
        draw.text(at, text, fill=colour)


def legend(layers: list[str], kinds: list[str]):
    """A small key of the map's layers and the markers' kinds (an image to paste), or None when
    neither is drawn."""
    from PIL import Image, ImageDraw

    names = layers + [KINDS[k][0] for k in kinds]
    if not names:
        return None
    probe = ImageDraw.Draw(Image.new("RGB", (1, 1)))
    row = 12
    width = 4 + 14 + 4 + int(max(probe.textlength(n) for n in names)) + 4
    image = Image.new("RGB", (width, 4 + row * len(names) + 2), BACKGROUND)
    draw = ImageDraw.Draw(image)
    draw.rectangle((0, 0, width - 1, image.height - 1), outline=LEGEND_OUTLINE)
    for i, name in enumerate(names):
        top = 4 + i * row
        box = (4, top + 2, 18, top + row - 3)
        if i < len(layers):
            swatch(draw, name, box)
        else:
            draw_marker(draw, 11, top + row / 2 - 0.5, kinds[i - len(layers)], radius=4)
        draw.text((22, top), name, fill=TEXT)
    return image
