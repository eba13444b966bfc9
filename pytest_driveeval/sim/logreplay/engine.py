"""Batched closed-loop unroll of a planning policy through logged scenes.

Semantics are l5kit's closed loop (``ClosedLoopSimulator`` and the seed
notebook): the policy fully controls the ego, other agents replay the log
(or, with ``reactive_agents``, follow their logged paths but brake by IDM for
what is in their way: :mod:`.reactive`).
At each frame t every active scene gets the inputs of :mod:`.inputs` built
from its *driven* ego history, all of them go through ONE ``policy(batch)``
call, and the ego of each scene moves to the first predicted pose, taken from
the ego frame to the world, through a :mod:`~pytest_driveeval.sim.dynamics`
model (the pose as is, or the nearest a unicycle can reach).

Scenes of different lengths step together; a scene leaves the batch at its
end or at its first error.  Errors are recorded per scene, never raised, so a
bad row does not cost the other scenes their results:

* the policy raises, or returns no dict / a missing key / a wrong shape:
  every scene of that forward stops, the message names them and the frame;
* a row with NaN/inf: only that scene stops.

Per-frame metrics (collisions, drift, speed) are computed once at the end
over the whole (scenes, frames) table: calling the metric functions per step
would cost more than everything else in the loop.  Only the freeze rule needs
to know about a collision during the loop; it uses the same overlap test as
:func:`pytest_driveeval.metrics.collisions.detect_collisions`, on the few
agents in range.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from functools import partial
from typing import Callable, Sequence

import numpy as np
import torch

from pytest_driveeval.core.deadline import TimeLimitExceeded, guarded_call, note
from pytest_driveeval.geometry import norm2d, oriented_boxes_overlap
from pytest_driveeval.io.l5.l5kit_zarr import L5Scene
from pytest_driveeval.metrics.collisions import detect_collisions, max_or_zero
from pytest_driveeval.metrics.drift import displacement_error, distance_to_reference, speed_difference
from pytest_driveeval.sim.dynamics import KinematicLimits, PoseTarget, Unicycle
from pytest_driveeval.sim.logreplay import jit
from pytest_driveeval.sim.logreplay.agents import LogCells
from pytest_driveeval.sim.logreplay.inputs import SECONDS_SAVED_PER_ROW, build_batch
from pytest_driveeval.sim.logreplay.logarrays import EGO_EXTENT, STEP_TIME, LogArrays, stack_scenes, window_columns
from pytest_driveeval.sim.logreplay.outputs import BadPolicyOutput, first_pose, format_scenes
from pytest_driveeval.sim.logreplay.perturb import perturb_history
from pytest_driveeval.sim.logreplay.reactive import ReactiveAgents, ReactiveReplay
from pytest_driveeval.sim.state import AgentState

__all__ = ["UnrollConfig", "UnrollResult", "unroll"]


@dataclass(frozen=True)
class UnrollConfig:
    """Options of :func:`unroll`.

    ``num_steps`` counts simulated frames from ``start_frame`` (the first one
    is the logged pose), like l5kit's ``num_simulation_steps``; None runs each
    scene to its end.  ``drift_threshold`` (m): when the next pose the policy
    asks for is farther than that from the logged one, the ego is put back on
    the log for that frame and ``reset`` is flagged (the seed notebook's
    rule).  ``freeze_on_collision``: in a frame where the ego overlaps an
    agent, the ego holds its pose for the next frame.  ``kinematic``: move the
    ego as a :class:`~pytest_driveeval.sim.dynamics.Unicycle` with ``limits``
    instead of onto the requested pose (:class:`~pytest_driveeval.sim.dynamics.PoseTarget`).
    ``reactive_agents``: None, the agents replay the log; else the options of
    :mod:`.reactive` agents, which brake for what the simulation puts in their way.
    """

    start_frame: int = 0
    num_steps: int | None = None
    history_frames: int = 10
    future_frames: int = 12
    max_agents: int = 30
    agents_radius: float = 35.0
    drift_threshold: float | None = None
    freeze_on_collision: bool = False
    kinematic: bool = False
    limits: KinematicLimits = field(default_factory=KinematicLimits)
    step_time: float = STEP_TIME
    ego_extent: tuple[float, float, float] = tuple(EGO_EXTENT)
    device: str = "cpu"
    reactive_agents: ReactiveAgents | None = None


@dataclass
class UnrollResult:
    """Everything recorded by :func:`unroll`, per (scene, frame), shaped (S, T).

    Frames outside ``valid`` (before ``start_frame``, past a scene's end or
    after its error) hold zeros / -1 / NaN.  ``displacement_error`` is the
    distance from the log of the pose the policy asked for: on a ``reset``
    frame the ego was put back on the log, the value says why.  ``frozen``
    marks frames where the ego held its pose after a collision.
    ``errors[s]`` is None or why scene s stopped early; everything before is
    kept.  ``total_time - model_time`` is the harness overhead (s).
    ``agents`` is the agents' side as the loop saw it (a LogArrays): the log
    itself, or with reactive agents a copy holding where they were, and
    ``reacted`` (S, T, C) then marks the cells whose agent was off its log.
    """

    scene_ids: np.ndarray
    start_frame: int
    valid: np.ndarray
    driven_xy: np.ndarray
    driven_yaw: np.ndarray
    logged_xy: np.ndarray
    logged_yaw: np.ndarray
    collision_kind: np.ndarray  # int8: 0 none, 1 front, 2 side, 3 rear
    collision_track_id: np.ndarray
    collision_at_fault: np.ndarray
    displacement_error: np.ndarray
    distance_to_reference: np.ndarray
    speed_difference: np.ndarray
    reset: np.ndarray
    frozen: np.ndarray
    errors: list
    model_time: float = 0.0
    total_time: float = 0.0
    forwards: int = 0
    scene_steps: int = 0
    agents: LogArrays | None = None
    reacted: np.ndarray | None = None

    @property
    def harness_time(self) -> float:
        return self.total_time - self.model_time

    def scene(self, i: int) -> dict:
        """Row i of every per-frame array, cut to its valid frames (the error too)."""
        keep = self.valid[i]
        out = {f: getattr(self, f)[i][keep] for f in _PER_FRAME}
        out["frames"], out["error"] = np.flatnonzero(keep), self.errors[i]
        return out


_PER_FRAME = ("driven_xy", "driven_yaw", "logged_xy", "logged_yaw", "collision_kind", "collision_track_id",
              "collision_at_fault", "displacement_error", "distance_to_reference", "speed_difference", "reset",
              "frozen")


def _coarse_reach_squared(log: LogArrays, extent: np.ndarray) -> float:
    """Square of a range no ego-agent pair of the log exceeds (detect_collisions'
    reach with the largest agent extents), widened a little so that rounding
    cannot make it smaller than a pair's own reach."""
    agents = log.agent_extent
    if agents.size == 0:
        return 0.0
    if agents.strides[0] == 0:  # copies of one scene (a broadcast view): read it once
        agents = agents[:1]
    longest = [max_or_zero(agents[..., i]) for i in (0, 1)]
    reach = 0.5 * (float(norm2d(extent[:2])) + float(np.hypot(longest[0], longest[1])))
    reach *= 1.0 + 1e-9
    return reach * reach


def _near_pairs(log: LogArrays, rows: np.ndarray, t: int, xy: np.ndarray, coarse2: float, ego_norm: float
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The (row position, column) pairs of agents within reach of the ego at frame t,
    and the agents' (length, width): the only pairs that
    can overlap the ego.  ``xy`` (B, 2) is the ego of each of ``rows`` at t,
    ``coarse2`` a squared range no pair's reach exceeds, ``ego_norm`` the ego box's diagonal."""
    a_xy = log.agent_xy[rows, t]
    dx = a_xy[..., 0] - xy[:, 0, None]
    dy = a_xy[..., 1] - xy[:, 1, None]
    dx *= dx
    dy *= dy
    dx += dy
    near = dx < coarse2
    near &= log.available[rows, t]
    f, a = np.nonzero(near)
    # The exact range test of each pair (l5kit's, as detect_collisions and _overlapping apply it):
    # the pairs it drops can never collide, and the judge at the end gathers only those left.
    a_ext = log.agent_extent[rows[f], t, a, :2].astype(np.float64)
    reach = 0.5 * (ego_norm + norm2d(a_ext))
    close = dx[f, a] < reach * reach
    return f[close], a[close], a_ext[close]


def _overlapping(log: LogArrays, rows: np.ndarray, t: int, xy: np.ndarray, yaw: np.ndarray, extent: np.ndarray,
                 pairs: tuple[np.ndarray, np.ndarray, np.ndarray]) -> np.ndarray:
    """(B,) True where the ego box overlaps an agent at frame t (detect_collisions' criterion),
    judged on the :func:`_near_pairs` of these rows (row positions into ``rows``,
    columns, agent extents), already within range: the separating-axis test."""
    f, a, a_ext = pairs
    out = np.zeros(rows.size, dtype=bool)
    if f.size:
        r = rows[f]
        hit = oriented_boxes_overlap(xy[f], yaw[f], extent[:2], log.agent_xy[r, t, a], log.agent_yaw[r, t, a], a_ext)
        out[f[hit]] = True
    return out


def _backward_speed(xy: np.ndarray, start: int, logged: np.ndarray, dt: float) -> np.ndarray:
    """(S, T) speed from the step into each frame; frame ``start`` uses the logged step."""
    step = np.zeros_like(xy)
    step[:, 1:] = xy[:, 1:] - xy[:, :-1]
    step[:, 0] = logged[:, min(1, xy.shape[1] - 1)] - logged[:, 0]
    if 0 < start < xy.shape[1]:  # past the end no frame is valid: nothing to fix
        step[:, start] = logged[:, start] - logged[:, start - 1]
    return norm2d(step) / dt


def unroll(scenes: Sequence[L5Scene] | LogArrays, policy: Callable[[dict], object],
           config: UnrollConfig = UnrollConfig(), *, start_perturbation: np.ndarray | None = None,
           cells: LogCells | None = None, candidates: tuple[np.ndarray, np.ndarray] | None = None,
           extra_inputs: Callable[[np.ndarray, int, np.ndarray, np.ndarray, LogArrays], dict] | None = None,
           progress: Callable[[int, int], None] | None = None) -> UnrollResult:
    """Drive ``policy`` through all ``scenes`` together; see the module doc.

    ``start_perturbation`` (S, 4): each scene's start moved off the log, its
    past moved with it (:func:`~pytest_driveeval.sim.logreplay.perturb.perturb_history`);
    the log stays the reference that drift is measured against.  ``cells``:
    the log's :class:`~.agents.LogCells` when the caller has them already
    (packed once for many unrolls of the same scenes; only the numpy inputs
    read them, when numba is absent: the compiled ones read the log itself),
    and ``candidates`` its :func:`~.logarrays.window_columns` for ``config.history_frames``.
    ``extra_inputs(rows, t, driven_xy, driven_yaw, agents)``: more tensors for the
    policy's batch at frame t (e.g. the bird's-eye rasters of
    :mod:`pytest_driveeval.raster`), drawn from the ego's driven history.
    ``progress(done, total)``: called with the steps done, all scenes stepping together.
    """
    t_begin = time.perf_counter()
    log = scenes if isinstance(scenes, LogArrays) else stack_scenes(scenes)
    cfg = config
    n_scenes, n_frames = log.ego_yaw.shape
    start = cfg.start_frame
    end = log.num_frames if cfg.num_steps is None else np.minimum(log.num_frames, start + cfg.num_steps)
    ext = np.asarray(cfg.ego_extent, dtype=np.float64)
    driven_xy, driven_yaw = log.ego_xy.copy(), log.ego_yaw.copy()
    # What the ego did up to the start: the log, or the perturbed past that leads to a perturbed start.
    past_xy = log.ego_xy
    if start_perturbation is not None and start < n_frames:
        driven_xy, driven_yaw = perturb_history(driven_xy, driven_yaw, start, start_perturbation)
        past_xy = log.ego_xy.copy()
        past_xy[:, :start + 1] = driven_xy[:, :start + 1]
    proposed = np.zeros((n_scenes, n_frames))
    valid = np.zeros((n_scenes, n_frames), bool)
    reset = np.zeros((n_scenes, n_frames), bool)
    frozen = np.zeros((n_scenes, n_frames), bool)
    errors: list[str | None] = [None] * n_scenes
    alive = end > start
    for s in np.flatnonzero(~alive):
        errors[s] = (f"scene {log.scene_ids[s]}: start_frame {start} is not before its end "
                     f"({log.num_frames[s]} frames, num_steps {cfg.num_steps})")
    speed = _backward_speed(past_xy, start, past_xy, cfg.step_time)[:, min(start, n_frames - 1)]
    model_time, forwards, scene_steps = 0.0, 0, 0
    reactive = None
    if cfg.reactive_agents is not None:
        # The agents move: the loop reads and writes its own copy of their poses (and packing, if one is read).
        reactive = ReactiveReplay(log, cfg.reactive_agents, cfg.step_time)
        log, cells = reactive.sim, None
    # Numba pays for its start when the whole unroll saves more than that (see .jit).
    compiled = jit.wanted(float(np.maximum(end - start, 0).sum()) * SECONDS_SAVED_PER_ROW)
    if cells is None and not compiled:
        # The compiled inputs read the log itself; only the numpy ones read the packing.
        cells = LogCells(log)
    options = dict(history_frames=cfg.history_frames, future_frames=cfg.future_frames, max_agents=cfg.max_agents,
                   radius=cfg.agents_radius, step_time=cfg.step_time, ego_extent=ext,
                   candidates=candidates or window_columns(log, cfg.history_frames), cells=cells, compiled=compiled)
    coarse2, ego_norm = _coarse_reach_squared(log, ext), norm2d(ext[:2])
    near: list[tuple[np.ndarray, int, np.ndarray]] = []  # (rows, frame, columns) that may collide, per frame
    dynamics = Unicycle(cfg.limits) if cfg.kinematic else PoseTarget(cfg.step_time)

    last = int(end.max(initial=start))
    if progress is not None:
        progress(0, last - start)
    with torch.no_grad():
        for t in range(start, last):
            if progress is not None and t > start:
                progress(t - start, last - start)
            active = alive & (t < end)
            valid[active, t] = True
            # Which agents are near enough to touch the ego in this frame: collisions are judged on those
            # only, at the end; a pass over every agent column of the table would cost more than the loop.
            act = np.flatnonzero(active)
            pairs = _near_pairs(log, act, t, driven_xy[act, t], coarse2, ego_norm)
            pair_rows = act[pairs[0]]
            near.append((pair_rows, t, pairs[1]))
            rows = np.flatnonzero(active & (t + 1 < end))  # the last frame needs no forward
            if rows.size == 0:
                continue
            batch = build_batch(log, rows, np.full(rows.size, t), driven_xy, driven_yaw, **options)
            if extra_inputs is not None:
                batch.update(extra_inputs(rows, t, driven_xy, driven_yaw, log))
            if cfg.device != "cpu":
                batch = {k: v.to(cfg.device) for k, v in batch.items()}
            forwards += 1
            note(scenes=partial(format_scenes, log.scene_ids[rows]), frame=t, step=t - start)
            tic = time.perf_counter()
            try:
                out = guarded_call(policy, batch)
                pos, dyaw = first_pose(out, rows.size)
            except TimeLimitExceeded:
                raise
            except Exception as exc:  # a broken model must not take the harness down
                what = str(exc) if isinstance(exc, BadPolicyOutput) else f"policy raised {type(exc).__name__}: {exc}"
                msg = f"model output at frame {t} for scenes {format_scenes(log.scene_ids[rows])}: {what}"
                for s in rows:
                    errors[s] = msg
                alive[rows] = False
                continue
            finally:
                model_time += time.perf_counter() - tic
            finite = np.isfinite(pos).all(-1) & np.isfinite(dyaw)
            for s in rows[~finite]:
                errors[s] = f"scene {log.scene_ids[s]}: model returned NaN/inf in its first pose at frame {t}"
            alive[rows[~finite]] = False
            rows, pos, dyaw = rows[finite], pos[finite], dyaw[finite]
            scene_steps += rows.size

            xy, yaw = driven_xy[rows, t], driven_yaw[rows, t]
            c, s_ = np.cos(yaw), np.sin(yaw)
            target = xy + np.stack([c * pos[:, 0] - s_ * pos[:, 1], s_ * pos[:, 0] + c * pos[:, 1]], -1), yaw + dyaw
            moved = dynamics.step(AgentState(xy, yaw, speed[rows]), target)
            nxt, nyaw, speed[rows] = moved.xy, moved.yaw, moved.speed
            proposed[rows, t + 1] = norm2d(nxt - log.ego_xy[rows, t + 1])
            if cfg.drift_threshold is not None:
                back = proposed[rows, t + 1] > cfg.drift_threshold
                nxt[back], nyaw[back] = log.ego_xy[rows[back], t + 1], log.ego_yaw[rows[back], t + 1]
                reset[rows[back], t + 1] = True
                speed[rows[back]] = norm2d(log.ego_xy[rows[back], t + 1] - log.ego_xy[rows[back], t]) / cfg.step_time
            if cfg.freeze_on_collision:
                moving = np.zeros(n_scenes, bool)
                moving[rows] = True
                mine = moving[pair_rows]  # the pairs of the rows that moved
                f = np.searchsorted(rows, pair_rows[mine])
                hold = _overlapping(log, rows, t, xy, yaw, ext, (f, pairs[1][mine], pairs[2][mine]))
                nxt[hold], nyaw[hold] = xy[hold], yaw[hold]
                reset[rows[hold], t + 1] = False
                frozen[rows[hold], t + 1] = True
                speed[rows[hold]] = 0.0
            driven_xy[rows, t + 1], driven_yaw[rows, t + 1] = nxt, nyaw
            if reactive is not None:
                reactive.step(rows, t, driven_xy, driven_yaw, ext, options["cells"])

    if progress is not None and last > start:
        progress(last - start, last - start)
    result = _finish(log, cfg, driven_xy, driven_yaw, proposed, valid, reset, frozen, errors,
                     timing=(time.perf_counter() - t_begin, model_time, forwards, scene_steps), ext=ext,
                     past_xy=past_xy, near=near)
    result.agents = log
    if reactive is not None:
        result.reacted = reactive.reacted
    return result


def _finish(log, cfg, driven_xy, driven_yaw, proposed, valid, reset, frozen, errors, timing, ext,
            past_xy, near) -> UnrollResult:
    """Per-frame metrics over the whole table in one pass each."""
    t_metrics = time.perf_counter()
    start = cfg.start_frame
    dt = cfg.step_time
    ego_speed = _backward_speed(driven_xy, start, past_xy, dt)
    # Velocity for blame: the step into the frame, along the motion.
    step = np.zeros_like(driven_xy)
    step[:, 1:] = driven_xy[:, 1:] - driven_xy[:, :-1]
    first = min(start, driven_xy.shape[1] - 1)  # a start past every scene's end has no valid frame
    step[:, : first + 1] = (past_xy[:, 1:2] - past_xy[:, 0:1]) if first == 0 else \
        (past_xy[:, first:first + 1] - past_xy[:, first - 1:first])
    kind, track, fault = _judge_near(log, near, driven_xy, driven_yaw, step / dt, ext)
    disp = np.where(reset, proposed, displacement_error(driven_xy, log.ego_xy))
    frame_ok = np.arange(log.ego_yaw.shape[1]) < log.num_frames[:, None]
    to_ref = distance_to_reference(driven_xy, log.ego_xy, frame_ok)
    dspeed = speed_difference(ego_speed, _backward_speed(log.ego_xy, start, log.ego_xy, dt))
    nan = np.nan
    total, model_time, forwards, scene_steps = timing
    return UnrollResult(
        scene_ids=log.scene_ids.copy(), start_frame=start, valid=valid,
        driven_xy=driven_xy, driven_yaw=driven_yaw, logged_xy=log.ego_xy, logged_yaw=log.ego_yaw,
        collision_kind=np.where(valid, kind, 0).astype(np.int8),
        collision_track_id=np.where(valid, track, -1), collision_at_fault=valid & fault,
        displacement_error=np.where(valid, disp, nan), distance_to_reference=np.where(valid, to_ref, nan),
        speed_difference=np.where(valid, dspeed, nan), reset=reset & valid, frozen=frozen & valid,
        errors=errors, model_time=model_time, total_time=total + time.perf_counter() - t_metrics,
        forwards=forwards, scene_steps=scene_steps,
    )


def _judge_near(log: LogArrays, near: list, driven_xy: np.ndarray, driven_yaw: np.ndarray, ego_velocity: np.ndarray,
                ext: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(S, T) collision kind, partner track and blame from the near pairs the loop
    recorded: :func:`~pytest_driveeval.metrics.collisions.detect_collisions` on one
    row per frame that has any, holding only its near agents (the rest cannot
    touch the ego, and the partner is chosen by the log's row order, not by slot)."""
    shape = driven_yaw.shape
    kind = np.zeros(shape, np.int8)
    track = np.full(shape, -1, np.int64)
    fault = np.zeros(shape, bool)
    s = np.concatenate([n[0] for n in near]) if near else np.zeros(0, np.int64)
    if s.size == 0:
        return kind, track, fault
    t = np.concatenate([np.full(n[0].size, n[1], np.int64) for n in near])
    c = np.concatenate([n[2] for n in near])
    # The loop recorded frame after frame, rows ascending and columns ascending within a row,
    # so each (scene, frame) group is contiguous and in column order already.
    key = t * shape[0] + s
    first = np.ones(key.size, bool)
    first[1:] = key[1:] != key[:-1]
    frame = np.cumsum(first) - 1  # which judged frame each pair belongs to
    starts = np.flatnonzero(first)
    slot = np.arange(key.size) - starts[frame]
    fs, ft = s[starts], t[starts]
    grid = (starts.size, int(slot.max()) + 1)
    available = np.zeros(grid, bool)
    available[frame, slot] = True

    cell = (s * shape[1] + t) * log.available.shape[2] + c

    def table(x: np.ndarray, fill=0) -> np.ndarray:
        out = np.full(grid + x.shape[3:], fill, x.dtype)
        # One take at the flat cell index is several times faster than indexing with three
        # arrays; a broadcast or sliced log is indexed as it is (flattening it would copy it).
        out[frame, slot] = np.take(x.reshape((-1,) + x.shape[3:]), cell, axis=0) if x.flags.c_contiguous \
            else x[s, t, c]
        return out

    col = detect_collisions(driven_xy[fs, ft], driven_yaw[fs, ft], ext, table(log.agent_xy), table(log.agent_yaw),
                            table(log.agent_extent), available, table(log.agent_velocity), ego_velocity[fs, ft],
                            track_ids=table(log.track_id, -1), agent_order=table(log.frame_row, -1))
    kind[fs, ft], track[fs, ft], fault[fs, ft] = col.kind, col.track_id, col.at_fault
    return kind, track, fault
