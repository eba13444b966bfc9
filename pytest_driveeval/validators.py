"""Thresholds over per-frame figures, turned into findings that name frames."""
from __future__ import annotations

from typing import Sequence

import numpy as np

from .outcome import Finding, format_figure

MAX_FRAMES_LISTED = 5


def runs_longer_than(mask: np.ndarray, tolerated: int) -> np.ndarray:
    """Keep only the True runs of ``mask`` longer than ``tolerated`` frames."""
    if tolerated <= 0 or not mask.any():
        return mask
    edges = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    keep = np.zeros_like(mask)
    for start, end in zip(starts[ends - starts > tolerated], ends[ends - starts > tolerated]):
        keep[start:end] = True
    return keep


def within(values: Sequence[float] | np.ndarray, *, figure: str, max: float | None = None,
           min: float | None = None, frames: Sequence[int] | None = None, unit: str = "",
           scene: int | str | None = None, keypath: tuple = (), tolerated_frames: int = 0) -> Finding | None:
    """None if every value lies in [min, max]; else a finding naming the frames
    that do not (first few, and the worst).  NaN is never within bounds.
    ``tolerated_frames``: violations lasting at most that many consecutive
    frames are allowed (a validator's duration)."""
    values = np.asarray(values, dtype=float).reshape(-1)
    frame_ids = np.arange(values.size) if frames is None else np.asarray(frames).reshape(-1)
    bad = ~np.isfinite(values)
    excess = np.zeros_like(values)
    if max is not None:
        excess = np.where(values > max, values - max, excess)
    if min is not None:
        excess = np.where(values < min, min - values, excess)
    bad |= excess > 0
    bad = runs_longer_than(bad, tolerated_frames)
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
