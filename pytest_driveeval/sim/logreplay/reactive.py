"""Reactive agents: logged vehicles that brake for what the simulation puts in their way.

Log replay is non-reactive: a logged driver behind the ego cannot see our
simulated ego brake, so it drives into it.  In reactive mode each logged
vehicle follows its logged path (the polyline of its logged centroids,
measured by arc length) with its logged speed profile as IDM's desired
behaviour, and brakes by IDM (the policy benchmark's own
:func:`~pytest_driveeval.sim.agents.idm_free`,
:func:`~pytest_driveeval.sim.agents.idm_interaction` and
:func:`~pytest_driveeval.sim.agents.idm_advance`) for what is in its way.

* **In its way**: the ego or another agent whose centre projects ahead of the
  agent on its path (the next ``lookahead_frames`` logged frames, and a
  straight line along its last logged heading where its track ends sooner)
  and whose box comes within ``corridor`` metres of the path sideways.  The
  gap is bumper to bumper along the path; the leader's speed is its velocity
  along the path.
* **On its log** an agent is exactly where the log has it (pose, yaw,
  velocity, bit for bit).  It leaves the log at a frame where something in its
  way is closer than IDM's desired gap (the interaction term is above 1) *and*
  asks for harder braking than the same thing did in the log (by more than
  :data:`TOLERANCE`): a log that already kept a tight gap to the logged ego
  is not second-guessed, only what the simulation changed is reacted to.
  With the ego on its log and nothing else off its log, nothing reacts.
* **Off its log** it drives by IDM along its path: desired speed the logged
  speed of the current frame (at least ``creep_speed``, so an agent held up
  behind its stopped log closes up to it at walking pace instead of waiting
  for a stop that happened ahead of it), interaction with everything in its
  way.  It never passes its logged position: when it reaches it, it is back
  on its log (the log's pose and speed) from that frame on.  It may lag behind
  its log for the rest of its track; when the log's track ends (or has a
  hole), the agent disappears there, wherever it is, as the logged agent does:
  agents exist in exactly the frames the log has them, and agents that appear
  later in the log appear as logged.
* **Who reacts**: vehicles (:data:`VEHICLE_LABELS`, judged on each track's
  most frequent label).  Pedestrians, cyclists, animals and unknown objects
  replay the log: a lane-following IDM describes neither how they move nor
  how they give way.  They still count as obstacles for the vehicles.

All agents move together from the snapshot of frame t (ego included), as the
policy benchmark's traffic does; the ego's move is the policy's, made from the
same snapshot.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from pytest_driveeval.geometry import norm2d as norm
from pytest_driveeval.io.l5.l5kit_zarr import label_index
from pytest_driveeval.sim.agents import TrafficModel, idm_advance, idm_free, idm_interaction
from pytest_driveeval.sim.logreplay.agents import LogCells
from pytest_driveeval.sim.logreplay.logarrays import LogArrays

__all__ = ["TOLERANCE", "VEHICLE_LABELS", "ReactiveAgents", "ReactiveReplay"]

VEHICLE_LABELS = ("CAR", "VAN", "TRAM", "BUS", "TRUCK", "EMERGENCY_VEHICLE", "OTHER_VEHICLE", "MOTORCYCLE",
                  "MOTORCYCLIST")
#: how much more IDM interaction (in units of the comfortable acceleration) than in the log makes an agent react:
#: the ego replaying its log reproduces it only to float32 precision, which must not count as a change
TOLERANCE = 0.01
# Off its log an agent ignores what is more than this many times its desired gap away (see ReactiveReplay.step).
_FAR = 4.0
# How far (m) the path goes on straight past the end of a track, so an agent near its track's end still sees the
# ego ahead of it.
_EXTENSION = 60.0


@dataclass(frozen=True)
class ReactiveAgents:
    """Options of reactive agents (module doc): the IDM constants (``idm``:
    the policy benchmark's defaults), the half-width of the corridor along an
    agent's path (m), how many logged frames ahead its path is looked along,
    the least desired speed off the log (m/s), and which labels react."""

    idm: TrafficModel = field(default_factory=TrafficModel)
    corridor: float = 1.75
    lookahead_frames: int = 60
    creep_speed: float = 1.0
    labels: tuple[str, ...] = VEHICLE_LABELS

    def __post_init__(self):
        if not self.corridor > 0 or not np.isfinite(self.corridor):
            raise ValueError(f"corridor must be a finite number > 0, got {self.corridor!r}")
        if int(self.lookahead_frames) != self.lookahead_frames or self.lookahead_frames < 1:
            raise ValueError(f"lookahead_frames must be a whole number >= 1, got {self.lookahead_frames!r}")
        if not self.creep_speed > 0 or not np.isfinite(self.creep_speed):
            raise ValueError(f"creep_speed must be a finite number > 0, got {self.creep_speed!r}")
        for name in self.labels:
            label_index(name)  # an unknown name fails here, listing the known ones


def _runs(log: LogArrays) -> tuple[np.ndarray, np.ndarray]:
    """(S, T, C) run number of each available cell (-1 elsewhere) and its arc length
    along its run (inf elsewhere).  A run is a stretch of consecutive frames
    of one track in one column: a track with a hole is two runs."""
    avail = np.asarray(log.available)
    cont = np.zeros(avail.shape, bool)
    cont[:, 1:] = avail[:, 1:] & avail[:, :-1] & (log.track_id[:, 1:] == log.track_id[:, :-1])
    start = avail & ~cont
    run = np.cumsum(start, axis=1, dtype=np.int32)
    run[~avail] = -1
    step = np.zeros(avail.shape)
    d = np.diff(log.agent_xy, axis=1)
    step[:, 1:] = np.hypot(d[..., 0], d[..., 1])
    step[~cont] = 0.0
    total = np.cumsum(step, axis=1)
    # total never decreases, so the latest run start's total is the running maximum of the starts' totals
    arc = total - np.maximum.accumulate(np.where(start, total, 0.0), axis=1)
    arc[~avail] = np.inf
    return run, arc


class ReactiveReplay:
    """The agents of one unroll in reactive mode: ``sim`` is the log with its own,
    writable copies of the agents' poses, yaws and velocities, which
    :meth:`step` moves; every other field is the log's own array.  ``reacted``
    (S, T, C) marks the cells whose agent was off its log."""

    def __init__(self, log: LogArrays, spec: ReactiveAgents, step_time: float):
        self.log, self.spec, self.dt = log, spec, float(step_time)
        self.sim = dataclasses.replace(log, agent_xy=np.array(log.agent_xy), agent_yaw=np.array(log.agent_yaw),
                                       agent_velocity=np.array(log.agent_velocity))
        self.run, self.arc = _runs(log)
        self.reacts = np.isin(log.label, [label_index(n) for n in spec.labels]) & log.available
        n_rows, _, n_cols = log.available.shape
        self.off = np.zeros((n_rows, n_cols), bool)  # off its log now
        self.frame = np.zeros((n_rows, n_cols), np.int64)  # last logged frame at or behind it (off the log)
        self.s = np.zeros((n_rows, n_cols))  # arc length along its run (off the log)
        self.v = np.zeros((n_rows, n_cols))  # speed (off the log)
        self.reacted = np.zeros(log.available.shape, bool)

    def step(self, rows: np.ndarray, t: int, ego_xy: np.ndarray, ego_yaw: np.ndarray, ego_extent: np.ndarray,
             cells: LogCells | None) -> None:
        """Move the agents of ``rows`` from frame t to t+1 in ``sim`` (and ``cells``, the packing
        the numpy inputs read; None when the compiled inputs read ``sim`` itself).

        ``ego_xy`` (S, T, 2) / ``ego_yaw`` (S, T): the driven ego, known up to t."""
        log, sim, model = self.log, self.sim, self.spec.idm
        if rows.size == 0 or t + 1 >= log.available.shape[1]:
            return
        run_now = self.run[rows, t]
        cont = (run_now >= 0) & (self.run[rows, t + 1] == run_now)  # the same run goes on at t+1
        off = self.off[rows] & cont
        self.off[rows] = off  # an agent whose run ends leaves with it; if it comes back, it is on its log
        reacts = self.reacts[rows, t] & cont

        ego_now = ego_xy[rows, t]
        ego_vel = self._velocity(ego_xy, rows, t)
        a_xy = sim.agent_xy[rows, t]
        # Every agent's speed now: its state off the log, the log's step into t on it.
        arc_now = self.arc[rows, t]
        with np.errstate(invalid="ignore"):  # inf - inf where a run does not go on; those are masked
            fwd_speed = (self.arc[rows, t + 1] - arc_now) / self.dt
            back_speed = fwd_speed if t == 0 else np.where(
                self.run[rows, t - 1] == run_now, (arc_now - self.arc[rows, t - 1]) / self.dt, fwd_speed)
        speed = np.where(off, self.v[rows], back_speed)
        extent = log.agent_extent[rows, t].astype(np.float64)
        half, diag = 0.5 * extent[..., 0], np.hypot(extent[..., 0], extent[..., 1])
        obstacle_speed = np.hypot(*np.moveaxis(sim.agent_velocity[rows, t].astype(np.float64), -1, 0))

        # Pairs farther apart than IDM's desired gap cannot make an agent leave its log (the
        # interaction is below 1), and off its log those beyond _FAR times it brake it by less than
        # a / _FAR^2: both are left out, which saves most of the work.  The gap along the path is at
        # least the centres' distance less the corridor, the obstacle's diagonal and the follower's
        # half length; the desired gap is at most s0 + v T + v (v + |v_lead|) / 2 sqrt(ab).
        def beyond(distance, v, v_lead, obstacle_diag, follower_half, factor):
            wanted = model.min_gap + v * (model.time_headway + (v + v_lead) / (2.0 * np.sqrt(
                model.max_accel * model.comfort_decel)))
            return distance - self.spec.corridor - obstacle_diag - follower_half > factor * wanted

        rel = ego_now[:, None, :] - a_xy
        yaw = sim.agent_yaw[rows, t].astype(np.float64)
        ahead = rel[..., 0] * np.cos(yaw) + rel[..., 1] * np.sin(yaw) > 0.0
        with np.errstate(invalid="ignore"):
            far = beyond(np.hypot(rel[..., 0], rel[..., 1]), speed, norm(ego_vel)[:, None],
                         float(np.hypot(*ego_extent[:2])), half, np.where(off, _FAR, 1.0))
        ego_pair = reacts & ahead & ~far
        candidate = reacts & (off | ego_pair)

        # Agent-agent pairs: an agent off its log meets everything; one on it only the agents off theirs
        # (the others are where the log has them, and the log did not collide with them).
        ob, oc = np.nonzero(off)
        pair_b = pair_i = pair_j = np.zeros(0, np.int64)
        if ob.size:
            d = a_xy[ob] - a_xy[ob, oc][:, None, :]  # (off agents, every column)
            distance = np.hypot(d[..., 0], d[..., 1])
            others = np.arange(off.shape[1]) != oc[:, None]
            with np.errstate(invalid="ignore"):
                follows = others & sim.available[rows[ob], t] & ~beyond(
                    distance, speed[ob, oc][:, None], obstacle_speed[ob], diag[ob], half[ob, oc][:, None], _FAR)
                followed = others & reacts[ob] & ~off[ob] & ~beyond(
                    distance, speed[ob], obstacle_speed[ob, oc][:, None], diag[ob, oc][:, None], half[ob], 1.0)
            n1, j1 = np.nonzero(follows)  # off agent oc[n1] behind column j1
            n2, i2 = np.nonzero(followed)  # column i2 behind off agent oc[n2]
            pair_b = np.concatenate([ob[n1], ob[n2]])
            pair_i = np.concatenate([oc[n1], i2])
            pair_j = np.concatenate([j1, oc[n2]])
            candidate[ob[n2], i2] = True
        cb, cc = np.nonzero(candidate)  # the candidates: row position, column
        if cb.size == 0:
            return
        index = np.full(off.shape, -1, np.int64)
        index[cb, cc] = np.arange(cb.size)
        ego_b, ego_c = np.nonzero(ego_pair)
        n_ego = ego_b.size
        which = np.concatenate([index[ego_b, ego_c], index[pair_b, pair_i]])
        r, c = rows[cb], cc

        on = ~off[cb, cc]
        k0 = np.where(on, t, self.frame[r, c])
        s_now = np.where(on, arc_now[cb, cc], self.s[r, c])
        v_now = speed[cb, cc]
        fwd_speed = fwd_speed[cb, cc]
        wx, wy, ws = self._window(r, c, run_now[cb, cc], k0)

        # Obstacles of each pair, as simulated and as logged.
        pa = which  # candidate of each pair
        obs_b = np.concatenate([ego_b, pair_b]).astype(np.int64)
        j = np.concatenate([np.full(n_ego, -1), pair_j]).astype(np.int64)
        is_ego = j < 0
        jr, jc = rows[obs_b], np.maximum(j, 0)
        ext = log.agent_extent[jr, t, jc, :2].astype(np.float64)
        ext[is_ego] = ego_extent[:2]
        sim_pose = (np.where(is_ego[:, None], ego_now[obs_b], sim.agent_xy[jr, t, jc]),
                    np.where(is_ego, ego_yaw[rows[obs_b], t], sim.agent_yaw[jr, t, jc]),
                    np.where(is_ego[:, None], ego_vel[obs_b], sim.agent_velocity[jr, t, jc]))
        log_ego = log.ego_xy[rows[obs_b], t]
        log_pose = (np.where(is_ego[:, None], log_ego, log.agent_xy[jr, t, jc]),
                    np.where(is_ego, log.ego_yaw[rows[obs_b], t], log.agent_yaw[jr, t, jc]),
                    np.where(is_ego[:, None], self._velocity(log.ego_xy, rows, t)[obs_b],
                             log.agent_velocity[jr, t, jc]))
        half = half[cb, cc]
        inter = self._interaction(wx[pa], wy[pa], ws[pa], s_now[pa], half[pa], v_now[pa], sim_pose, ext)
        strongest = np.zeros(cb.size)
        np.maximum.at(strongest, pa, inter)
        # Leave the log where the simulation asks for more braking than the log did (module doc).
        trigger = np.zeros(cb.size, bool)
        ask = on[pa] & (inter > 1.0)
        if ask.any():
            q = pa[ask]
            logged = self._interaction(wx[q], wy[q], ws[q], s_now[q], half[q], v_now[q],
                                       tuple(x[ask] for x in log_pose), ext[ask])
            trigger[pa[ask][inter[ask] > logged + TOLERANCE]] = True
        move = ~on | trigger
        if not move.any():
            return
        r, c, k0, s_now, v_now, strongest = r[move], c[move], k0[move], s_now[move], v_now[move], strongest[move]
        run = run_now[cb[move], cc[move]]
        desired = np.maximum(fwd_speed[move], self.spec.creep_speed)
        accel = idm_free(model, v_now, desired) - model.max_accel * strongest
        travel, v_next = idm_advance(model, v_now, accel, self.dt)
        s_next = s_now + travel
        back_on = s_next >= self.arc[r, t + 1, c]  # caught up with its log: the log's pose from here
        self.off[r, c] = ~back_on
        stay = ~back_on
        r, c, k0, s_next, v_next, run = r[stay], c[stay], k0[stay], s_next[stay], v_next[stay], run[stay]
        if r.size == 0:
            return
        f = self._frame_below(r, c, run, k0, s_next)
        arc0, arc1 = self.arc[r, f, c], self.arc[r, f + 1, c]
        u = (s_next - arc0) / (arc1 - arc0)  # arc1 > s_next >= arc0: f is the last frame at or below it
        p0, p1 = log.agent_xy[r, f, c], log.agent_xy[r, f + 1, c]
        xy = p0 + u[:, None] * (p1 - p0)
        y0 = log.agent_yaw[r, f, c].astype(np.float64)
        turn = np.angle(np.exp(1j * (log.agent_yaw[r, f + 1, c] - y0)))
        new_yaw = (y0 + u * turn).astype(np.float32)
        tangent = (p1 - p0) / np.linalg.norm(p1 - p0, axis=-1, keepdims=True)
        sim.agent_xy[r, t + 1, c] = xy
        sim.agent_yaw[r, t + 1, c] = new_yaw
        sim.agent_velocity[r, t + 1, c] = (v_next[:, None] * tangent).astype(np.float32)
        self.reacted[r, t + 1, c] = True
        self.frame[r, c], self.s[r, c], self.v[r, c] = f, s_next, v_next
        if cells is None:
            return
        cell = cells.base(r, np.full(r.size, t + 1)) + c
        cells.sel.view(np.float64)[cell, 1:3] = xy
        feat = cells.feat.view(np.float64)
        feat[cell, 1:3] = xy
        feat[cell, 3] = new_yaw  # widened exactly, as LogCells packs the float32 yaw

    def _velocity(self, xy: np.ndarray, rows: np.ndarray, t: int) -> np.ndarray:
        """(B, 2) velocity of the step into frame t (out of frame 0 at t = 0)."""
        if t == 0:
            return (xy[rows, min(1, xy.shape[1] - 1)] - xy[rows, 0]) / self.dt
        return (xy[rows, t] - xy[rows, t - 1]) / self.dt

    def _window(self, r: np.ndarray, c: np.ndarray, run: np.ndarray, k0: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Each candidate's path ahead: (n, W+2) logged points from frame ``k0`` on and
        their arc lengths; past its run's end the path goes on straight along the
        last logged heading for :data:`_EXTENSION` m."""
        log = self.log
        n_frames = log.available.shape[1]
        frames = k0[:, None] + np.arange(self.spec.lookahead_frames + 2)
        inside = frames < n_frames
        frames = np.minimum(frames, n_frames - 1)
        valid = inside & (self.run[r[:, None], frames, c[:, None]] == run[:, None])
        xy = log.agent_xy[r[:, None], frames, c[:, None]]
        arc = self.arc[r[:, None], frames, c[:, None]]
        last = frames[np.arange(r.size), valid.sum(axis=1) - 1]  # the run's frames in the window come first
        if not valid.all():
            heading = log.agent_yaw[r, last, c].astype(np.float64)
            end = log.agent_xy[r, last, c] + _EXTENSION * np.stack([np.cos(heading), np.sin(heading)], -1)
            xy = np.where(valid[..., None], xy, end[:, None, :])
            arc = np.where(valid, arc, self.arc[r, last, c][:, None] + _EXTENSION)
        return xy[..., 0], xy[..., 1], arc

    def _interaction(self, wx, wy, ws, s_centre, half, speed, pose, ext) -> np.ndarray:
        """IDM's interaction term for each pair (0 where the obstacle is not in the way):
        the path (wx, wy, ws), the follower's centre on it (arc length), half
        length and speed, the obstacle's (xy, yaw, velocity) ``pose`` and extent."""
        (px, py), o_yaw, o_vel = pose[0].T, pose[1].astype(np.float64), pose[2].astype(np.float64)
        ax, ay = wx[:, :-1], wy[:, :-1]
        dx, dy = wx[:, 1:] - ax, wy[:, 1:] - ay
        length2 = dx * dx + dy * dy
        safe = np.where(length2 > 0.0, length2, 1.0)
        u = np.clip(((px[:, None] - ax) * dx + (py[:, None] - ay) * dy) / safe, 0.0, 1.0)
        u[length2 == 0.0] = 0.0
        ex, ey = px[:, None] - (ax + u * dx), py[:, None] - (ay + u * dy)
        i = np.argmin(ex * ex + ey * ey, axis=1)
        n = np.arange(px.size)
        lateral = np.hypot(ex[n, i], ey[n, i])
        seg = np.sqrt(length2[n, i])
        moving = seg > 0.0
        tx = np.where(moving, dx[n, i] / np.where(moving, seg, 1.0), np.cos(o_yaw))
        ty = np.where(moving, dy[n, i] / np.where(moving, seg, 1.0), np.sin(o_yaw))
        s_obstacle = ws[n, i] + u[n, i] * (ws[n, i + 1] - ws[n, i])
        rel = o_yaw - np.arctan2(ty, tx)
        cos_rel, sin_rel = np.abs(np.cos(rel)), np.abs(np.sin(rel))
        along = 0.5 * (ext[:, 0] * cos_rel + ext[:, 1] * sin_rel)
        across = 0.5 * (ext[:, 0] * sin_rel + ext[:, 1] * cos_rel)
        in_way = (s_obstacle > s_centre) & (lateral - across < self.spec.corridor)
        gap = s_obstacle - along - s_centre - half
        lead_speed = o_vel[:, 0] * tx + o_vel[:, 1] * ty
        return np.where(in_way, idm_interaction(self.spec.idm, speed, lead_speed, gap), 0.0)

    def _frame_below(self, r, c, run, k0, s) -> np.ndarray:
        """The last frame of each agent's run (from ``k0`` on) whose arc length is at most ``s``."""
        n_frames = self.log.available.shape[1]
        width = self.spec.lookahead_frames + 2
        out = np.empty(r.size, np.int64)
        todo = np.arange(r.size)
        k = k0.copy()
        while todo.size:
            frames = np.minimum(k[todo, None] + np.arange(width), n_frames - 1)
            arc = np.where(self.run[r[todo, None], frames, c[todo, None]] == run[todo, None],
                           self.arc[r[todo, None], frames, c[todo, None]], np.inf)
            count = (arc <= s[todo, None]).sum(axis=1)  # arc lengths grow along a run: a prefix
            done = count < width
            out[todo[done]] = k[todo[done]] + count[done] - 1
            k[todo[~done]] += width - 1
            todo = todo[~done]
        return out
