"""Policy inputs in the layout of l5kit's planning datasets, built for many rows at once.

A row is one (scene, frame) pair.  Keys, shapes and frames follow l5kit's
``generate_agent_sample`` / ``generate_agent_sample_vectorized`` (ego as the
agent of interest), all expressed in the ego frame of the current step::

    history_positions (H+1, 2)  history_yaws (H+1, 1)  history_availabilities (H+1,)
        index 0 is the current frame, index k is k frames back (l5kit order)
    target_positions (F, 2)  target_yaws (F, 1)  target_availabilities (F,)
        the LOGGED future, frames t+1 .. t+F
    centroid (2,)  yaw ()  extent (3,)  speed ()  world_from_agent (3, 3)  agent_from_world (3, 3)
    all_other_agents_history_positions (N, H+1, 2)  ..._yaws (N, H+1, 1)
    all_other_agents_history_extents (N, H+1, 2)  ..._availability (N, H+1)  all_other_agents_types (N,)

Every value is a float32 tensor with a leading batch axis B.  Unavailable
slots are zero, as l5kit leaves them.

Where we differ from l5kit, on purpose:

* ``speed`` is the backward difference ``|p_t - p_(t-1)| / dt`` of the ego
  history.  l5kit's vectorised sample uses the *next logged* position, which
  in closed loop leaks the human's future into the input.
* The other agents are chosen deterministically (:mod:`.agents`): agents
  seen at frame t within ``radius`` by distance, then agents seen only in the
  history window by their closest approach (l5kit takes the same two groups
  but orders them through a Python set).  The label filter keeps l5kit's agent classes, judged on each
  track's most frequent label rather than per-row probabilities.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np
import torch

from pytest_driveeval.io.l5.l5kit_zarr import L5Scene
from pytest_driveeval.sim.logreplay import jit
from pytest_driveeval.sim.logreplay.agents import LogCells, agent_histories
from pytest_driveeval.sim.logreplay.logarrays import EGO_EXTENT, STEP_TIME, LogArrays, stack_scenes, window_columns

__all__ = ["build_batch", "collate_training_samples"]

_TWO_PI = 2.0 * np.pi
# What the compiled agent inputs save per row over the numpy ones (64 copies of the real scene).
SECONDS_SAVED_PER_ROW = 25e-6


def _wrap_masked(angle: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """``float32(wrap_angle(angle) * mask)`` bit for bit; ``angle`` (float64) is overwritten.

    ``wrap_angle`` is ``(a + pi) % 2pi - pi``.  With y = a + pi in [-2pi, 4pi)
    numpy's float modulo is a single exact step: fmod is exact, so it gives y
    for y in [0, 2pi), the rounded y + 2pi below (Python's sign rule), and
    y - 2pi above, which is exact there (Sterbenz).  Those two adds replace
    the slow modulo; any value farther out takes the modulo itself.
    """
    angle += np.pi
    low = angle < 0.0
    high = angle >= _TWO_PI
    if low.any() or high.any():
        far = (angle < -_TWO_PI) | (angle >= 2.0 * _TWO_PI)
        if far.any():
            low &= ~far
            high &= ~far
            angle[far] %= _TWO_PI
        np.add(angle, _TWO_PI, out=angle, where=low)
        np.subtract(angle, _TWO_PI, out=angle, where=high)
    angle -= np.pi
    return np.multiply(angle, mask, out=np.empty(angle.shape, np.float32), casting="unsafe")


def _planes_to_ego(x: np.ndarray, y: np.ndarray, origin: np.ndarray, cos: np.ndarray, sin: np.ndarray,
                   mask: np.ndarray) -> np.ndarray:
    """World points, given as x/y planes (B, ...), into each row's ego frame, times
    ``mask``, as float32; origin/cos/sin are (B,).  Each value is rounded
    once, so it does not depend on the path taken."""
    shape = (-1,) + (1,) * (x.ndim - 1)
    dx = x - origin[:, 0].reshape(shape)
    dy = y - origin[:, 1].reshape(shape)
    c, s = cos.reshape(shape), sin.reshape(shape)
    out = np.empty(x.shape + (2,), np.float32)
    u = c * dx
    u += s * dy
    u *= mask
    out[..., 0] = u
    dy *= c
    dx *= s
    dy -= dx
    dy *= mask
    out[..., 1] = dy
    return out


def build_batch(log: LogArrays, rows: np.ndarray, frames: np.ndarray, ego_xy: np.ndarray, ego_yaw: np.ndarray, *,
                history_frames: int = 10, future_frames: int = 12, max_agents: int = 30, radius: float = 35.0,
                step_time: float = STEP_TIME, ego_extent: np.ndarray = EGO_EXTENT,
                candidates: tuple[np.ndarray, np.ndarray] | None = None,
                cells: LogCells | None = None, compiled: bool | None = None) -> dict[str, torch.Tensor]:
    """Inputs for rows ``(rows[b], frames[b])`` with the ego poses taken from ``ego_xy``/``ego_yaw``.

    ``ego_xy`` (S, T, 2) / ``ego_yaw`` (S, T) are the poses the ego actually
    had: the driven ones in closed loop, the logged ones for training.  The
    targets always come from the log.  ``candidates`` is
    ``window_columns(log, history_frames)``, computed here when not given.
    ``cells`` (``LogCells(log)``) only saves work on repeated calls of the numpy
    path.  ``compiled``: take the agents from :mod:`.agents_jit` (numba), which
    reads the log itself; None decides by :func:`.jit.wanted` for this call's
    rows.  Both paths give the same tensors.

    Every value is computed with the same float64 operations and rounded to
    float32 once, so the tensors do not depend on the path taken.
    """
    rows, frames = np.asarray(rows, np.int64), np.asarray(frames, np.int64)
    b = rows.size
    hist = frames[:, None] - np.arange(history_frames + 1)
    hist_ok = hist >= 0
    np.maximum(hist, 0, out=hist)
    r2 = rows[:, None]
    centre, yaw = ego_xy[rows, frames], ego_yaw[rows, frames]
    cos, sin = np.cos(yaw), np.sin(yaw)
    f32 = np.float32

    # Frame 0 has no past: fall back to the logged step out of it.
    step = np.where((frames == 0)[:, None], log.ego_xy[rows, min(1, log.ego_xy.shape[1] - 1)] - log.ego_xy[rows, 0],
                    centre - ego_xy[rows, np.maximum(frames - 1, 0)])
    speed = np.sqrt((step ** 2).sum(-1)) / step_time

    fut = frames[:, None] + 1 + np.arange(future_frames)
    fut_ok = fut < log.num_frames[rows][:, None]
    np.minimum(fut, log.ego_xy.shape[1] - 1, out=fut)
    # Driven history and logged future together: (B, H+1+F) poses, one transform.
    n_hist = history_frames + 1
    e_xy = np.concatenate([ego_xy[r2, hist], log.ego_xy[r2, fut]], axis=1)
    e_yaw = np.concatenate([ego_yaw[r2, hist], log.ego_yaw[r2, fut]], axis=1)
    e_ok = np.concatenate([hist_ok, fut_ok], axis=1)
    e_pos = _planes_to_ego(e_xy[..., 0], e_xy[..., 1], centre, cos, sin, e_ok)
    e_yaw -= yaw[:, None]
    e_yaw = _wrap_masked(e_yaw, e_ok)
    h_pos, t_pos = e_pos[:, :n_hist], e_pos[:, n_hist:]
    h_yaw, t_yaw = e_yaw[:, :n_hist], e_yaw[:, n_hist:]

    if candidates is None:
        candidates = window_columns(log, history_frames)
    if compiled is None:
        compiled = jit.wanted(b * SECONDS_SAVED_PER_ROW)
    if compiled and jit.AVAILABLE:
        a_pos, a_yaw, a_ext, a_ok, a_type = _agents_compiled(log, rows, frames, centre, yaw, cos, sin, max_agents,
                                                             radius, n_hist, candidates)
    else:
        a_pos, a_yaw, a_ext, a_ok, a_type = _agents_numpy(log, rows, hist, hist_ok, centre, yaw, cos, sin, max_agents,
                                                          radius, candidates, cells)

    out = {
        "history_positions": h_pos, "history_yaws": h_yaw[..., None], "history_availabilities": hist_ok,
        "target_positions": t_pos, "target_yaws": t_yaw[..., None], "target_availabilities": fut_ok,
        "centroid": centre, "yaw": yaw, "extent": np.broadcast_to(ego_extent, (b, 3)), "speed": speed,
        "world_from_agent": _world_from_agent32(centre, cos, sin),
        "agent_from_world": _agent_from_world32(centre, cos, sin),
        "all_other_agents_history_positions": a_pos, "all_other_agents_history_yaws": a_yaw,
        "all_other_agents_history_extents": a_ext, "all_other_agents_history_availability": a_ok,
        "all_other_agents_types": a_type,
    }
    return {k: torch.from_numpy(np.ascontiguousarray(v, dtype=f32)) for k, v in out.items()}


def _agents_compiled(log, rows, frames, centre, yaw, cos, sin, max_agents, radius, n_hist, candidates):
    """The other agents' inputs from :func:`.agents_jit.agent_inputs`, already float32."""
    from pytest_driveeval.sim.logreplay import agents_jit  # imports numba: only when it is used
    b = rows.size
    pos = np.empty((b, max_agents, n_hist, 2), np.float32)
    yaws = np.empty((b, max_agents, n_hist, 1), np.float32)
    ext = np.empty((b, max_agents, n_hist, 2), np.float32)
    ok = np.empty((b, max_agents, n_hist), np.float32)
    types = np.empty((b, max_agents), np.float32)
    agents_jit.agent_inputs(log.agent_xy, log.agent_yaw, log.agent_extent, log.track_id, log.relevant, log.available,
                            log.label, candidates[0], candidates[1], rows, frames, centre, yaw, cos, sin,
                            int(max_agents), float(radius), pos, yaws[..., 0], ext, ok, types)
    return pos, yaws, ext, ok, types


def _agents_numpy(log, rows, hist, hist_ok, centre, yaw, cos, sin, max_agents, radius, candidates, cells):
    """The other agents' inputs by numpy gathers over the log (or its ``cells``)."""
    a_ok, ax, ay, a_yaw, a_len, a_wid, a_label = agent_histories(log, rows, hist, hist_ok, centre, max_agents, radius,
                                                                 candidates, cells)
    a_pos = _planes_to_ego(ax, ay, centre, cos, sin, a_ok)
    a_yaw = _wrap_masked(a_yaw - yaw[:, None, None], a_ok)
    a_ext = np.empty(a_ok.shape + (2,), np.float32)  # extent * availability, in the log's precision (float32)
    np.multiply(a_len, a_ok, out=a_ext[..., 0], dtype=a_len.dtype, casting="unsafe")
    np.multiply(a_wid, a_ok, out=a_ext[..., 1], dtype=a_wid.dtype, casting="unsafe")
    a_type = (a_label * a_ok).max(axis=-1)  # constant per track; zero for unused slots
    return a_pos, a_yaw[..., None], a_ext, a_ok, a_type


def _world_from_agent32(centre: np.ndarray, cos: np.ndarray, sin: np.ndarray) -> np.ndarray:
    """``world_from_agent(centre, yaw)`` as float32, from the yaw's cos/sin."""
    out = np.zeros((centre.shape[0], 3, 3), np.float32)
    out[:, 0, 0] = cos
    out[:, 0, 1] = -sin
    out[:, 1, 0] = sin
    out[:, 1, 1] = cos
    out[:, :2, 2] = centre
    out[:, 2, 2] = 1.0
    return out


def _agent_from_world32(centre: np.ndarray, cos: np.ndarray, sin: np.ndarray) -> np.ndarray:
    """``agent_from_world(centre, yaw)`` as float32: R^T and -R^T t, with the
    same einsum as the geometry function on the same float64 R^T."""
    rt = np.empty((centre.shape[0], 2, 2))
    rt[:, 0, 0] = cos
    rt[:, 0, 1] = sin
    rt[:, 1, 0] = -sin
    rt[:, 1, 1] = cos
    out = np.zeros((centre.shape[0], 3, 3), np.float32)
    out[:, :2, :2] = rt
    out[:, :2, 2] = -np.einsum("...ij,...j->...i", rt, centre)
    out[:, 2, 2] = 1.0
    return out


def collate_training_samples(scene: L5Scene | LogArrays, frames: Sequence[int] | np.ndarray, *, row: int = 0,
                             **options) -> dict[str, torch.Tensor]:
    """Open-loop samples of one scene at ``frames``: history and future both from the log.

    Same keys and conventions as the closed-loop input (``options`` as in
    :func:`build_batch`), so a model trained on these sees identical features
    at evaluation time.
    """
    log = scene if isinstance(scene, LogArrays) else stack_scenes([scene])
    frames = np.asarray(frames, dtype=np.int64).reshape(-1)
    n = int(log.num_frames[row])
    bad = frames[(frames < 0) | (frames >= n)]
    if bad.size:
        raise IndexError(f"scene {int(log.scene_ids[row])}: frame {int(bad[0])} outside [0, {n})")
    return build_batch(log, np.full(frames.size, row), frames, log.ego_xy, log.ego_yaw, **options)
