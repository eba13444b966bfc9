"""A GNN actor and twin critic for SAC over the flat graph observation of :mod:`.graph`.

Message passing (seed 002, chapter 3): each round sends node j's message to
node i along every edge, ``MLP([h_j, e_ij])`` with one hidden ReLU layer,
sums them at i and updates i with a gated residual (GRU-like)
``h_i + z * (tanh(c / 2) - h_i)``, ``z, c`` linear in ``[h_i, m_i]``.  Only the ego's
embedding leaves the encoder (the seed's actor reads node 0), so the last
round computes the ego's messages alone.

Why it is fast on a CPU: graphs have at most K (12) nodes, so every round is
dense over (B, K, K) pairs, with no gather or scatter.  The edge features are
node differences (``e_ij = P n_i - P n_j``), so the message's first layer
splits into a sender part and a receiver part added by broadcasting; missing
edges add ``-1e30`` before the ReLU, which masks them without a multiply, and
the pair tensor is made once and then changed in place.  Padded nodes lose
their edges, so no finite value they hold reaches the output.  The message's
second layer is folded into the node update (see ``MessageRound.updated``).

The squashed Gaussian head (:class:`SquashedGaussianActor`) and the twin Q heads
(:class:`TwinCritic`) take the encoder as a part, so :mod:`.mlp`'s flat-vector actor and critic
are the same code with another encoder.

Everything here compiles with ``torch.jit.script``; weights load with
``weights.pt=pytest_driveeval.policies.gnn:make_actor``.  float32 or float64:
float16 cannot hold the ``1e30``.
"""
from __future__ import annotations

import math
from collections.abc import Sequence

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from .graph import (
    EDGE_FEATURES,
    EDGE_SOURCE_COLUMNS,
    NODE_FEATURES,
    SEED_AGENT_LIMIT,
    check_agent_limit,
    observation_size,
    split_flat,
)

__all__ = ["GNNActor", "GNNCritic", "GraphEncoder", "MessageRound", "NodeScaling", "SquashedGaussianActor",
           "TwinCritic", "check_flat", "make_actor", "make_critic"]

# The shipped configuration: widths chosen to pass 200k observations/s at batch 256 on one core.
HIDDEN = 32
MESSAGE_HIDDEN = 16
ROUNDS = 2
HEAD_HIDDEN = 64
# BARK-ML's BehaviorContinuousML bounds: acceleration (m/s^2), steering (rad).
ACTION_LOW = (-5.0, -0.2)
ACTION_HIGH = (4.0, 0.2)
LOG_STD_MIN, LOG_STD_MAX = -5.0, 2.0


def check_flat(flat: Tensor, agent_limit: int, num_features: int, size: int) -> None:
    """Refuse flat observations of another width or whose header names another K or F."""
    if flat.dim() != 2 or flat.shape[1] != size:
        raise ValueError(f"flat observations: expected shape (B, {size}) for K="
                         f"{agent_limit}, F={num_features}, found {list(flat.shape)}")
    header_ok = (flat[:, 0] == agent_limit).all() & (flat[:, 2] == num_features).all()
    header_error = f"flat observations: header [K, n, F] does not say K={agent_limit}, F={num_features}"
    if torch.jit.is_scripting():
        if not bool(header_ok):
            raise ValueError(header_error)
    elif torch.compiler.is_exporting():
        # An exported program cannot branch on values: the check becomes an op that fails the call.
        torch._assert_async(header_ok, header_error)
    elif not bool(header_ok):
        raise ValueError(header_error)


class NodeScaling(nn.Module):
    """Standardises the features of the nodes in use, ``(x - shift) / scale`` per feature, the same
    for every node (so the GNN stays invariant to the order of the others).  The observation is
    normalised by the whole map's extent, which at the intersection leaves a metre at 0.005: too fine
    for a small network to resolve where the turn starts.  The training script sets ``shift`` and
    ``scale`` from the expert's states; they travel with the weights.  The default, and weights saved
    before these buffers existed, leave the features as they are."""

    def __init__(self, num_features: int):
        super().__init__()
        self.register_buffer("shift", torch.zeros(num_features))
        self.register_buffer("scale", torch.ones(num_features))

    def forward(self, nodes: Tensor, mask: Tensor) -> Tensor:
        return torch.where(mask.unsqueeze(-1), (nodes - self.shift) / self.scale, nodes)

    def _load_from_state_dict(self, state_dict, prefix, *args, **kwargs):
        for name, identity in (("shift", torch.zeros_like(self.shift)), ("scale", torch.ones_like(self.scale))):
            state_dict.setdefault(prefix + name, identity)
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)


class MessageRound(nn.Module):
    def __init__(self, hidden: int, message_hidden: int):
        super().__init__()
        self.sender = nn.Linear(hidden, message_hidden)
        self.edge = nn.Linear(len(EDGE_FEATURES), message_hidden, bias=False)
        self.message = nn.Linear(message_hidden, hidden)
        self.update = nn.Linear(2 * hidden, 2 * hidden)

    def halves(self, h: Tensor, rel: Tensor) -> tuple[Tensor, Tensor]:
        """The first message layer as sender term (of h_j, n_j) + receiver term (of n_i)."""
        receiver = self.edge(rel)
        return self.sender(h) - receiver, receiver

    def all_nodes(self, h: Tensor, rel: Tensor, blocked: Tensor, degree: Tensor) -> Tensor:
        sender, receiver = self.halves(h, rel)
        pairs = torch.add(sender.unsqueeze(1), receiver.unsqueeze(2))  # (B, i, j, M)
        pairs.add_(blocked.unsqueeze(-1)).relu_()
        return self.updated(h, pairs.sum(2), degree)

    def ego(self, h: Tensor, rel: Tensor, blocked: Tensor, degree: Tensor) -> Tensor:
        sender, receiver = self.halves(h, rel)
        pairs = torch.add(sender, receiver[:, :1]).add_(blocked[:, 0].unsqueeze(-1)).relu_()  # (B, j, M)
        return self.updated(h[:, 0], pairs.sum(1), degree[:, 0])

    def updated(self, h: Tensor, hidden_sum: Tensor, degree: Tensor) -> Tensor:
        # The message's second layer is linear, so it applies once to the sum over edges (its bias
        # once per edge), and folds into the update's message half: one matmul over [h_i, sum]
        # instead of two, a third fewer multiply-adds in the costliest step.
        width = h.shape[-1]
        on_message = self.update.weight[:, width:]
        weight = torch.cat([self.update.weight[:, :width], on_message.mm(self.message.weight)], dim=1)
        pre = F.linear(torch.cat([h, hidden_sum], dim=-1), weight, self.update.bias)
        pre = pre + degree * on_message.mv(self.message.bias)
        # One sigmoid for gate and candidate: 2 sigmoid(c) - 1 is tanh(c / 2), and torch's CPU
        # sigmoid is several times faster than its tanh.
        gate, candidate = torch.sigmoid(pre).chunk(2, dim=-1)
        return h + gate * (2.0 * candidate - 1.0 - h)


class GraphEncoder(nn.Module):
    """Flat observations (B, 3 + K*F + K*K) -> the ego's embedding (B, hidden)."""

    def __init__(self, agent_limit: int = SEED_AGENT_LIMIT, num_features: int = len(NODE_FEATURES),
                 hidden: int = HIDDEN, message_hidden: int = MESSAGE_HIDDEN, rounds: int = ROUNDS):
        super().__init__()
        check_agent_limit(agent_limit)
        if rounds < 1:
            raise ValueError(f"rounds must be at least 1, got {rounds}")
        if num_features <= max(EDGE_SOURCE_COLUMNS):
            raise ValueError(f"num_features must be at least {max(EDGE_SOURCE_COLUMNS) + 1} "
                             f"(edge features read x, y, theta, vel), got {num_features}")
        self.agent_limit = agent_limit
        self.num_features = num_features
        self.observation_size = observation_size(agent_limit, num_features)
        self.hidden = hidden
        self.scaling = NodeScaling(num_features)
        self.embed = nn.Linear(num_features, hidden)
        self.inner = nn.ModuleList([MessageRound(hidden, message_hidden) for _ in range(rounds - 1)])
        self.last = MessageRound(hidden, message_hidden)
        self.register_buffer("edge_columns", torch.tensor(EDGE_SOURCE_COLUMNS), persistent=False)

    def forward(self, flat: Tensor) -> Tensor:
        check_flat(flat, self.agent_limit, self.num_features, self.observation_size)
        nodes, adjacency, mask = split_flat(flat, self.agent_limit, self.num_features)
        return self.ego_embedding(self.scaling(nodes, mask), adjacency, mask)

    def ego_embedding(self, nodes: Tensor, adjacency: Tensor, mask: Tensor) -> Tensor:
        # Padded nodes keep whatever they hold: with no edges, no finite value of theirs reaches a real node.
        in_use = mask.to(nodes.dtype)
        linked = (adjacency > 0).to(nodes.dtype) * in_use.unsqueeze(1) * in_use.unsqueeze(2)
        # Finite, not -inf, so one multiply makes it: no pre-activation comes near 1e30.
        blocked = (linked - 1.0) * 1e30
        degree = linked.sum(dim=-1, keepdim=True)
        rel = nodes.index_select(-1, self.edge_columns)
        h = torch.relu(self.embed(nodes))
        for layer in self.inner:
            h = layer.all_nodes(h, rel, blocked, degree)
        return self.last.ego(h, rel, blocked, degree)


def mlp(inputs: int, hidden: int, outputs: int) -> nn.Sequential:
    return nn.Sequential(nn.Linear(inputs, hidden), nn.ReLU(), nn.Linear(hidden, hidden), nn.ReLU(),
                         nn.Linear(hidden, outputs))


def _bounds(low: Sequence[float], high: Sequence[float]) -> tuple[Tensor, Tensor]:
    low_t, high_t = torch.tensor(low, dtype=torch.float32), torch.tensor(high, dtype=torch.float32)
    if low_t.dim() != 1 or low_t.shape != high_t.shape or not bool((low_t < high_t).all()):
        raise ValueError(f"action bounds must be two equal-length lists with low < high, got {low}, {high}")
    return (high_t + low_t) / 2, (high_t - low_t) / 2


class SquashedGaussianActor(nn.Module):
    """Squashed Gaussian policy over an encoder's embedding: ``forward`` is the deterministic
    action for evaluation.  The GNN and MLP actors differ only in ``encoder`` (flat observation
    -> (B, features)), so the head, squashing and log-density are this one implementation."""

    def __init__(self, encoder: nn.Module, features: int, head_hidden: int, action_low: Sequence[float],
                 action_high: Sequence[float]):
        super().__init__()
        center, half = _bounds(action_low, action_high)
        self.encoder = encoder
        self.head = mlp(features, head_hidden, 2 * center.shape[0])
        self.log_std_min, self.log_std_max = LOG_STD_MIN, LOG_STD_MAX
        # In the state_dict, so trained weights travel with the bounds they were trained for.
        self.register_buffer("action_center", center)
        self.register_buffer("action_half_range", half)

    def distribution(self, flat: Tensor) -> tuple[Tensor, Tensor]:
        """Mean and log standard deviation of the Gaussian before tanh, (B, 2) each."""
        mean, raw = self.head(self.encoder(flat)).chunk(2, dim=-1)
        log_std = self.log_std_min + 0.5 * (self.log_std_max - self.log_std_min) * (torch.tanh(raw) + 1.0)
        return mean, log_std

    def forward(self, flat: Tensor) -> Tensor:
        mean = self.head(self.encoder(flat))[:, :self.action_center.shape[0]]
        return self.action_center + self.action_half_range * torch.tanh(mean)

    @torch.jit.export
    def sample(self, flat: Tensor) -> tuple[Tensor, Tensor]:
        """A reparameterised action (B, 2) and its log-density (B,) in action space."""
        mean, log_std = self.distribution(flat)
        noise = torch.randn_like(mean)
        pre_tanh = mean + log_std.exp() * noise
        action = self.action_center + self.action_half_range * torch.tanh(pre_tanh)
        gaussian = -0.5 * noise.pow(2) - log_std - 0.5 * math.log(2.0 * math.pi)
        # log |d action / d pre_tanh|, with log(1 - tanh(u)^2) written to stay finite for large |u|.
        squash = torch.log(self.action_half_range) + 2.0 * (math.log(2.0) - pre_tanh - F.softplus(-2.0 * pre_tanh))
        return action, (gaussian - squash).sum(dim=-1)


class TwinCritic(nn.Module):
    """Twin Q: two independent encoder + MLP pairs over ``[embedding, action scaled to [-1, 1]]``."""

    def __init__(self, encoder1: nn.Module, encoder2: nn.Module, features: int, head_hidden: int,
                 action_low: Sequence[float], action_high: Sequence[float]):
        super().__init__()
        center, half = _bounds(action_low, action_high)
        actions = center.shape[0]
        self.encoder1 = encoder1
        self.encoder2 = encoder2
        self.q1 = mlp(features + actions, head_hidden, 1)
        self.q2 = mlp(features + actions, head_hidden, 1)
        self.register_buffer("action_center", center)
        self.register_buffer("action_half_range", half)

    def forward(self, flat: Tensor, action: Tensor) -> tuple[Tensor, Tensor]:
        """Q1 and Q2, (B,) each."""
        if action.dim() != 2 or action.shape[1] != self.action_center.shape[0]:
            raise ValueError(f"action: expected shape (B, {self.action_center.shape[0]}), found {list(action.shape)}")
        scaled = (action - self.action_center) / self.action_half_range
        q1 = self.q1(torch.cat([self.encoder1(flat), scaled], dim=-1)).squeeze(-1)
        q2 = self.q2(torch.cat([self.encoder2(flat), scaled], dim=-1)).squeeze(-1)
        return q1, q2


class GNNActor(SquashedGaussianActor):
    """The squashed Gaussian policy over the message-passing encoder's ego embedding."""

    def __init__(self, agent_limit: int = SEED_AGENT_LIMIT, num_features: int = len(NODE_FEATURES),
                 hidden: int = HIDDEN, message_hidden: int = MESSAGE_HIDDEN, rounds: int = ROUNDS,
                 head_hidden: int = HEAD_HIDDEN, action_low: Sequence[float] = ACTION_LOW,
                 action_high: Sequence[float] = ACTION_HIGH):
        super().__init__(GraphEncoder(agent_limit, num_features, hidden, message_hidden, rounds), hidden,
                         head_hidden, action_low, action_high)


class GNNCritic(TwinCritic):
    """Twin Q over two independent message-passing encoders."""

    def __init__(self, agent_limit: int = SEED_AGENT_LIMIT, num_features: int = len(NODE_FEATURES),
                 hidden: int = HIDDEN, message_hidden: int = MESSAGE_HIDDEN, rounds: int = ROUNDS,
                 head_hidden: int = HEAD_HIDDEN, action_low: Sequence[float] = ACTION_LOW,
                 action_high: Sequence[float] = ACTION_HIGH):
        super().__init__(GraphEncoder(agent_limit, num_features, hidden, message_hidden, rounds),
                         GraphEncoder(agent_limit, num_features, hidden, message_hidden, rounds), hidden,
                         head_hidden, action_low, action_high)


def make_actor(*, agent_limit: int = SEED_AGENT_LIMIT, num_features: int = len(NODE_FEATURES),
               hidden: int = HIDDEN, message_hidden: int = MESSAGE_HIDDEN, rounds: int = ROUNDS,
               head_hidden: int = HEAD_HIDDEN, action_low: Sequence[float] = ACTION_LOW,
               action_high: Sequence[float] = ACTION_HIGH) -> GNNActor:
    """The shipped actor, in evaluation mode (load a state_dict into it)."""
    return GNNActor(agent_limit, num_features, hidden, message_hidden, rounds, head_hidden, action_low,
                    action_high).eval()


def make_critic(*, agent_limit: int = SEED_AGENT_LIMIT, num_features: int = len(NODE_FEATURES),
                hidden: int = HIDDEN, message_hidden: int = MESSAGE_HIDDEN, rounds: int = ROUNDS,
                head_hidden: int = HEAD_HIDDEN, action_low: Sequence[float] = ACTION_LOW,
                action_high: Sequence[float] = ACTION_HIGH) -> GNNCritic:
    return GNNCritic(agent_limit, num_features, hidden, message_hidden, rounds, head_hidden, action_low,
                     action_high)
