"""What a raster is: l5kit's ``raster_params`` and the model options that shape it."""
from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["MAP_TYPES", "RasterParams"]

MAP_TYPES = ("box_debug", "py_semantic")


def _pair(name: str, value, kind) -> tuple:
    try:
        pair = tuple(kind(v) for v in value)
    except (TypeError, ValueError):
        raise ValueError(f"RasterParams.{name} must be a pair of numbers, got {value!r}") from None
    if len(pair) != 2:
        raise ValueError(f"RasterParams.{name} must be a pair (x, y), got {value!r}")
    return pair


@dataclass(frozen=True)
class RasterParams:
    """One raster configuration; the defaults are l5kit's example config.

    * ``raster_size`` (width, height) in pixels; the image is (height, width).
    * ``pixel_size`` metres per pixel, square pixels only (as l5kit).
    * ``ego_center`` where the ego sits, as fractions of the raster size; with
      ``set_origin_to_bottom`` the y fraction counts from the bottom row, so
      (0.25, 0.5) puts the ego a quarter in from the left, looking right.
    * ``history_num_frames`` past frames drawn besides the current one.
    * ``filter_agents_threshold``: an agent row is drawn when the summed
      probability of l5kit's agent classes (CAR .. ANIMAL) exceeds it.
    * ``render_ego_history``: draw the ego in every history channel, else only
      at the current frame.
    """

    map_type: str = "py_semantic"
    raster_size: tuple[int, int] = (224, 224)
    pixel_size: tuple[float, float] = (0.5, 0.5)
    ego_center: tuple[float, float] = (0.25, 0.5)
    history_num_frames: int = 0
    filter_agents_threshold: float = 0.5
    set_origin_to_bottom: bool = True
    render_ego_history: bool = True

    def __post_init__(self):
        if self.map_type not in MAP_TYPES:
            raise ValueError(f"RasterParams.map_type {self.map_type!r} is not supported; use one of {MAP_TYPES}")
        size = _pair("raster_size", self.raster_size, int)
        if size != tuple(self.raster_size) or min(size) < 1:
            raise ValueError(f"RasterParams.raster_size must be two positive integers, got {self.raster_size!r}")
        pixel = _pair("pixel_size", self.pixel_size, float)
        if not all(math.isfinite(p) and p > 0 for p in pixel):
            raise ValueError(f"RasterParams.pixel_size must be positive metres, got {self.pixel_size!r}")
        if pixel[0] != pixel[1]:
            raise ValueError(f"RasterParams.pixel_size must be square (l5kit has no other), got {self.pixel_size!r}")
        centre = _pair("ego_center", self.ego_center, float)
        if not all(math.isfinite(c) for c in centre):
            raise ValueError(f"RasterParams.ego_center must be finite fractions, got {self.ego_center!r}")
        if isinstance(self.history_num_frames, bool) or int(self.history_num_frames) != self.history_num_frames \
                or self.history_num_frames < 0:
            raise ValueError(f"RasterParams.history_num_frames must be an integer >= 0, got {self.history_num_frames!r}")
        threshold = float(self.filter_agents_threshold)
        if not math.isfinite(threshold):
            raise ValueError(f"RasterParams.filter_agents_threshold must be a number, got {self.filter_agents_threshold!r}")
        object.__setattr__(self, "raster_size", size)
        object.__setattr__(self, "pixel_size", pixel)
        object.__setattr__(self, "ego_center", centre)
        object.__setattr__(self, "history_num_frames", int(self.history_num_frames))
        object.__setattr__(self, "filter_agents_threshold", threshold)

    @property
    def width(self) -> int:
        return self.raster_size[0]

    @property
    def height(self) -> int:
        return self.raster_size[1]

    @property
    def box_channels(self) -> int:
        """Agents then ego, one channel each per frame from the current one back."""
        return 2 * (self.history_num_frames + 1)

    @property
    def num_channels(self) -> int:
        return self.box_channels + (3 if self.map_type == "py_semantic" else 0)
