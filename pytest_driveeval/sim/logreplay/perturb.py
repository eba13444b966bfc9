"""A closed-loop start moved off the log, with a past that leads there.

A policy reads the ego's recent history, so moving only the start pose would
show it a jump in the last frame.  Instead the offset (lateral and
longitudinal in the ego's frame at the start, a heading offset) is blended
in over the history frames with a smoothstep, the way a driver drifts out of
lane, and a speed scale stretches that history around the start pose so the
speed the policy infers from it is scaled too.  With every field at its
no-change value the log comes back unchanged, bit for bit.

Rows are scenes (or copies of one scene, one per example of a robustness
search), so a whole generation of perturbations unrolls as one batch.
"""
from __future__ import annotations

import numpy as np

__all__ = ["FIELDS", "perturb_history"]

#: columns of the perturbation array, in order
FIELDS = ("lateral", "longitudinal", "heading", "speed_scale")


def _smoothstep(u: np.ndarray) -> np.ndarray:
    return u * u * (3.0 - 2.0 * u)


def perturb_history(xy: np.ndarray, yaw: np.ndarray, start: int, history: int,
                    perturbation: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``xy`` (S, T, 2), ``yaw`` (S, T) with frames ``start - history .. start``
    of each row perturbed by its row of ``perturbation`` (S, 4): see :data:`FIELDS`.

    Returns new arrays; frames outside that window are the log's.
    """
    xy, yaw = np.array(xy, dtype=np.float64), np.array(yaw, dtype=np.float64)
    perturbation = np.asarray(perturbation, dtype=np.float64)
    if perturbation.shape != (xy.shape[0], len(FIELDS)):
        raise ValueError(f"perturbation must be ({xy.shape[0]}, {len(FIELDS)}) = one row of {FIELDS} per scene, "
                         f"got {perturbation.shape}")
    if not 0 <= start < xy.shape[1]:
        raise ValueError(f"start frame {start} is outside the {xy.shape[1]} frames")
    first = max(0, start - history)
    frames = np.arange(first, start + 1)
    lateral, longitudinal, heading, scale = perturbation.T
    # Stretch the past around the start pose: the steps into it scale by speed_scale.
    anchor = xy[:, start:start + 1]
    xy[:, frames] = anchor + scale[:, None, None] * (xy[:, frames] - anchor)
    weight = _smoothstep((frames - first) / max(start - first, 1)) if start > first else np.ones(1)
    c, s = np.cos(yaw[:, start]), np.sin(yaw[:, start])
    offset = np.stack([c * longitudinal - s * lateral, s * longitudinal + c * lateral], axis=-1)  # (S, 2)
    xy[:, frames] += weight[None, :, None] * offset[:, None, :]
    yaw[:, frames] += weight[None, :] * heading[:, None]
    return xy, yaw
