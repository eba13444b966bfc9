"""The graph observation of seed 002 (BARK-ML's ``GraphObserver``), batched in torch.

Nodes are the ego (node 0) and the other valid agents nearest to it, up to an
agent limit K, each with the 11 :data:`NODE_FEATURES` normalised to
``(v - lo) / (hi - lo)`` without clipping.  Agents within the visibility radius
of each other are joined both ways; :data:`EDGE_FEATURES` are differences of
the normalised node values, source minus target, as BARK-ML's current observer
computes them.  The flat form is the seed's: a header ``[K, n, F]``, the ``K*F``
node features (padded rows zero), the ``K*K`` adjacency.  Edge features are not
stored: :func:`decode` derives them from the nodes, which makes it the exact
inverse of :func:`encode`.

As BARK-ML's code does: ``goal_theta`` is the bearing from the agent to its
goal, ``atan2(goal_dy, goal_dx)`` (the seed's prose calls it the orientation
needed at the goal, so a goal heading is not an input); headings are neither
wrapped nor clipped; an agent exactly at the radius is linked; each node has a
self-loop (``SelfLoops``, on by default since October 2020; ``self_loops=False``
is the seed's August 2020 observer).

Where this differs from BARK-ML (bark_ml/observers/graph_observer.py):

* The others are always sorted by distance; BARK-ML skips the sort when there
  are exactly two of them (``if len(agents) > 2``), a slip.  Ties keep the
  input order.
* BARK-ML gives each agent the goal of its own lane corridor.  The simulator
  knows only the ego's goal, so unless ``agent_goal_xy`` / ``agent_goal_speed``
  say otherwise the others share it, as in BARK-ML's highway blueprint where
  every lane corridor has the same goal.
* Padded rows are zero (the 2020 observer the seed ran padded with -1).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, NamedTuple

import torch
from torch import Tensor

from ..core.errors import DriveEvalError

__all__ = [
    "EDGE_FEATURES", "HEADER", "NODE_FEATURES", "GraphObservation", "GraphObservationError",
    "ObservationRanges", "decode", "edge_features", "encode", "graph_observation", "observation_size",
    "split_flat",
]

# BARK-ML's order (available_node_attributes); the seed's prose lists goal_d before goal_theta.
NODE_FEATURES = ("x", "y", "theta", "vel", "goal_x", "goal_y", "goal_dx", "goal_dy", "goal_theta", "goal_d",
                 "goal_vel")
EDGE_FEATURES = ("dx", "dy", "dvel", "dtheta")
# The node columns whose differences are the edge features, in EDGE_FEATURES order.
EDGE_SOURCE_COLUMNS = (0, 1, 3, 2)
HEADER = 3  # agent limit K, agent count n, features per node F

SEED_AGENT_LIMIT = 12
SEED_VISIBILITY_RADIUS = 50.0


class GraphObservationError(DriveEvalError, ValueError):
    """Inputs or a flat observation that do not make a graph observation."""


Range = tuple[float, float]


@dataclass(frozen=True)
class ObservationRanges:
    """What maps to 0 and 1 for each kind of feature.

    ``x`` and ``y`` are the map's bounding box; distances and goal offsets
    follow from it as in BARK-ML (``distance`` up to the box diagonal, ``dx`` and
    ``dy`` over plus/minus the box size).  ``theta`` and ``velocity`` are the
    seed's ``[0, 2pi]`` and ``[0, 100]`` m/s (BARK-ML's ``BaseObserver`` now
    defaults theta to ``[-2pi, 2pi]``).
    """

    x: Range
    y: Range
    theta: Range = (0.0, 2.0 * math.pi)
    velocity: Range = (0.0, 100.0)

    def __post_init__(self) -> None:
        for name in ("x", "y", "theta", "velocity"):
            lo, hi = getattr(self, name)
            if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
                raise GraphObservationError(f"ObservationRanges.{name} must be finite with low < high, got {(lo, hi)}")

    @classmethod
    def from_bounding_box(cls, x_min: float, y_min: float, x_max: float, y_max: float, **kwargs: Any
                          ) -> ObservationRanges:
        return cls(x=(float(x_min), float(x_max)), y=(float(y_min), float(y_max)), **kwargs)

    @property
    def distance(self) -> Range:
        return (0.0, math.hypot(self.x[1] - self.x[0], self.y[1] - self.y[0]))

    @property
    def dx(self) -> Range:
        return (-(self.x[1] - self.x[0]), self.x[1] - self.x[0])

    @property
    def dy(self) -> Range:
        return (-(self.y[1] - self.y[0]), self.y[1] - self.y[0])

    def per_feature(self) -> tuple[Range, ...]:
        """The range of each of :data:`NODE_FEATURES`, in order."""
        return (self.x, self.y, self.theta, self.velocity, self.x, self.y, self.dx, self.dy, self.theta,
                self.distance, self.velocity)


class GraphObservation(NamedTuple):
    nodes: Tensor           # (B, K, F) normalised node features, padded rows zero
    adjacency: Tensor       # (B, K, K) 0/1, symmetric
    edge_features: Tensor   # (B, K, K, 4) source minus target where adjacent, else zero
    count: Tensor           # (B,) int64, nodes in use (the ego and up to K-1 others)
    mask: Tensor            # (B, K) bool, node in use


def observation_size(agent_limit: int, num_features: int = len(NODE_FEATURES)) -> int:
    check_agent_limit(agent_limit)
    return HEADER + agent_limit * num_features + agent_limit * agent_limit


def check_agent_limit(agent_limit: int) -> None:
    if isinstance(agent_limit, bool) or not isinstance(agent_limit, int) or agent_limit < 1:
        raise GraphObservationError(
            f"agent_limit must be an integer of at least 1 (node 0 is the ego), got {agent_limit!r}")


def edge_features(nodes: Tensor, adjacency: Tensor) -> Tensor:
    """(B, K, K, 4): for each edge i -> j, node i minus node j in x, y, vel, theta."""
    cols = nodes[:, :, [0, 1, 3, 2]]  # EDGE_SOURCE_COLUMNS, spelled out: TorchScript reads no module globals
    return (cols.unsqueeze(2) - cols.unsqueeze(1)) * adjacency.unsqueeze(-1)


def split_flat(flat: Tensor, agent_limit: int, num_features: int) -> tuple[Tensor, Tensor, Tensor]:
    """(nodes, adjacency, mask) of flat observations whose K and F are known; no checks."""
    batch = flat.shape[0]
    k, f = agent_limit, num_features
    start = 3  # HEADER, spelled out: TorchScript reads no module globals
    nodes = flat[:, start:start + k * f].reshape(batch, k, f)
    adjacency = flat[:, start + k * f:start + k * f + k * k].reshape(batch, k, k)
    mask = torch.arange(k, device=flat.device).unsqueeze(0) < flat[:, 1:2]
    return nodes, adjacency, mask


def encode(graph: GraphObservation) -> Tensor:
    """(B, 3 + K*F + K*K) in the nodes' dtype."""
    nodes, adjacency, count = graph.nodes, graph.adjacency, graph.count
    if nodes.dim() != 3:
        raise GraphObservationError(f"nodes: expected shape (B, K, F), found {tuple(nodes.shape)}")
    batch, k, f = nodes.shape
    if tuple(adjacency.shape) != (batch, k, k):
        raise GraphObservationError(f"adjacency: expected shape {(batch, k, k)}, found {tuple(adjacency.shape)}")
    if tuple(count.shape) != (batch,):
        raise GraphObservationError(f"count: expected shape {(batch,)}, found {tuple(count.shape)}")
    header = torch.stack([torch.full_like(count, k), count, torch.full_like(count, f)], dim=1).to(nodes.dtype)
    return torch.cat([header, nodes.reshape(batch, k * f), adjacency.to(nodes.dtype).reshape(batch, k * k)], dim=1)


def decode(flat: Tensor) -> GraphObservation:
    """The graph of flat observations (B, L); K and F come from the header."""
    if not isinstance(flat, Tensor):
        flat = torch.as_tensor(flat)
    if flat.dim() != 2 or flat.shape[1] < HEADER:
        raise GraphObservationError(
            f"flat observations: expected shape (B, {HEADER} + K*F + K*K), found {tuple(flat.shape)}")
    if flat.shape[0] == 0:
        raise GraphObservationError("flat observations: an empty batch has no header to read K and F from")
    header = flat[:, :HEADER]
    if not bool(torch.isfinite(header).all()) or not bool((header == header.round()).all()):
        raise GraphObservationError("flat observations: the header [K, n, F] must hold integers")
    k, f = int(header[0, 0]), int(header[0, 2])
    if not (bool((header[:, 0] == k).all()) and bool((header[:, 2] == f).all())):
        raise GraphObservationError("flat observations: K and F differ between rows of the batch")
    if k < 1 or f < 1:
        raise GraphObservationError(f"flat observations: header has K={k}, F={f}; both must be at least 1")
    expected = HEADER + k * f + k * k
    if flat.shape[1] != expected:
        raise GraphObservationError(f"flat observations: header says K={k}, F={f}, so expected shape "
                                    f"({flat.shape[0]}, {expected}), found {tuple(flat.shape)}")
    count = header[:, 1].to(torch.int64)
    if bool(((count < 1) | (count > k)).any()):
        raise GraphObservationError(f"flat observations: agent count n must be in [1, {k}], "
                                    f"found {sorted(set(count.tolist()) - set(range(1, k + 1)))[:5]}")
    nodes, adjacency, mask = split_flat(flat, k, f)
    return GraphObservation(nodes, adjacency, edge_features(nodes, adjacency), count, mask)


def graph_observation(
    xy: Any, yaw: Any, speed: Any, valid: Any, goal_xy: Any, goal_speed: Any, ranges: ObservationRanges, *,
    agent_goal_xy: Any = None, agent_goal_speed: Any = None, agent_limit: int = SEED_AGENT_LIMIT,
    radius: float = SEED_VISIBILITY_RADIUS, self_loops: bool = True, dtype: torch.dtype = torch.float32,
) -> GraphObservation:
    """The graph observations of E episodes with A agents each, agent 0 the ego.

    xy (E, A, 2), yaw (E, A), speed (E, A), valid (E, A) bool; goal_xy (E, 2)
    and goal_speed (E,) are the ego's goal, and also the others' unless
    agent_goal_xy (E, A, 2) / agent_goal_speed (E, A) give theirs (their
    column 0 is not read).  numpy or torch.  The ego is node 0 whatever its
    ``valid`` flag; invalid others are ignored, whatever their values.

    ``self_loops`` is BARK-ML's ``SelfLoops`` (default True since Oct 2020).
    Features are computed in float64 and stored in ``dtype``.
    """
    check_agent_limit(agent_limit)
    if not isinstance(ranges, ObservationRanges):
        raise GraphObservationError(f"ranges: expected ObservationRanges, found {type(ranges).__name__}")
    if not radius >= 0:
        raise GraphObservationError(f"radius must be at least 0, got {radius!r}")
    xy = _float64("xy", xy)
    if xy.dim() != 3 or xy.shape[2] != 2 or xy.shape[1] < 1:
        raise GraphObservationError(f"xy: expected shape (E, A, 2) with A >= 1 (agent 0 is the ego), "
                                    f"found {tuple(xy.shape)}")
    episodes, agents = xy.shape[:2]
    yaw = _shaped("yaw", _float64("yaw", yaw), (episodes, agents), "(E, A)")
    speed = _shaped("speed", _float64("speed", speed), (episodes, agents), "(E, A)")
    valid = _shaped("valid", torch.as_tensor(valid, device=xy.device).to(torch.bool), (episodes, agents), "(E, A)")
    goal_xy = _shaped("goal_xy", _float64("goal_xy", goal_xy), (episodes, 2), "(E, 2)")
    goal_speed = _shaped("goal_speed", _float64("goal_speed", goal_speed), (episodes,), "(E,)")
    if agent_goal_xy is None:
        goals = goal_xy.unsqueeze(1).expand(episodes, agents, 2)
    else:
        goals = _shaped("agent_goal_xy", _float64("agent_goal_xy", agent_goal_xy), (episodes, agents, 2),
                        "(E, A, 2)").clone()
        goals[:, 0] = goal_xy
    if agent_goal_speed is None:
        goal_speeds = goal_speed.unsqueeze(1).expand(episodes, agents)
    else:
        goal_speeds = _shaped("agent_goal_speed", _float64("agent_goal_speed", agent_goal_speed),
                              (episodes, agents), "(E, A)").clone()
        goal_speeds[:, 0] = goal_speed

    # One array for the checks and the gather: x, y, yaw, speed, goal x, goal y, goal speed.
    per_agent = torch.cat([xy, yaw.unsqueeze(-1), speed.unsqueeze(-1), goals, goal_speeds.unsqueeze(-1)], dim=-1)
    observed = valid.clone()
    observed[:, 0] = True
    if not bool((torch.isfinite(per_agent).all(dim=-1) | ~observed).all()):
        _raise_not_finite(observed, xy=xy, yaw=yaw, speed=speed, goal_xy=goal_xy.unsqueeze(1),
                          goal_speed=goal_speed.unsqueeze(1),
                          **({} if agent_goal_xy is None else {"agent_goal_xy": goals}),
                          **({} if agent_goal_speed is None else {"agent_goal_speed": goal_speeds}))
    order, count = _nearest(xy, valid, agent_limit)
    kept = order.shape[1]
    in_use = torch.arange(kept, device=xy.device).unsqueeze(0) < count.unsqueeze(1)

    taken = torch.gather(per_agent, 1, order.unsqueeze(-1).expand(-1, -1, per_agent.shape[-1]))
    pos = taken[..., 0:2]
    to_goal = taken[..., 4:6] - pos
    raw = torch.cat([taken[..., :6], to_goal, torch.atan2(to_goal[..., 1:], to_goal[..., :1]),
                     torch.linalg.vector_norm(to_goal, dim=-1, keepdim=True), taken[..., 6:]], dim=-1)
    lo, hi = torch.tensor(ranges.per_feature(), dtype=torch.float64, device=xy.device).unbind(1)
    normalised = torch.where(in_use.unsqueeze(-1), (raw - lo) / (hi - lo), 0.0)

    apart = torch.linalg.vector_norm(pos.unsqueeze(2) - pos.unsqueeze(1), dim=-1)
    near = (apart <= radius) & in_use.unsqueeze(2) & in_use.unsqueeze(1)
    eye = torch.eye(kept, dtype=torch.bool, device=xy.device)
    near = near & ~eye
    if self_loops:
        near = near | (eye & in_use.unsqueeze(2))

    nodes = torch.zeros(episodes, agent_limit, len(NODE_FEATURES), dtype=dtype, device=xy.device)
    nodes[:, :kept] = normalised.to(dtype)
    adjacency = torch.zeros(episodes, agent_limit, agent_limit, dtype=dtype, device=xy.device)
    adjacency[:, :kept, :kept] = near.to(dtype)
    mask = torch.arange(agent_limit, device=xy.device).unsqueeze(0) < count.unsqueeze(1)
    return GraphObservation(nodes, adjacency, edge_features(nodes, adjacency), count, mask)


def _nearest(xy: Tensor, valid: Tensor, agent_limit: int) -> tuple[Tensor, Tensor]:
    """Agent indices per episode, ego first then valid others by distance (E, min(A, K)), and how many are real."""
    distance = torch.linalg.vector_norm(xy - xy[:, :1], dim=-1)
    key = torch.where(valid, distance, math.inf)
    key[:, 0] = -math.inf
    order = torch.sort(key, dim=1, stable=True).indices[:, :agent_limit]
    others = valid[:, 1:].sum(dim=1)
    return order, 1 + torch.clamp(others, max=agent_limit - 1)


def _raise_not_finite(observed: Tensor, **arrays: Tensor) -> None:
    """Name the input and agent of a NaN or infinity: in a valid agent (or the ego) it is a
    simulator fault, not a far-away car."""
    for name, values in arrays.items():
        bad = ~torch.isfinite(values.reshape(values.shape[:2] + (-1,))).all(dim=-1) & observed[:, :values.shape[1]]
        if bool(bad.any()):
            episode, agent = (int(i) for i in bad.nonzero()[0])
            where = f"episode {episode}" if values.shape[1] == 1 else f"episode {episode}, agent {agent} (valid)"
            raise GraphObservationError(f"{name}: {where} is not finite")


def _float64(name: str, value: Any) -> Tensor:
    try:
        tensor = torch.as_tensor(value)
    except (TypeError, ValueError, RuntimeError) as exc:
        raise GraphObservationError(f"{name}: expected an array of numbers, found {type(value).__name__}") from exc
    if not (tensor.is_floating_point() or tensor.dtype in (torch.int8, torch.int16, torch.int32, torch.int64,
                                                             torch.uint8)):
        raise GraphObservationError(f"{name}: expected an array of numbers, found dtype {tensor.dtype}")
    return tensor.to(torch.float64)


def _shaped(name: str, tensor: Tensor, shape: tuple[int, ...], symbolic: str) -> Tensor:
    if tuple(tensor.shape) != shape:
        raise GraphObservationError(f"{name}: expected shape {symbolic} = {shape}, found {tuple(tensor.shape)}")
    return tensor
