"""The map under a bird's-eye animation's boxes: lane surfaces, road lines, road edges and
crosswalks as plain world-frame arrays, drawn in muted colours.

The view follows the ego, so the map is drawn once per square tile of the view's size and each
frame is pasted together from the (at most four) tiles it overlaps: a scene's 100-200 frames
draw the few tiles its ego crosses, not the map once per frame.  Tiles share one pixel grid
(a tile is exactly ``size`` pixels), so a polygon cut by a tile border joins without a seam;
the map sits within half a pixel of where the boxes are drawn.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np


LANE = (229, 231, 226)
ROAD_LINE = (205, 186, 125)
ROAD_EDGE = (150, 136, 122)
CROSSWALK = (226, 222, 242)
CROSSWALK_OUTLINE = (176, 168, 214)
COLOURS = (LANE, ROAD_LINE, ROAD_EDGE, CROSSWALK, CROSSWALK_OUTLINE)


@dataclass(frozen=True)
class DrawnMap:
    """What the animation draws of a map, each entry a (K, 2) array of world metres."""

    lane_surfaces: list[np.ndarray] = field(default_factory=list)  # polygons
    road_lines: list[np.ndarray] = field(default_factory=list)     # polylines
    road_edges: list[np.ndarray] = field(default_factory=list)     # polylines
    crosswalks: list[np.ndarray] = field(default_factory=list)     # polygons

    def present(self) -> list[str]:
        """The legend's names of the layers that hold something, in drawing order."""
        return [name for name, items in (("lane", self.lane_surfaces), ("road line", self.road_lines),
                                         ("road edge", self.road_edges), ("crosswalk", self.crosswalks)) if items]


def _bounds(items: list[np.ndarray]) -> np.ndarray:
    """(N, 4) xmin, ymin, xmax, ymax of each item."""
    if not items:
        return np.zeros((0, 4))
    return np.array([[*item.min(axis=0), *item.max(axis=0)] for item in items], dtype=float).reshape(-1, 4)


def _overlapping(bounds: np.ndarray, box: tuple[float, float, float, float]) -> np.ndarray:
    xmin, ymin, xmax, ymax = box
    return np.flatnonzero((bounds[:, 0] <= xmax) & (bounds[:, 1] <= ymax) & (bounds[:, 2] >= xmin)
                          & (bounds[:, 3] >= ymin))


class MapBackground:
    """The map as each frame's background, for a view ``size`` pixels wide at ``scale`` px/m."""

    def __init__(self, drawn: DrawnMap, scale: float, size: int, background: tuple[int, int, int]):
        self.scale, self.size, self.background = scale, size, background
        self.metres = size / scale
        # Drawn bottom to top: surfaces, crosswalks on them, then the lines.  Lanes have no outline:
        # overlapping lanes read as one road, the road lines divide it (and outlines cost a quarter
        # of the GIF's size).
        self.layers = [(items, _bounds(items), painter) for items, painter in (
            ([np.asarray(p, float)[:, :2] for p in drawn.lane_surfaces], _polygon(LANE, None)),
            ([np.asarray(p, float)[:, :2] for p in drawn.crosswalks], _polygon(CROSSWALK, CROSSWALK_OUTLINE)),
            ([np.asarray(p, float)[:, :2] for p in drawn.road_lines], _line(ROAD_LINE, 1)),
            ([np.asarray(p, float)[:, :2] for p in drawn.road_edges], _line(ROAD_EDGE, 2)),
        ) if items]
        self.tiles: dict[tuple[int, int], object] = {}

    def tile(self, i: int, j: int):
        """Tile (i, j): world x in [i, i + 1) and y in [j, j + 1) views, drawn when first needed."""
        if (i, j) not in self.tiles:
            from PIL import Image, ImageDraw

            image = Image.new("RGB", (self.size, self.size), self.background)
            draw = ImageDraw.Draw(image)
            m = self.metres
            # The tile's pixels as canvas.pixel_mapper's around the tile's centre, in numpy: a map's
            # lines run to thousands of points, too many for a point-by-point conversion.
            corner, flip = np.array([i * m, (j + 1) * m]), np.array([self.scale, -self.scale])
            margin = 2.0 / self.scale  # a line's width past the tile's edge still shows
            box = (i * m - margin, j * m - margin, (i + 1) * m + margin, (j + 1) * m + margin)
            for items, bounds, paint in self.layers:
                for k in _overlapping(bounds, box):
                    paint(draw, ((items[k] - corner) * flip).ravel().tolist())
            self.tiles[(i, j)] = image
        return self.tiles[(i, j)]

    def under(self, centre: np.ndarray):
        """A new frame image with the map of the view around ``centre`` drawn on it."""
        from PIL import Image

        m, size = self.metres, self.size
        image = Image.new("RGB", (size, size), self.background)
        i0 = int(np.floor((centre[0] - m / 2) / m))
        j0 = int(np.floor((centre[1] - m / 2) / m))
        # Where tile (i0, j0)'s top-left pixel lands in the frame; the others are whole tiles away.
        dx = int(round(((i0 + 0.5) * m - centre[0]) * self.scale))
        dy = int(round((centre[1] - (j0 + 0.5) * m) * self.scale))
        for di in (0, 1):
            for dj in (0, 1):
                image.paste(self.tile(i0 + di, j0 + dj), (dx + di * size, dy - dj * size))
        return image


def _polygon(fill: tuple[int, int, int], outline: tuple[int, int, int] | None) -> Callable:
    def paint(draw, points) -> None:
        if len(points) >= 6:  # three (x, y) pairs
            draw.polygon(points, fill=fill, outline=outline)

    return paint


def _line(colour: tuple[int, int, int], width: int) -> Callable:
    def paint(draw, points) -> None:
        draw.line(points, fill=colour, width=width)

    return paint


def swatch(draw, name: str, box: tuple[int, int, int, int]) -> None:
    """The legend's sample of layer ``name`` in ``box`` (x0, y0, x1, y1)."""
    x0, y0, x1, y1 = box
    if name == "lane":
        draw.rectangle(box, fill=LANE)
    elif name == "crosswalk":
        draw.rectangle(box, fill=CROSSWALK, outline=CROSSWALK_OUTLINE)
    else:
        draw.line([(x0, (y0 + y1) / 2), (x1, (y0 + y1) / 2)], fill=ROAD_LINE if name == "road line" else ROAD_EDGE,
                  width=1 if name == "road line" else 2)
