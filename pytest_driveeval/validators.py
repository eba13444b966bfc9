"""Thresholds over per-frame figures, turned into findings that name frames."""
from __future__ import annotations

from typing import Sequence

import numpy as np

from .outcome import Finding, format_figure

MAX_FRAMES_LISTED = 5


def within(values: Sequence[float] | np.ndarray, *, figure: str, max: float | None = None,
           min: float | None = None, frames: Sequence[int] | None = None, unit: str = "",
           scene: int | str | None = None, keypath: tuple = ()) -> Finding | None:
    """None if every value lies in [min, max]; else a finding naming the frames
    that do not (first few, and the worst).  NaN is never within bounds."""
    values = np.asarray(values, dtype=float).reshape(-1)
    frame_ids = np.arange(values.size) if frames is None else np.asarray(frames).reshape(-1)
    bad = ~np.isfinite(values)
    excess = np.zeros_like(values)
    if max is not None:
        excess = np.where(values > max, values - max, excess)
    if min is not None:
        excess = np.where(values < min, min - values, excess)
    bad |= excess > 0
    if not bad.any():
        return None
    index = np.flatnonzero(bad)
    worst = index[np.argmax(np.where(np.isfinite(excess[index]), excess[index], np.inf))]
    bound = " and ".join(b for b in (f">= {format_figure(min)}" if min is not None else "",
                                     f"<= {format_figure(max)}" if max is not None else "") if b)
    listed = ", ".join(f"frame {int(frame_ids[i])} ({format_figure(float(values[i]))}{unit})"
                       for i in index[:MAX_FRAMES_LISTED])
    more = f", ... {index.size - MAX_FRAMES_LISTED} more" if index.size > MAX_FRAMES_LISTED else ""
    where = f"scene {scene}: " if scene is not None else ""
    message = (f"{where}{figure} should be {bound}{unit} but is not at {index.size} of {values.size} frame(s): "
               f"{listed}{more}; worst at frame {int(frame_ids[worst])}: {format_figure(float(values[worst]))}{unit}")
    limit = max if max is not None and (min is None or values[worst] > max) else min
    return Finding(message, figure=figure, value=float(values[worst]), limit=limit,
                   frame=int(frame_ids[worst]), scene=scene, keypath=keypath)
