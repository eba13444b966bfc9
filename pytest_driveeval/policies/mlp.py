"""An MLP actor and twin critic over the same flat graph observation as :mod:`.gnn` (the seed's "SAC",
BARK-ML's ``BehaviorSACAgent``).

The flat observation after its header (the K*F node features, then the K*K adjacency) is read as one
vector: node i's features sit in fixed input columns, so the network has no reason to treat the
other vehicles alike, and relabelling them (the order of nodes 1..n-1) changes its output.  That is
the point of the comparison: the GNN is invariant to it by construction.  Everything else is the
GNN's: the same squashed Gaussian head, action bounds and log-density
(:class:`.gnn.SquashedGaussianActor`), the same twin critic (:class:`.gnn.TwinCritic`), the same
header checks, the same factories.  Sized like the GNN: with ``HIDDEN`` 32 the encoder has exactly the
GNN encoder's 10,976 parameters (actor 17,508, twin critic 34,882, the GNN's figures too).

Compiles with ``torch.jit.script`` and exports with ``torch.export``; weights load with
``weights.pt=pytest_driveeval.policies.mlp:make_actor``.
"""
from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import Tensor, nn

from .gnn import ACTION_HIGH, ACTION_LOW, HEAD_HIDDEN, NodeScaling, SquashedGaussianActor, TwinCritic, check_flat, mlp
from .graph import HEADER, NODE_FEATURES, SEED_AGENT_LIMIT, check_agent_limit, observation_size, split_flat

__all__ = ["FlatEncoder", "MLPActor", "MLPCritic", "make_actor", "make_critic", "parameter_count"]

HIDDEN = 32


class FlatEncoder(nn.Module):
    """Flat observations (B, 3 + K*F + K*K) -> an embedding (B, hidden), by an MLP over everything
    after the header (the agent count is in the adjacency: padded nodes have no self-loop or edge)."""

    def __init__(self, agent_limit: int = SEED_AGENT_LIMIT, num_features: int = len(NODE_FEATURES),
                 hidden: int = HIDDEN):
        super().__init__()
        check_agent_limit(agent_limit)
        if num_features < 1:
            raise ValueError(f"num_features must be at least 1, got {num_features}")
        self.agent_limit = agent_limit
        self.num_features = num_features
        self.observation_size = observation_size(agent_limit, num_features)
        self.hidden = hidden
        self.scaling = NodeScaling(num_features)
        self.net = nn.Sequential(mlp(self.observation_size - HEADER, hidden, hidden), nn.ReLU())

    def forward(self, flat: Tensor) -> Tensor:
        check_flat(flat, self.agent_limit, self.num_features, self.observation_size)
        nodes, adjacency, mask = split_flat(flat, self.agent_limit, self.num_features)
        scaled = self.scaling(nodes, mask).flatten(1)
        return self.net(torch.cat([scaled, adjacency.flatten(1)], dim=1))


class MLPActor(SquashedGaussianActor):
    """The squashed Gaussian policy of :class:`.gnn.GNNActor` over :class:`FlatEncoder`."""

    def __init__(self, agent_limit: int = SEED_AGENT_LIMIT, num_features: int = len(NODE_FEATURES),
                 hidden: int = HIDDEN, head_hidden: int = HEAD_HIDDEN, action_low: Sequence[float] = ACTION_LOW,
                 action_high: Sequence[float] = ACTION_HIGH):
        super().__init__(FlatEncoder(agent_limit, num_features, hidden), hidden, head_hidden, action_low,
                         action_high)


class MLPCritic(TwinCritic):
    """Twin Q over two independent :class:`FlatEncoder`."""

    def __init__(self, agent_limit: int = SEED_AGENT_LIMIT, num_features: int = len(NODE_FEATURES),
                 hidden: int = HIDDEN, head_hidden: int = HEAD_HIDDEN, action_low: Sequence[float] = ACTION_LOW,
                 action_high: Sequence[float] = ACTION_HIGH):
        super().__init__(FlatEncoder(agent_limit, num_features, hidden), FlatEncoder(agent_limit, num_features, hidden),
                         hidden, head_hidden, action_low, action_high)


def make_actor(*, agent_limit: int = SEED_AGENT_LIMIT, num_features: int = len(NODE_FEATURES),
               hidden: int = HIDDEN, head_hidden: int = HEAD_HIDDEN, action_low: Sequence[float] = ACTION_LOW,
               action_high: Sequence[float] = ACTION_HIGH) -> MLPActor:
    """The MLP actor, in evaluation mode (load a state_dict into it)."""
    return MLPActor(agent_limit, num_features, hidden, head_hidden, action_low, action_high).eval()


def make_critic(*, agent_limit: int = SEED_AGENT_LIMIT, num_features: int = len(NODE_FEATURES),
                hidden: int = HIDDEN, head_hidden: int = HEAD_HIDDEN, action_low: Sequence[float] = ACTION_LOW,
                action_high: Sequence[float] = ACTION_HIGH) -> MLPCritic:
    return MLPCritic(agent_limit, num_features, hidden, head_hidden, action_low, action_high)


def parameter_count(module: nn.Module) -> int:
    return sum(p.numel() for p in module.parameters())

