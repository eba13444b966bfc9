"""A small CNN planning model over l5kit-style bird's-eye rasters.

The seed's kind of model: l5kit's raster planning models read only
``data["image"]`` (channels first: the agents' and the ego's boxes for each
history frame, then, with ``py_semantic``, the map's three colour
channels) and predict the future poses in the ego frame.  l5kit uses a
ResNet-50; on one CPU core that would cost ~4 GFLOP per scene-step, so this
one is a few strided convolutions (about 12 MFLOP per 112 x 112 raster),
enough for the generated roads and the demo's time budget.

Architecture: a 4 x 4 stride-4 "patchify" convolution, then two 3 x 3
stride-2 convolutions with batch norm and GELU, flattened (the position of
things in the raster is the signal: no global pooling), an MLP to
``future_frames`` x (dx, dy, dyaw) increments summed along the horizon (as
the vector model does, so the first pose is a small, well-scaled number).

Output: ``{"positions": (B, F, 2), "yaws": (B, F, 1)}`` in the ego frame.
Compiles with ``torch.jit.script``.
"""
from __future__ import annotations

from typing import Dict

import torch
from torch import Tensor, nn

__all__ = ["RasterPlanningModel"]


def _conv(inp: int, out: int, kernel: int, stride: int) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(inp, out, kernel, stride, padding=(kernel - stride + 1) // 2, bias=False),
                         nn.BatchNorm2d(out), nn.GELU())


class RasterPlanningModel(nn.Module):
    def __init__(self, in_channels: int, raster_size: int = 112, future_frames: int = 12, width: int = 32,
                 hidden: int = 256):
        super().__init__()
        if raster_size % 16:
            raise ValueError(f"raster_size {raster_size}: must be a multiple of 16 (a stride-4 then two stride-2 "
                             "convolutions)")
        self.in_channels = in_channels
        self.future_frames = future_frames
        self.features = nn.Sequential(
            _conv(in_channels, width, 4, 4),
            _conv(width, 2 * width, 3, 2),
            _conv(2 * width, 2 * width, 3, 2),
        )
        side = raster_size // 16
        self.head = nn.Sequential(nn.Flatten(), nn.Linear(2 * width * side * side, hidden), nn.GELU(),
                                  nn.Linear(hidden, future_frames * 3))
        # Small initial increments: training starts near "stand still", not at random metres.
        nn.init.zeros_(self.head[3].weight)
        nn.init.zeros_(self.head[3].bias)

    def forward(self, data: Dict[str, Tensor]) -> Dict[str, Tensor]:
        image = data["image"]
        if image.shape[1] != self.in_channels:
            raise ValueError(f"image has {image.shape[1]} channels, the model was built for {self.in_channels}")
        out = self.head(self.features(image)).reshape(image.shape[0], self.future_frames, 3)
        positions = torch.cumsum(out[..., :2], 1)
        yaws = torch.cumsum(out[..., 2:3] * 0.1, 1)
        return {"positions": positions, "yaws": yaws}
