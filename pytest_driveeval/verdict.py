"""The verdict vocabulary every use case speaks.

Three shapes of rule cover what the use cases judge, after nuPlan's
``WithinBoundMetricBase`` / ``ViolationMetricBase``:

* :func:`within`: a per-frame figure stays inside [min, max], excursions up to
  a tolerated duration allowed (drift, speed, acceleration);
* :func:`violations`: events (frames with a collision, resets) counted
  against an allowed number;
* :class:`PassRate`: frames judged Success / Warn / Fail, and the share that
  passed against a required percentage.

Each returns a :class:`~pytest_driveeval.core.outcome.Finding` (or None) whose
message names the failing frames with :func:`listing`, so every failure
reads the same way: the first few, "... N more", and the worst.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from .core.outcome import Finding, format_figure

MAX_FRAMES_LISTED = 5


def listing(texts: Sequence[str], sep: str = ", ", limit: int = MAX_FRAMES_LISTED, total: int | None = None) -> str:
    """The first ``limit`` texts joined by ``sep``, then how many more there are.

    ``total``: how many there are in all, when only the first few texts were made."""
    total = len(texts) if total is None else total
    return sep.join(texts[:limit]) + (f"{sep}... {total - limit} more" if total > limit else "")


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
    listed = listing([f"frame {int(frame_ids[i])} ({format_figure(float(values[i]))}{unit})"
                      for i in index[:MAX_FRAMES_LISTED]], total=index.size)
    where = f"scene {scene}: " if scene is not None else ""
    message = (f"{where}{figure} should be {bound}{unit} but is not at {index.size} of {values.size} frame(s): "
               f"{listed}; worst at frame {int(frame_ids[worst])}: {format_figure(float(values[worst]))}{unit}")
    limit = max if max is not None and (min is None or values[worst] > max) else min
    return Finding(message, figure=figure, value=float(values[worst]), limit=limit,
                   frame=int(frame_ids[worst]), scene=scene, keypath=keypath)


def violations(frames: Sequence[int] | np.ndarray, allowed: int, *, what: str, figure: str,
               scene: int | str | None = None, keypath: tuple = (), first_detail: str = "") -> Finding | None:
    """None if at most ``allowed`` events happened; else a finding with their
    number and the first one's frame (``first_detail`` adds what it was)."""
    frames = [int(f) for f in frames]
    if len(frames) <= allowed:
        return None
    where = f"scene {scene}: " if scene is not None else ""
    return Finding(f"{where}{len(frames)} {what}, {allowed} allowed; first at frame {frames[0]}{first_detail}",
                   figure=figure, value=len(frames), limit=allowed, frame=frames[0], scene=scene, keypath=keypath)


@dataclass
class PassRate:
    """Frames judged one by one ("Success", "Warn" or "Fail", as driving_log_replayer
    says), and the share that passed."""

    total: int = 0
    passed: int = 0
    warned: int = 0

    def add(self, verdict: str) -> None:
        self.total += 1
        self.passed += verdict == "Success"
        self.warned += verdict == "Warn"

    @property
    def rate(self) -> float:
        """Percent of frames that passed (0 with no frame)."""
        return 100.0 * self.passed / self.total if self.total else 0.0

    def meets(self, required: float | None) -> bool:
        return required is None or self.rate >= required

    def finding(self, required: float | None, *, what: str, failing: Sequence[str], figure: str,
                keypath: tuple = (), failing_total: int | None = None) -> Finding | None:
        """None if the rate meets ``required`` (or nothing was judged); else a finding
        with the counts and the listing of ``failing`` (one text per failing frame).

        ``failing_total``: how many frames failed, when ``failing`` describes only the first few."""
        if required is None or not self.total or self.meets(required):
            return None
        return Finding(f"{what}: {self.passed} / {self.total} frame(s) passed ({self.rate:.2f}%), "
                       f"{required:g}% required; {listing(list(failing), sep='; ', total=failing_total)}",
                       figure=figure, value=self.rate, limit=required, keypath=keypath)
