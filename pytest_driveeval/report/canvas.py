"""What the bird's-eye animations share: which frames to draw, world metres to
pixels around a moving centre, and a small-palette GIF written whole.

Pillow straight from arrays (no matplotlib figure per frame), sized for a
report: frames are subsampled and the palette is small, so a GIF stays a few
hundred KB.
"""
from __future__ import annotations

from pathlib import Path
from typing import Callable, Iterable, Sequence

import numpy as np

from ..atomic import atomic_path

Pixels = Callable[[np.ndarray], list[tuple[float, float]]]


def frames_to_show(count: int, max_frames: int, always: Iterable[int] = ()) -> np.ndarray:
    """About ``max_frames`` evenly spaced frames of ``count``, plus every frame of ``always``
    (a collision, the last frame) that the spacing would skip."""
    step = max(1, int(np.ceil(count / max_frames)))
    return np.union1d(np.arange(0, count, step), np.asarray(list(always), dtype=int)).astype(int)


def pixel_mapper(centre: np.ndarray, scale: float, size: int) -> Pixels:
    """World points (..., 2) -> pixel tuples for Pillow, ``centre`` in the middle, y up, ``scale`` px/m."""
    def px(points: np.ndarray) -> list[tuple[float, float]]:
        rel = (np.asarray(points).reshape(-1, 2) - centre) * scale
        return [(size / 2 + x, size / 2 - y) for x, y in rel]

    return px


def save_gif(path: Path, images: Sequence, frame_ms: int, colors: int) -> Path:
    """The frames as a looping GIF of ``colors`` colours; a killed session leaves no truncated file."""
    from PIL import Image

    frames = [image.quantize(colors=colors, method=Image.Quantize.MEDIANCUT) for image in images]
    with atomic_path(path) as tmp:
        frames[0].save(tmp, format="GIF", save_all=True, append_images=frames[1:], duration=frame_ms, loop=0,
                       optimize=True)
    return path
