"""Reading what the policy returned: l5kit's planning output, checked.

A policy is anybody's code; whatever it returns, the engine needs a message
that says what was expected and what came instead, so a broken model fails
its scenes clearly instead of taking the harness down.
"""
from __future__ import annotations

from typing import Mapping

import numpy as np
import torch

__all__ = ["BadPolicyOutput", "first_pose", "format_scenes"]


class BadPolicyOutput(Exception):
    """The policy's output is not ``{"positions": (B, T, 2), "yaws": (B, T, 1)}`` float tensors."""


def format_scenes(ids: np.ndarray) -> str:
    ids = [int(i) for i in ids]
    return str(ids) if len(ids) <= 20 else f"[{', '.join(map(str, ids[:20]))}, ... ({len(ids)} scenes)]"


def first_pose(out: object, rows: int) -> tuple[np.ndarray, np.ndarray]:
    """First predicted pose (B, 2), (B,) from a model output, or BadPolicyOutput saying why not."""
    if not isinstance(out, Mapping):
        raise BadPolicyOutput(f"expected a dict with 'positions' (B={rows}, T, 2) and 'yaws' (B={rows}, T, 1) "
                              f"float tensors, found {type(out).__name__}")
    got = {}
    for key, last in (("positions", 2), ("yaws", 1)):
        value = out.get(key)
        want = f"'{key}' as a float tensor of shape (B={rows}, T, {last})"
        if value is None:
            raise BadPolicyOutput(f"expected {want}, found no '{key}' key (keys: {sorted(map(str, out))})")
        if not torch.is_tensor(value) or not value.is_floating_point():
            kind = f"a {value.dtype} tensor" if torch.is_tensor(value) else type(value).__name__
            raise BadPolicyOutput(f"expected {want}, found {kind}")
        shape = tuple(value.shape)
        if len(shape) != 3 or shape[0] != rows or shape[1] < 1 or shape[2] != last:
            raise BadPolicyOutput(f"expected {want}, found shape {shape}")
        got[key] = value[:, 0].detach().to("cpu", torch.float64).numpy()
    return got["positions"], got["yaws"][:, 0]
