"""Where and when a score term failed, as the bird's-eye animation marks it: a marker is
(frame number, x, y, kind), the frame as the log numbers it, the place in world metres; each
kind has its colour and shape, drawn from its frame to the end and named in the caption."""
from __future__ import annotations

from typing import Sequence

import numpy as np

Marker = tuple[int, float, float, str]

#: kind -> (caption and legend name, colour, shape)
KINDS = {
    "off_drivable_area": ("off drivable area", (239, 108, 0), "circle"),
    "wrong_direction": ("wrong direction", (142, 36, 170), "square"),
    "time_to_collision": ("time to collision", (0, 137, 123), "diamond"),
    "collision": ("collision", (211, 47, 47), "cross"),
}
#: caption lines of past failures kept on a frame: the newest
CAPTION_LINES = 3


def checked(markers: Sequence[Marker] | None) -> list[Marker]:
    """The markers as (int, float, float, str), refusing a kind the animation cannot draw."""
    out = []
    for frame, x, y, kind in markers or ():
        if kind not in KINDS:
            raise ValueError(f"marker kind {kind!r} is not one of {', '.join(KINDS)}")
        out.append((int(frame), float(x), float(y), kind))
    return out


def first_rows(markers: list[Marker], numbers: np.ndarray) -> np.ndarray:
    """The row of the animation each marker first shows on: the first whose frame number is the
    marker's or later (``len(numbers)``, never, for a marker past the end)."""
    return np.searchsorted(np.asarray(numbers), [m[0] for m in markers], side="left").astype(int)


def failure_lines(markers: list[Marker], rows: np.ndarray, t: int) -> list[tuple[str, tuple[int, int, int]]]:
    """The caption's lines of failures shown by row ``t``: "frame 41: off drivable area" per frame
    that has markers, in the colour of its first, newest last."""
    by_frame: dict[int, list[str]] = {}
    for (frame, _, _, kind), row in zip(markers, rows):
        if row <= t and kind not in by_frame.setdefault(frame, []):
            by_frame[frame].append(kind)
    return [(f"frame {frame}: " + ", ".join(KINDS[k][0] for k in kinds), KINDS[kinds[0]][1])
            for frame, kinds in sorted(by_frame.items())][-CAPTION_LINES:]


def draw_marker(draw, x: float, y: float, kind: str, radius: float) -> None:
    """Kind ``kind``'s mark centred on pixel (x, y)."""
    _, colour, shape = KINDS[kind]
    r = radius
    if shape == "circle":
        draw.ellipse((x - r, y - r, x + r, y + r), outline=colour, width=2)
    elif shape == "square":
        draw.rectangle((x - r, y - r, x + r, y + r), outline=colour, width=2)
    elif shape == "diamond":
        draw.polygon([(x, y - r), (x + r, y), (x, y + r), (x - r, y)], outline=colour, width=2)
    else:
        draw.line([(x - r, y - r), (x + r, y + r)], fill=colour, width=2)
        draw.line([(x - r, y + r), (x + r, y - r)], fill=colour, width=2)
