"""A closed-loop start moved off the log, with a past that leads there, and agents sped up or slowed down.

A policy reads the ego's recent history, so moving only the start pose would
show it a jump, and a jump no car can make.  Instead the whole past up to
the start is moved rigidly: rotated by the heading offset about the start
pose, shifted by the lateral and longitudinal offset (in the ego's frame at
the start) and stretched about the start pose by the speed scale.  A rigid
motion keeps every speed, acceleration and curvature of the logged past,
and the stretch scales speeds and accelerations by the same factor and
leaves curvature alone, so the perturbed past is as feasible for the car as
the logged one was (what l5kit's Ackermann perturbation sets out to keep),
and it arrives at the perturbed start with a heading that matches its path.

The other agents' speed scale replays them faster or slower: an agent is at
frame ``t`` where the log had it at ``start + (t - start) * scale``,
interpolated between logged frames, on both sides of the start.

Rows are scenes (or copies of one scene, one per example of a robustness
search), so a whole generation of perturbations unrolls as one batch.  With
every field at its no-change value the log comes back unchanged, bit for bit.
"""
from __future__ import annotations

import numpy as np

from pytest_driveeval.sim.logreplay.logarrays import LogArrays

__all__ = ["FIELDS", "perturb_history", "scale_agent_time"]

#: columns of the ego's perturbation array, in order
FIELDS = ("lateral", "longitudinal", "heading", "speed_scale")


def perturb_history(xy: np.ndarray, yaw: np.ndarray, start: int, perturbation: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray]:
    """``xy`` (S, T, 2), ``yaw`` (S, T) with frames ``0 .. start`` of each row
    moved by its row of ``perturbation`` (S, 4): see :data:`FIELDS`.

    Returns new arrays; frames after ``start`` are the log's.
    """
    xy, yaw = np.array(xy, dtype=np.float64), np.array(yaw, dtype=np.float64)
    perturbation = np.asarray(perturbation, dtype=np.float64)
    if perturbation.shape != (xy.shape[0], len(FIELDS)):
        raise ValueError(f"perturbation must be ({xy.shape[0]}, {len(FIELDS)}) = one row of {FIELDS} per scene, "
                         f"got {perturbation.shape}")
    if not 0 <= start < xy.shape[1]:
        raise ValueError(f"start frame {start} is outside the {xy.shape[1]} frames")
    changed = np.flatnonzero((perturbation != [0.0, 0.0, 0.0, 1.0]).any(axis=1))
    if changed.size == 0:
        return xy, yaw
    lateral, longitudinal, heading, scale = perturbation[changed].T
    past = xy[changed, :start + 1]
    anchor = past[:, -1:]
    c, s = np.cos(heading)[:, None], np.sin(heading)[:, None]
    d = scale[:, None, None] * (past - anchor)
    turned = np.stack([c * d[..., 0] - s * d[..., 1], s * d[..., 0] + c * d[..., 1]], axis=-1)
    cy, sy = np.cos(yaw[changed, start]), np.sin(yaw[changed, start])
    offset = np.stack([cy * longitudinal - sy * lateral, sy * longitudinal + cy * lateral], axis=-1)
    xy[changed, :start + 1] = anchor + offset[:, None, :] + turned
    yaw[changed, :start + 1] += heading[:, None]
    return xy, yaw


def scale_agent_time(log: LogArrays, start: int, scale: np.ndarray) -> LogArrays:
    """``log`` with row s's agents replayed ``scale[s]`` times as fast, about frame ``start``.

    A cell holds the track the log had there at the earlier of the two
    logged frames it falls between; its pose is interpolated when that track
    is in both, else it is the earlier frame's (a track's last frame holds).
    Velocities scale too.  Cells whose logged time is past the scene's end
    are empty.
    """
    scale = np.asarray(scale, dtype=np.float64)
    if scale.shape != (log.ego_xy.shape[0],):
        raise ValueError(f"scale must be one factor per row ({log.ego_xy.shape[0]}), got {scale.shape}")
    if np.any(scale <= 0) or not np.all(np.isfinite(scale)):
        raise ValueError(f"agent speed scales must be finite and > 0, got {scale[~(scale > 0)][:3].tolist()}")
    rows = np.flatnonzero(scale != 1.0)
    if rows.size == 0:
        return log
    out = LogArrays(*(getattr(log, f).copy() for f in log.__dataclass_fields__))
    n_frames = log.ego_yaw.shape[1]
    t = np.arange(n_frames)
    for r in rows:
        when = start + (t - start) * scale[r]
        inside = (when >= 0) & (when <= log.num_frames[r] - 1)
        lo = np.clip(np.floor(when).astype(np.int64), 0, n_frames - 1)
        hi = np.clip(lo + 1, 0, n_frames - 1)
        w = (when - lo)[:, None]
        same = (log.track_id[r, hi] == log.track_id[r, lo]) & log.available[r, hi]
        w_agents = np.where(same, w, 0.0)
        a_xy = log.agent_xy[r, lo] + w_agents[..., None] * (log.agent_xy[r, hi] - log.agent_xy[r, lo])
        dyaw = np.angle(np.exp(1j * (log.agent_yaw[r, hi].astype(np.float64) - log.agent_yaw[r, lo])))
        a_yaw = (log.agent_yaw[r, lo] + w_agents * dyaw).astype(np.float32)
        keep = inside[:, None] & log.available[r, lo]
        for name, value in (("agent_xy", a_xy), ("agent_yaw", a_yaw), ("agent_extent", log.agent_extent[r, lo]),
                            ("agent_velocity", log.agent_velocity[r, lo] * np.float32(scale[r])),
                            ("track_id", log.track_id[r, lo]), ("label", log.label[r, lo]),
                            ("frame_row", log.frame_row[r, lo])):
            target = getattr(out, name)
            empty = -1 if name in ("track_id", "frame_row") else 0
            mask = keep.reshape(keep.shape + (1,) * (value.ndim - keep.ndim))
            target[r] = np.where(mask, value, empty).astype(target.dtype)
        out.available[r] = keep
        out.relevant[r] = keep & log.relevant[r, lo]
    return out
