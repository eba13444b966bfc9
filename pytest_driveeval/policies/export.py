"""Saving a model as a ``torch.export`` program (``.pt2``), the format the shipped models use.

TorchScript is deprecated in the torch we pin; an exported program, like a TorchScript archive,
carries its graph and weights and runs no Python of ours when loaded (``policies.loading``).
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

from .pt2_archive import load_exported_program

__all__ = ["export_program"]


def _every_dim_free(example: Any) -> Any:
    """``dynamic_shapes`` letting torch decide each dimension: the batch, the agents and the
    history stay free wherever the model allows it, and what it fixes (the channels, the
    observation width) is checked on every call."""
    import torch

    if isinstance(example, torch.Tensor):
        # A dimension of one in the example (a yaw's last axis) is taken as fixed: give examples
        # of two rows or more, or the batch would be fixed too.
        return {axis: torch.export.Dim.AUTO for axis, size in enumerate(example.shape) if size > 1}
    if isinstance(example, dict):
        return {key: _every_dim_free(value) for key, value in example.items()}
    if isinstance(example, (list, tuple)):
        return type(example)(_every_dim_free(value) for value in example)
    return None


def export_program(model: Any, example_args: tuple, path: Path) -> Any:
    """Export ``model`` (an ``nn.Module`` in eval mode) traced on ``example_args`` and save it to
    ``path``; returns the loaded program's module, which is what ``load_model(path)`` gives."""
    import torch

    model.eval()
    with torch.no_grad():
        program = torch.export.export(model, example_args, dynamic_shapes=_every_dim_free(example_args))
    # The example batch would travel inside the file (the raster model's images: 2.5 MB).
    program.example_inputs = None
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    torch.export.save(program, str(path))
    return load_exported_program(path).module()
