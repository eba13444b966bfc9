"""``ego_is_comfortable``: six filtered signals strictly inside their bounds on every frame
(docs/nuplan_score.md §3.8).  The filters are scipy's Savitzky-Golay with nuplan-devkit's own
arguments (an even window of 8 for accelerations, 15 for jerks, 5 for yaw; :mod:`.savgol` gives
scipy's numbers), so the figures match."""
from __future__ import annotations

import numpy as np

from .inputs import ScoreInputs
from .savgol import savgol
from .term import Term

#: signal -> (lower, upper) bounds, strict (nuplan-devkit's low-level metric configs)
BOUNDS = {"ego_lon_acceleration": (-4.05, 2.40), "ego_lat_acceleration": (-4.89, 4.89),
          "ego_lon_jerk": (-4.13, 4.13), "ego_jerk": (-8.37, 8.37),
          "ego_yaw_rate": (-0.95, 0.95), "ego_yaw_acceleration": (-1.93, 1.93)}
#: the fewest frames all six filters accept (the yaw acceleration's cubic needs a window of 4)
MIN_FRAMES = 4


def _smooth(signal: np.ndarray) -> np.ndarray:
    return np.round(savgol(signal, min(8, signal.shape[-1]), 2), 8)


def _derivative(signal: np.ndarray, spacing: float, window: int, order: int, deriv: int) -> np.ndarray:
    return np.round(savgol(signal, min(window, signal.shape[-1]), order, deriv, spacing), 8)


def unwrap_phase(headings: np.ndarray) -> np.ndarray:
    """nuplan-devkit's unwrapping: whole turns removed by the rounded step over 2 pi (along the last axis)."""
    turns = np.zeros_like(headings)
    turns[..., 1:] = np.cumsum(np.round(np.diff(headings, axis=-1) / (2 * np.pi)), axis=-1)
    return headings - 2 * np.pi * turns


def signals_of(ego, times: np.ndarray) -> dict[str, np.ndarray]:
    """The six signals of ego states (metrics.nuplan_score.EgoStates) at ``times`` (T,), states of one scene
    or of several made at once ((S, T) signals, each scene's row its numbers alone)."""
    # nuplan-devkit's centre acceleration: the rear axle's plus d (w^2 + dw/dt) on the x component only
    accel = ego.acceleration
    lon = accel[..., 0] + ego.rear_axle_to_center * (ego.angular_velocity ** 2 + ego.angular_acceleration)
    lon_smooth = _smooth(lon)
    heading = unwrap_phase(ego.center[..., 2])
    spacing = float(np.mean(np.diff(times)))
    return {"ego_lon_acceleration": lon_smooth,
            "ego_lat_acceleration": _smooth(accel[..., 1]),
            "ego_lon_jerk": _derivative(lon_smooth, spacing, 15, 2, 1),
            "ego_jerk": _derivative(_smooth(np.hypot(accel[..., 0], accel[..., 1])), spacing, 15, 2, 1),
            "ego_yaw_rate": _derivative(heading, spacing, 5, 2, 1),
            "ego_yaw_acceleration": _derivative(heading, spacing, 5, 3, 2)}


def comfort_signals(inputs: ScoreInputs) -> dict[str, np.ndarray]:
    """The scene's six signals, as made with its ego states where they were made for several scenes."""
    if inputs.ego.comfort is not None:
        return inputs.ego.comfort
    return signals_of(inputs.ego, inputs.times)


def ego_is_comfortable(inputs: ScoreInputs) -> Term:
    name = "ego_is_comfortable"
    if inputs.num_frames < MIN_FRAMES:
        return Term.not_available(name, f"{inputs.num_frames} frame(s); the comfort filters need {MIN_FRAMES}")
    if np.any(np.diff(inputs.times) <= 0):
        return Term.not_available(name, "the frames' times do not increase")
    signals = comfort_signals(inputs)
    names = list(signals)
    values = np.stack([signals[n] for n in names])  # (6, T): each test once over all six
    lows, highs = np.array([[BOUNDS[n][0]] for n in names]), np.array([[BOUNDS[n][1]] for n in names])
    lowest, highest = values.min(axis=1).tolist(), values.max(axis=1).tolist()
    outside = ~((values > lows) & (values < highs))
    detail, failing = {}, []
    for i, signal in enumerate(names):
        detail[f"{signal}_min"], detail[f"{signal}_max"] = lowest[i], highest[i]
    for i in np.flatnonzero(outside.any(axis=1)).tolist():
        k = int(np.argmax(outside[i]))
        lo, hi = BOUNDS[names[i]]
        failing.append(f"{names[i]} {values[i, k]:.2f} at frame {int(inputs.frame_numbers[k])} (bounds {lo:g}, {hi:g})")
    bad = outside.any(axis=0)
    term = Term(name, 0.0 if failing else 1.0, detail=detail, series=signals)
    if failing:
        term.frames = np.flatnonzero(bad).tolist()
        term.message = "; ".join(failing)
    return term
