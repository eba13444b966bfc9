"""A compact vectorised planning model over the l5kit-keyed batch.

It reads only what the closed loop can honestly provide at time t: the ego's
history (positions, yaws, availabilities, ``speed``) and the other agents'
histories (positions, yaws, extents, availability, type), all in the ego
frame.  ``centroid``/``yaw`` (world pose) are deliberately not read: a model
keyed on where the generated road happens to lie would not transfer to a real
log.  Traffic lights are not in the batch either, so stopping for a red light
has to be inferred from the traffic (queued cars, crossing traffic).

Architecture (``d`` = width):

* ego token: MLP over the flattened ego history (11 x [x, y, cos, sin, avail])
  and speed;
* agent tokens: the same MLP shape over each agent's flattened history
  (11 x [x, y, cos, sin, length, width, avail]) plus its current velocity,
  plus a learned embedding of its coarse class (vehicle, two-wheeler, ...);
* ``layers`` pre-norm transformer blocks over [ego, agents...] with a key
  padding mask for empty slots (the ego token is never masked, so every row
  has at least one key);
* head: MLP from the ego token to F x (dx, dy, dyaw) per-step increments,
  summed along the horizon, so the trajectory is continuous by construction
  and the first pose (the only one the closed loop executes) is a small,
  well-scaled number.

Output: ``{"positions": (B, F, 2), "yaws": (B, F, 1)}`` in the ego frame.
Compiles with ``torch.jit.script``.
"""
from __future__ import annotations

from typing import Dict

import torch
from torch import Tensor, nn

__all__ = ["PlanningModel"]

# Feature scales: inputs of order one keep the first layers well conditioned.
_POS_SCALE = 10.0
_EXT_SCALE = 5.0
_SPEED_SCALE = 10.0
# l5kit label index -> coarse class: 0 none/unknown, 1 vehicle, 2 two-wheeler,
# 3 pedestrian, 4 animal.  The generated training scenes only hold CAR,
# CYCLIST and PEDESTRIAN; a van or a motorcyclist in a real log must land on a
# trained embedding row, not on an untrained one.
_COARSE_TYPE = (0, 0, 0, 1, 1, 1, 1, 1, 1, 1, 2, 2, 2, 2, 3, 4, 0)


def _mlp(inp: int, hidden: int, out: int) -> nn.Sequential:
    return nn.Sequential(nn.Linear(inp, hidden), nn.GELU(), nn.Linear(hidden, out))


class _Block(nn.Module):
    """Pre-norm self-attention + feed-forward."""

    def __init__(self, d: int, heads: int, ffn: int):
        super().__init__()
        self.norm1 = nn.LayerNorm(d)
        self.attn = nn.MultiheadAttention(d, heads, batch_first=True)
        self.norm2 = nn.LayerNorm(d)
        self.ffn = _mlp(d, ffn, d)

    def forward(self, x: Tensor, pad: Tensor) -> Tensor:
        h = self.norm1(x)
        x = x + self.attn(h, h, h, key_padding_mask=pad, need_weights=False)[0]
        return x + self.ffn(self.norm2(x))


class PlanningModel(nn.Module):
    def __init__(self, history_frames: int = 10, future_frames: int = 12, d: int = 128, layers: int = 2,
                 heads: int = 4, ffn: int = 256):
        super().__init__()
        self.history_frames = history_frames
        self.future_frames = future_frames
        # Copied onto the instance: TorchScript cannot read module-level floats.
        self.pos_scale, self.ext_scale, self.speed_scale = _POS_SCALE, _EXT_SCALE, _SPEED_SCALE
        steps = history_frames + 1
        self.ego_enc = _mlp(steps * 5 + 1, d, d)
        self.agent_enc = _mlp(steps * 7 + 2, d, d)
        self.register_buffer("type_map", torch.tensor(_COARSE_TYPE, dtype=torch.long))
        self.type_emb = nn.Embedding(max(_COARSE_TYPE) + 1, d)
        # Tells the attention which token is the ego: without it ego and agent
        # tokens share no marker beyond what the MLPs happen to learn.
        self.ego_tag = nn.Parameter(torch.zeros(d))
        self.blocks = nn.ModuleList([_Block(d, heads, ffn) for _ in range(layers)])
        self.norm = nn.LayerNorm(d)
        self.head = _mlp(2 * d, d, future_frames * 3)
        # Small initial increments: training starts near "stand still", not at random metres.
        nn.init.zeros_(self.head[2].weight)
        nn.init.zeros_(self.head[2].bias)

    def forward(self, data: Dict[str, Tensor]) -> Dict[str, Tensor]:
        h = self.history_frames + 1
        pos = data["history_positions"][:, :h]
        yaw = data["history_yaws"][:, :h, 0]
        avail = data["history_availabilities"][:, :h]
        b = pos.shape[0]
        ego = torch.cat([pos / self.pos_scale, torch.cos(yaw)[..., None] * avail[..., None],
                         torch.sin(yaw)[..., None], avail[..., None]], -1).reshape(b, h * 5)
        ego = torch.cat([ego, data["speed"].reshape(b, 1) / self.speed_scale], -1)
        ego_tok = self.ego_enc(ego) + self.ego_tag

        a_pos = data["all_other_agents_history_positions"][:, :, :h]
        a_yaw = data["all_other_agents_history_yaws"][:, :, :h, 0]
        a_ext = data["all_other_agents_history_extents"][:, :, :h]
        a_ok = data["all_other_agents_history_availability"][:, :, :h]
        n = a_pos.shape[1]
        m = a_ok[..., None]
        feats = torch.cat([a_pos / self.pos_scale, torch.cos(a_yaw)[..., None] * m, torch.sin(a_yaw)[..., None] * m,
                           a_ext / self.ext_scale, m], -1).reshape(b, n, h * 7)
        # Velocity over the last step, only where both frames are seen: the
        # cue that a car ahead is braking or queued.
        both = (a_ok[:, :, 0] * a_ok[:, :, 1])[..., None]
        vel = (a_pos[:, :, 0] - a_pos[:, :, 1]) * both
        agent_tok = self.agent_enc(torch.cat([feats, vel], -1))
        types = data["all_other_agents_types"].long().clamp(0, self.type_map.shape[0] - 1)
        agent_tok = agent_tok + self.type_emb(self.type_map[types])

        x = torch.cat([ego_tok[:, None], agent_tok], 1)
        pad = torch.cat([torch.zeros(b, 1, dtype=torch.bool, device=x.device), a_ok.sum(-1) <= 0], 1)
        for block in self.blocks:
            x = block(x, pad)
        x = self.norm(x)
        # Ego token after attention plus its own encoding: the head keeps direct
        # access to the ego's kinematics, which dominate the first step.
        out = self.head(torch.cat([x[:, 0], ego_tok], -1)).reshape(b, self.future_frames, 3)
        steps_xy = out[..., :2]
        positions = torch.cumsum(steps_xy, 1)
        yaws = torch.cumsum(out[..., 2:3] * 0.1, 1)
        return {"positions": positions, "yaws": yaws}
