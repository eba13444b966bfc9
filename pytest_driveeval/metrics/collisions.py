"""Ego-vs-agent collisions per frame: front / side / rear, plus blame.

Semantics follow l5kit's ``detect_collision`` (``l5kit.cle.metrics`` /
``l5kit.planning.utils``), which the closed-loop evaluator calls once per
frame with shapely polygons:

1. agents are pre-filtered by ``|ego - agent| < (|ego_extent[:2]| +
   |agent_extent[:2]|) / 2`` (half-diagonals; the test cannot reject a real
   overlap, only corner-to-corner touching exactly on the diagonal);
2. the *first* agent in the frame's agent rows whose box intersects the ego
   box (touching counts) is the collision partner; others in the same frame
   are ignored.  We keep that rule so kinds and partners match l5kit.  The
   agent axis here need not be in row order (the log replay packs tracks
   into columns), so ``agent_order`` gives each agent's row position and the
   partner is the intersecting agent with the lowest one; without it, the
   lowest index.  ``overlap`` still lists every intersecting agent;
3. the kind is the ego edge (front, rear, left, right, in that order) with the
   longest length inside the agent box; ties go to the earlier edge, so an
   agent wholly inside the ego (all lengths 0) is "front", as in l5kit.
   Left and right both map to "side".

Here the same is computed for all (scene, frame, agent) at once: the range
test over every pair, an exact separating-axis test only on the few pairs in
range, and edge clipping only for the chosen partner of each frame.

Blame (``at_fault``) is our addition; l5kit counts every collision.  With
the unit normal ``n`` of the contacted ego edge (pointing out of the ego),
``ego_closing = v_ego . n`` and ``agent_closing = -v_agent . n``:

* front: at fault unless the agent closes faster than the ego
  (``ego_closing >= agent_closing``).  Keeping clear ahead is the ego's job,
  so a stopped ego overlapping a stopped car ahead is still at fault; only an
  agent reversing into a slower ego's nose is excused.
* rear and side: at fault only if the ego itself moves towards the agent
  (``ego_closing > speed_tol``) at least as fast as the agent moves towards
  it.  A replayed agent rear-ending a slower or stopped ego is therefore not
  at fault: log replay is non-reactive, the logged driver behind could not see
  our simulated ego braking.  Same for an agent cutting sideways into us.
* without ``ego_velocity``/``ego_speed`` the rule falls back to the kind alone: front and
  side at fault, rear not.  A missing ``agent_velocity`` is taken as zero.

Blame is judged from the velocities of that frame only.
"""
from __future__ import annotations

from typing import NamedTuple

import math

import numpy as np

from pytest_driveeval.geometry import norm2d

NONE, FRONT, SIDE, REAR = 0, 1, 2, 3
KIND_NAMES = ("", "front", "side", "rear")

# l5kit's argmax order is (front, rear, left, right); geometry numbers the ego
# edges (front, right, rear, left).  These map one onto the other and onto
# our kind codes.
_L5KIT_EDGE_ORDER = np.array([0, 2, 3, 1])
_L5KIT_EDGE_END = (_L5KIT_EDGE_ORDER + 1) % 4
_KIND_OF_L5KIT_SIDE = np.array([FRONT, REAR, SIDE, SIDE], dtype=np.int8)
# Outward normal of each l5kit-ordered edge in the ego frame (x fwd, y left).
_EDGE_NORMALS = np.array([[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [0.0, -1.0]])


class CollisionResult(NamedTuple):
    """Per-frame collision outcome; ``...`` is the frame layout, e.g. (S, T)."""

    kind: np.ndarray  # (...) int8: 0 none, 1 front, 2 side, 3 rear
    agent_index: np.ndarray  # (...) int64 index along the agent axis, -1 if none
    track_id: np.ndarray  # (...) int64 track id of that agent, -1 if none
    at_fault: np.ndarray  # (...) bool, False where kind == 0
    overlap: np.ndarray  # (..., A) bool, every available agent intersecting the ego


def detect_collisions(
    ego_centroid: np.ndarray,
    ego_yaw: np.ndarray,
    ego_extent: np.ndarray,
    agent_centroid: np.ndarray,
    agent_yaw: np.ndarray,
    agent_extent: np.ndarray,
    agent_available: np.ndarray | None = None,
    agent_velocity: np.ndarray | None = None,
    ego_velocity: np.ndarray | None = None,
    track_ids: np.ndarray | None = None,
    *,
    agent_order: np.ndarray | None = None,
    ego_speed: np.ndarray | None = None,
    speed_tol: float = 0.1,
) -> CollisionResult:
    """Classify the ego's collision in every frame.

    Shapes (``...`` = frame layout such as (S, T) or (S,); all broadcast):
    ego_centroid (..., 2); ego_yaw (...); ego_extent (..., >=2) as (length,
    width[, height]), e.g. a constant (2,); agent_centroid (..., A, 2);
    agent_yaw (..., A); agent_extent (..., A, >=2); agent_available (..., A)
    bool (padding slots False); agent_velocity (..., A, 2) world frame;
    ego_velocity (..., 2) world frame, or instead ego_speed (...) signed speed
    along the heading (l5kit's ego state); track_ids (..., A) ints (default:
    the agent index); agent_order (..., A) ints, the agent's position among
    its frame's rows, which picks the partner (default: the agent index).
    ``speed_tol`` in m/s.

    The arithmetic of every decision (range, separating axes, edge lengths,
    blame) is that of :func:`~pytest_driveeval.geometry.oriented_boxes_overlap`,
    :func:`~pytest_driveeval.geometry.box_corners` and
    :func:`~pytest_driveeval.geometry.segment_box_overlap_length`, operation
    for operation, only laid out for few numpy calls: per-frame terms (ego
    cos/sin, half extents) once per frame, pair terms gathered by flat index,
    x and y as planes.
    """
    ec = np.asarray(ego_centroid, dtype=np.float64)
    ac = np.asarray(agent_centroid, dtype=np.float64)
    ayaw = np.asarray(agent_yaw)
    eyaw = np.asarray(ego_yaw, dtype=np.float64)
    num_agents = ac.shape[-2]
    lead = ac.shape[:-2]
    if ec.shape[:-1] != lead or eyaw.shape != lead or ayaw.shape[:-1] != lead:
        lead = np.broadcast_shapes(ec.shape[:-1], eyaw.shape, lead, ayaw.shape[:-1])
    frames = math.prod(lead)

    def per_frame(x, tail, dtype=np.float64):  # -> (F, *tail), copying only when broadcasting
        x = np.asarray(x, dtype=dtype)
        if x.shape != lead + tail:
            x = np.broadcast_to(x, lead + tail)
        return x.reshape((frames,) + tail)

    pair_shape = lead + (num_agents,)

    def at_pairs(x, tail, pairs, dtype=None):  # x's values at flat (frame, agent) indices -> (P, *tail)
        # Gathered from the caller's (possibly sliced or broadcast) table as it is:
        # flattening a sliced (scenes, frames, agents) table first would copy all of it.
        x = np.asarray(x)
        if x.shape != pair_shape + tail:
            x = np.broadcast_to(x, pair_shape + tail)
        if x.flags.c_contiguous:
            v = np.take(x.reshape((-1,) + tail), pairs, axis=0)
        else:
            v = x[np.unravel_index(pairs, pair_shape)]
        return v if dtype is None else v.astype(dtype, copy=False)

    def as_pairs(x, tail):  # a read-only view shaped (..., A, *tail)
        x = np.asarray(x)
        return x if x.shape == pair_shape + tail else np.broadcast_to(x, pair_shape + tail)

    e_xy = per_frame(ec, (2,))
    e_yaw = per_frame(eyaw, ())
    e_ext = np.asarray(ego_extent, dtype=np.float64)[..., :2]
    const_ext = e_ext.ndim == 1  # one ego box for every frame: per-frame terms are scalars
    if not const_ext:
        e_ext = per_frame(e_ext, (2,))
    a_xy = as_pairs(ac, (2,))
    a_ext_raw = np.asarray(agent_extent)
    a_ext = as_pairs(a_ext_raw[..., :2] if a_ext_raw.shape[-1] != 2 else a_ext_raw, (2,))  # dtype kept; exact

    # 1. Coarse range test on every pair, against the largest possible
    # reach: the fewest passes over the (frames x agents) table.
    agent_diag = float(np.hypot(max_or_zero(a_ext[..., 0]), max_or_zero(a_ext[..., 1])))
    max_reach = 0.5 * (max_or_zero(norm2d(e_ext)) + agent_diag)
    e_grid = e_xy.reshape(lead + (1, 2))
    dx = a_xy[..., 0] - e_grid[..., 0]
    dy = a_xy[..., 1] - e_grid[..., 1]
    dx *= dx
    dy *= dy
    dx += dy
    near = dx < max_reach * max_reach
    if agent_available is not None:
        near &= as_pairs(np.asarray(agent_available, dtype=bool), ())
    pair = np.flatnonzero(near)  # row-major: by frame, then agent index
    f_idx = pair // num_agents

    # 2. l5kit's own within_range (strict, per pair), then the exact
    # separating-axis test on the pairs left.  l5kit's range test only drops
    # boxes touching corner to corner exactly along the diagonal.
    ext_p = at_pairs(a_ext, (2,), pair, np.float64)  # (P, 2)
    e_norm = norm2d(e_ext) if const_ext else np.take(norm2d(e_ext), f_idx)
    r = 0.5 * (e_norm + norm2d(ext_p))
    r *= r
    keep = np.take(dx, pair) < r
    pair, f_idx, ext_p = pair[keep], f_idx[keep], ext_p[keep]
    e_cos, e_sin = np.cos(e_yaw), np.sin(e_yaw)
    hit = _sat_overlap(e_xy, e_cos, e_sin, e_ext, const_ext, f_idx, at_pairs(a_xy, (2,), pair),
                       at_pairs(ayaw, (), pair, np.float64), ext_p)
    hit_pair = pair[hit]
    overlap = np.zeros(frames * num_agents, dtype=bool)
    overlap[hit_pair] = True

    # 3. l5kit's partner: the first colliding agent in the frame's rows.  The
    # pairs are row-major, so without an order the first hit per frame is the
    # lowest agent index; with one, a stable sort by (frame, order) puts the
    # partner first.
    hf = f_idx[hit]
    if agent_order is not None and hit_pair.size:
        by_row = np.lexsort((at_pairs(agent_order, (), hit_pair, np.int64), hf))
        hit_pair, hf = hit_pair[by_row], hf[by_row]
    first = np.ones(hf.shape, dtype=bool)
    first[1:] = hf[1:] != hf[:-1]
    cp = hit_pair[first]
    cf, ca = hf[first], cp - hf[first] * num_agents

    # 4. Ego-edge lengths inside the partner's box -> kind.
    side = _contact_side(
        np.take(e_xy, cf, axis=0), np.take(e_cos, cf), np.take(e_sin, cf),
        e_ext if const_ext else np.take(e_ext, cf, axis=0),
        at_pairs(a_xy, (2,), cp), at_pairs(ayaw, (), cp, np.float64), at_pairs(a_ext, (2,), cp, np.float64),
    )

    kind = np.zeros(frames, dtype=np.int8)
    kind[cf] = _KIND_OF_L5KIT_SIDE[side]
    agent_index = np.full(frames, -1, dtype=np.int64)
    agent_index[cf] = ca
    track = np.full(frames, -1, dtype=np.int64)
    if track_ids is None:
        track[cf] = ca
    else:
        track[cf] = at_pairs(track_ids, (), cp)

    at_fault = np.zeros(frames, dtype=bool)
    at_fault[cf] = _blame(side, np.take(e_cos, cf), np.take(e_sin, cf), cf, cp, lead, frames, num_agents,
                          ego_velocity, ego_speed, agent_velocity, speed_tol, at_pairs)
    return CollisionResult(
        kind.reshape(lead),
        agent_index.reshape(lead),
        track.reshape(lead),
        at_fault.reshape(lead),
        overlap.reshape(lead + (num_agents,)),
    )


def _sat_overlap(e_xy, e_cos, e_sin, e_ext, const_ext, f_idx, b_xy, b_yaw, b_ext) -> np.ndarray:
    """``oriented_boxes_overlap(ego of frame f_idx, agent pair)`` (tol 0), same operations."""
    ca, sa = np.take(e_cos, f_idx), np.take(e_sin, f_idx)
    cb, sb = np.cos(b_yaw), np.sin(b_yaw)
    ea = 0.5 * e_ext
    if const_ext:
        al, aw = float(ea[0]), float(ea[1])
    else:
        ea = np.take(ea, f_idx, axis=0)
        al, aw = ea[:, 0], ea[:, 1]
    eb = 0.5 * b_ext
    bl, bw = eb[:, 0], eb[:, 1]
    d = b_xy - np.take(e_xy, f_idx, axis=0)
    dx, dy = d[:, 0], d[:, 1]
    cos_rel = ca * cb
    cos_rel += sa * sb
    np.abs(cos_rel, out=cos_rel)
    sin_rel = ca * sb
    sin_rel -= sa * cb
    np.abs(sin_rel, out=sin_rel)
    # Each axis: |projection of d| <= sum of the projected half extents.  The
    # "+ tol" of the geometry function (0.0) changes no comparison.
    ok = _axis_fits(dx * ca + dy * sa, al + cos_rel * bl + sin_rel * bw)
    ok &= _axis_fits(dy * ca - dx * sa, aw + sin_rel * bl + cos_rel * bw)
    ok &= _axis_fits(dx * cb + dy * sb, bl + cos_rel * al + sin_rel * aw)
    ok &= _axis_fits(dy * cb - dx * sb, bw + sin_rel * al + cos_rel * aw)
    return ok


def _axis_fits(proj: np.ndarray, reach: np.ndarray) -> np.ndarray:
    np.abs(proj, out=proj)
    return proj <= reach


_CORNER_U = np.array([1.0, 1.0, -1.0, -1.0])[:, None]  # front-left, front-right, rear-right, rear-left
_CORNER_V = np.array([1.0, -1.0, -1.0, 1.0])[:, None]


def _contact_side(e_xy, e_cos, e_sin, e_ext, b_xy, b_yaw, b_ext) -> np.ndarray:
    """Index (l5kit order: front, rear, left, right) of the ego edge with the
    longest length inside the partner box, first maximum on ties.

    ``box_corners`` then ``segment_box_overlap_length`` on the four ego edges,
    with the same operations, on (4, K) planes (edges first).
    """
    half = 0.5 * e_ext
    hl, hw = (half[0], half[1]) if half.ndim == 1 else (half[:, 0], half[:, 1])
    # box_corners: c * (u * hl) == u * (c * hl) exactly for u = +-1.
    chl, shl, chw, shw = e_cos * hl, e_sin * hl, e_cos * hw, e_sin * hw
    cx = e_xy[:, 0] + _CORNER_U * chl
    cx -= _CORNER_V * shw
    cy = e_xy[:, 1] + _CORNER_U * shl
    cy += _CORNER_V * chw
    start_x, start_y = cx[_L5KIT_EDGE_ORDER], cy[_L5KIT_EDGE_ORDER]  # (4, K)
    vec_x, vec_y = cx[_L5KIT_EDGE_END], cy[_L5KIT_EDGE_END]
    vec_x -= start_x
    vec_y -= start_y

    # segment_box_overlap_length, into the box frame.
    c, s = np.cos(b_yaw), np.sin(b_yaw)
    rel_x = start_x - b_xy[:, 0]
    rel_y = start_y - b_xy[:, 1]
    p0 = np.empty((2,) + rel_x.shape)  # (axis, edge, K)
    d = np.empty_like(p0)
    np.add(rel_x * c, rel_y * s, out=p0[0])
    np.subtract(rel_y * c, rel_x * s, out=p0[1])
    np.add(vec_x * c, vec_y * s, out=d[0])
    np.subtract(vec_y * c, vec_x * s, out=d[1])
    half_b = (0.5 * b_ext).T[:, None, :]  # (axis, 1, K)
    with np.errstate(divide="ignore", invalid="ignore"):
        ta = (-half_b - p0) / d
        tb = (half_b - p0) / d
    # A segment parallel to a slab is either wholly inside it (no constraint)
    # or wholly outside (empty); lying exactly on the border counts as inside.
    parallel = d == 0
    t_lo = np.minimum(ta, tb)
    t_hi = np.maximum(ta, tb, out=tb)
    if parallel.any():
        in_slab = (p0 >= -half_b) & (p0 <= half_b)
        t_lo = np.where(parallel, np.where(in_slab, -np.inf, np.inf), t_lo)
        t_hi = np.where(parallel, np.where(in_slab, np.inf, -np.inf), t_hi)
    lo = np.maximum(t_lo[0], t_lo[1])
    np.maximum(lo, 0.0, out=lo)
    hi = np.minimum(t_hi[0], t_hi[1])
    np.minimum(hi, 1.0, out=hi)
    hi -= lo
    np.maximum(hi, 0.0, out=hi)
    d *= d
    length = d[0] + d[1]
    np.sqrt(length, out=length)
    hi *= length
    return np.argmax(hi, axis=0)  # first maximum wins, as np.argmax in l5kit


def max_or_zero(x: np.ndarray) -> float:
    """The largest value of ``x`` ignoring NaN; 0 when it is empty or all NaN."""
    # Padding slots may hold nan; the plain max is much faster, so only fall
    # back to nanmax when it is poisoned.
    if x.size == 0:
        return 0.0
    m = float(x.max())
    return float(np.nan_to_num(np.nanmax(x))) if np.isnan(m) else m


def _blame(side, c, s, cf, cp, lead, frames, num_agents, ego_velocity, ego_speed, agent_velocity, speed_tol,
           at_pairs):
    """At-fault flag for the K colliding frames (rules in the module doc);
    ``c``/``s``: cos/sin of the ego yaw, ``cp``: flat (frame, agent) pair index."""
    kind = _KIND_OF_L5KIT_SIDE[side]
    if ego_velocity is None and ego_speed is None:
        return kind != REAR
    ln = _EDGE_NORMALS[side]
    lx, ly = ln[:, 0], ln[:, 1]
    nx = c * lx - s * ly  # world normal
    ny = s * lx + c * ly

    if ego_velocity is not None:
        ev = np.broadcast_to(np.asarray(ego_velocity, dtype=np.float64), lead + (2,)).reshape(frames, 2)
        ev_k = np.take(ev, cf, axis=0)
        evx, evy = ev_k[:, 0], ev_k[:, 1]
    else:
        speed = np.take(np.broadcast_to(np.asarray(ego_speed, dtype=np.float64), lead).reshape(frames), cf)
        evx, evy = speed * c, speed * s
    ego_closing = evx * nx + evy * ny
    if agent_velocity is None:
        agent_closing = np.zeros_like(ego_closing)
    else:
        av = at_pairs(agent_velocity, (2,), cp, np.float64)
        agent_closing = av[:, 0] * nx
        agent_closing += av[:, 1] * ny
        np.negative(agent_closing, out=agent_closing)

    keeps_up = ego_closing >= agent_closing
    return np.where(kind == FRONT, keeps_up, keeps_up & (ego_closing > speed_tol))


def count_collisions(result: CollisionResult, *, at_fault_only: bool = False) -> dict[str, int]:
    """Number of colliding frames of each kind over the whole result."""
    kind = result.kind if not at_fault_only else np.where(result.at_fault, result.kind, NONE)
    counts = np.bincount(np.asarray(kind, dtype=np.int64).ravel(), minlength=4)
    return {"front": int(counts[FRONT]), "side": int(counts[SIDE]), "rear": int(counts[REAR])}
