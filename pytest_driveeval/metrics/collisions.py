"""Ego-vs-agent collisions per frame: front / side / rear, plus blame.

Semantics follow l5kit's ``detect_collision`` (``l5kit.cle.metrics`` /
``l5kit.planning.utils``), which the closed-loop evaluator calls once per
frame with shapely polygons:

1. agents are pre-filtered by ``|ego - agent| < (|ego_extent[:2]| +
   |agent_extent[:2]|) / 2`` (half-diagonals; the test cannot reject a real
   overlap, only corner-to-corner touching exactly on the diagonal);
2. the *first* agent in array order whose box intersects the ego box
   (touching counts) is the collision partner; others in the same frame are
   ignored.  We keep that rule so counts match l5kit: ``agent_index`` is the
   lowest colliding available index.  ``overlap`` still lists every
   intersecting agent;
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

from pytest_driveeval.geometry import box_corners, norm2d, oriented_boxes_overlap, segment_box_overlap_length

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
    the agent index).  ``speed_tol`` in m/s.
    """
    ec = np.asarray(ego_centroid, dtype=np.float64)
    ac = np.asarray(agent_centroid, dtype=np.float64)
    ayaw = np.asarray(agent_yaw, dtype=np.float64)
    num_agents = ac.shape[-2]
    lead = np.broadcast_shapes(ec.shape[:-1], np.shape(ego_yaw), ac.shape[:-2], ayaw.shape[:-1])
    frames = math.prod(lead)

    def per_frame(x, tail):  # -> (F, *tail), copying only when broadcasting
        return np.broadcast_to(np.asarray(x, dtype=np.float64), lead + tail).reshape((frames,) + tail)

    e_xy = per_frame(ec, (2,))
    e_yaw = per_frame(ego_yaw, ())
    e_ext = per_frame(np.asarray(ego_extent)[..., :2], (2,))
    a_xy = np.broadcast_to(ac, lead + (num_agents, 2)).reshape(frames, num_agents, 2)
    a_ext2 = np.asarray(agent_extent, dtype=np.float64)[..., :2]
    a_ext = np.broadcast_to(a_ext2, lead + (num_agents, 2)).reshape(frames, num_agents, 2)

    # 1. Coarse range test on every pair, against the largest possible
    # reach: the fewest passes over the (frames x agents) table.
    agent_diag = float(np.hypot(_max_or_zero(a_ext[..., 0]), _max_or_zero(a_ext[..., 1])))
    max_reach = 0.5 * (_max_or_zero(norm2d(e_ext)) + agent_diag)
    dx = a_xy[..., 0] - e_xy[:, None, 0]
    dy = a_xy[..., 1] - e_xy[:, None, 1]
    dx *= dx
    dy *= dy
    dx += dy
    near = dx < max_reach * max_reach
    if agent_available is not None:
        near &= np.broadcast_to(np.asarray(agent_available, dtype=bool), lead + (num_agents,)).reshape(
            frames, num_agents
        )

    # 2. Exact separating-axis test on the pairs in range only.
    f_idx, a_idx = np.nonzero(near)
    a_yaw_f = np.broadcast_to(ayaw, lead + (num_agents,)).reshape(frames, num_agents)
    hit = oriented_boxes_overlap(
        e_xy[f_idx], e_yaw[f_idx], e_ext[f_idx], a_xy[f_idx, a_idx], a_yaw_f[f_idx, a_idx], a_ext[f_idx, a_idx]
    )
    # l5kit's own within_range (strict, per pair): only drops boxes touching
    # corner to corner exactly along the diagonal, kept for parity.
    r = 0.5 * (norm2d(e_ext[f_idx]) + norm2d(a_ext[f_idx, a_idx]))
    hit &= dx[f_idx, a_idx] < r * r
    overlap = np.zeros((frames, num_agents), dtype=bool)
    overlap[f_idx[hit], a_idx[hit]] = True

    # 3. l5kit's partner: first colliding agent in array order.  np.nonzero is
    # row-major, so the first hit per frame is the lowest agent index.
    hf, ha = f_idx[hit], a_idx[hit]
    first = np.ones(hf.shape, dtype=bool)
    first[1:] = hf[1:] != hf[:-1]
    cf, ca = hf[first], ha[first]

    # 4. Ego-edge lengths inside the partner's box -> kind.
    corners = box_corners(e_xy[cf], e_yaw[cf], e_ext[cf])  # (K, 4, 2)
    starts = corners[:, _L5KIT_EDGE_ORDER]
    ends = corners[:, _L5KIT_EDGE_END]
    lengths = segment_box_overlap_length(
        starts, ends, a_xy[cf, ca][:, None], a_yaw_f[cf, ca][:, None], a_ext[cf, ca][:, None]
    )
    side = np.argmax(lengths, axis=1)  # first maximum wins, as np.argmax in l5kit

    kind = np.zeros(frames, dtype=np.int8)
    kind[cf] = _KIND_OF_L5KIT_SIDE[side]
    agent_index = np.full(frames, -1, dtype=np.int64)
    agent_index[cf] = ca
    track = np.full(frames, -1, dtype=np.int64)
    if track_ids is None:
        track[cf] = ca
    else:
        tid = np.broadcast_to(np.asarray(track_ids), lead + (num_agents,)).reshape(frames, num_agents)
        track[cf] = tid[cf, ca]

    at_fault = np.zeros(frames, dtype=bool)
    at_fault[cf] = _blame(
        side, e_yaw[cf], cf, ca, lead, frames, num_agents, ego_velocity, ego_speed, agent_velocity, speed_tol
    )
    return CollisionResult(
        kind.reshape(lead),
        agent_index.reshape(lead),
        track.reshape(lead),
        at_fault.reshape(lead),
        overlap.reshape(lead + (num_agents,)),
    )


def _max_or_zero(x: np.ndarray) -> float:
    # Padding slots may hold nan; the plain max is much faster, so only fall
    # back to nanmax when it is poisoned.
    if x.size == 0:
        return 0.0
    m = float(x.max())
    return float(np.nan_to_num(np.nanmax(x))) if np.isnan(m) else m


def _blame(side, yaw, cf, ca, lead, frames, num_agents, ego_velocity, ego_speed, agent_velocity, speed_tol):
    """At-fault flag for the K colliding frames (rules in the module doc)."""
    kind = _KIND_OF_L5KIT_SIDE[side]
    if ego_velocity is None and ego_speed is None:
        return kind != REAR
    c, s = np.cos(yaw), np.sin(yaw)
    ln = _EDGE_NORMALS[side]
    normal = np.stack([c * ln[:, 0] - s * ln[:, 1], s * ln[:, 0] + c * ln[:, 1]], axis=1)  # world

    if ego_velocity is not None:
        ev = np.broadcast_to(np.asarray(ego_velocity, dtype=np.float64), lead + (2,))
        ev_k = ev.reshape(frames, 2)[cf]
    else:
        speed = np.broadcast_to(np.asarray(ego_speed, dtype=np.float64), lead).reshape(frames)[cf]
        ev_k = np.stack([speed * c, speed * s], axis=1)
    ego_closing = np.einsum("kd,kd->k", ev_k, normal)
    if agent_velocity is None:
        agent_closing = np.zeros_like(ego_closing)
    else:
        av = np.broadcast_to(np.asarray(agent_velocity, dtype=np.float64), lead + (num_agents, 2))
        agent_closing = -np.einsum("kd,kd->k", av.reshape(frames, num_agents, 2)[cf, ca], normal)

    keeps_up = ego_closing >= agent_closing
    return np.where(kind == FRONT, keeps_up, keeps_up & (ego_closing > speed_tol))


def count_collisions(result: CollisionResult, *, at_fault_only: bool = False) -> dict[str, int]:
    """Number of colliding frames of each kind over the whole result."""
    kind = result.kind if not at_fault_only else np.where(result.at_fault, result.kind, NONE)
    counts = np.bincount(np.asarray(kind, dtype=np.int64).ravel(), minlength=4)
    return {"front": int(counts[FRONT]), "side": int(counts[SIDE]), "rear": int(counts[REAR])}
