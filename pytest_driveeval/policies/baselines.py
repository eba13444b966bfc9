"""Reference policies: constant velocity and log replay.

Both are ``torch.nn.Module`` taking the batch of
:mod:`pytest_driveeval.sim.logreplay.inputs` and returning l5kit's planning output,
``{"positions": (B, F, 2), "yaws": (B, F, 1)}`` in the ego frame, and both
compile with ``torch.jit.script``.
"""
from __future__ import annotations

from typing import Dict

import torch
from torch import Tensor, nn

__all__ = ["ConstantVelocityPolicy", "ReplayLogPolicy"]


class ConstantVelocityPolicy(nn.Module):
    """Keep the last step's displacement and heading: a straight line at constant speed.

    The step is ``history_positions[:, 0] - history_positions[:, 1]`` (one
    frame back).  Where there is no past (a scene's first frame) it is, with
    ``first_step="heading"``, ``speed`` along the heading, or with
    ``"logged_next"`` the step to the logged next position
    (``target_positions[:, 0]``), which is where a constant-velocity model
    in l5kit's closed loop starts: its ``speed`` input comes from that
    position.  It never brakes, so it runs red lights and into whatever
    stops ahead: the baseline every real policy must beat.
    """

    FIRST_STEPS = ("heading", "logged_next")

    def __init__(self, future_frames: int = 12, step_time: float = 0.1, first_step: str = "heading"):
        super().__init__()
        if first_step not in self.FIRST_STEPS:
            raise ValueError(f"first_step must be one of {', '.join(self.FIRST_STEPS)}, not {first_step!r}")
        self.future_frames = future_frames
        self.step_time = step_time
        self.first_from_log = first_step == "logged_next"

    def forward(self, data: Dict[str, Tensor]) -> Dict[str, Tensor]:
        pos = data["history_positions"]
        avail = data["history_availabilities"]
        has_past = avail[:, 1:2] > 0
        if self.first_from_log:
            ahead = data["target_positions"][:, 0]
        else:
            ahead = torch.zeros_like(pos[:, 0])
            ahead[:, 0] = data["speed"] * self.step_time
        step = torch.where(has_past, pos[:, 0] - pos[:, 1], ahead)
        k = torch.arange(1, self.future_frames + 1, dtype=pos.dtype, device=pos.device)
        positions = pos[:, 0:1] + k[None, :, None] * step[:, None, :]
        yaws = torch.zeros(positions.shape[0], self.future_frames, 1, dtype=pos.dtype, device=pos.device)
        return {"positions": positions, "yaws": yaws}


class ReplayLogPolicy(nn.Module):
    """The oracle: return the logged future (``target_*``) as the prediction.

    Driven by it, a closed-loop unroll reproduces the log up to float32
    rounding, so any collision or drift it reports is a harness bug.
    """

    def forward(self, data: Dict[str, Tensor]) -> Dict[str, Tensor]:
        return {"positions": data["target_positions"], "yaws": data["target_yaws"]}
