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

from ..core.atomic import atomic_path

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


def blends(colours: Sequence[tuple[int, int, int]], background: tuple[int, int, int], steps: int = 3
           ) -> list[tuple[int, int, int]]:
    """Each colour part-way to ``background``: the shades of a text's anti-aliased edges, for a palette."""
    return [tuple(int(round(c + (b - c) * k / steps)) for c, b in zip(colour, background))
            for colour in colours for k in range(1, steps)]


def save_gif(path: Path, images: Sequence, frame_ms: int, colors: int,
             palette: Sequence[tuple[int, int, int]] | None = None) -> Path:
    """The frames as a looping GIF of ``colors`` colours, or of exactly the colours of ``palette``
    (each pixel its nearest, undithered: a colour drawn in a few pixels, a legend's, is kept, where
    each frame's own median cut would merge it into a neighbour); a killed session leaves no
    truncated file."""
    from PIL import Image

    if palette is not None:
        fixed = Image.new("P", (1, 1))
        # Filled to 256 entries with a colour of its own: unfilled entries would be black, and nearest to dark text.
        fixed.putpalette([c for colour in list(palette) + [palette[0]] * (256 - len(palette)) for c in colour])
        frames = [image.quantize(palette=fixed, dither=Image.Dither.NONE) for image in images]
    else:
        frames = [image.quantize(colors=colors, method=Image.Quantize.MEDIANCUT) for image in images]
    with atomic_path(path) as tmp:
        frames[0].save(tmp, format="GIF", save_all=True, append_images=frames[1:], duration=frame_ms, loop=0,
                       optimize=True)
    return path
