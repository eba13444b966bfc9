"""``Inputs: raster``: l5kit's bird's-eye raster in the policy's batch, drawn each step.

The engine asks for extra inputs at every step (``unroll(extra_inputs=...)``);
this gives it ``image``, drawn by :class:`pytest_driveeval.raster.Rasterizer`
from the ego's driven history and the agents where the engine has them: the
log, or with reactive agents its copy in which they braked (the label filter
and the traffic-light faces are read from the scenes the log was stacked from,
so they must be those).
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from pytest_driveeval.core.errors import DataError

__all__ = ["KEPT_MAPS", "load_semantic_map", "raster_inputs", "semantic_map_files", "semantic_map_for"]

#: semantic maps a process keeps for its next chunks (a full-size one is large)
KEPT_MAPS = 2


def raster_inputs(params: Any, log: Any, scenes: Sequence[Any], semantic_map: Any = None) -> Callable:
    """The engine's ``extra_inputs`` for rasters with ``params`` (raster.RasterParams)."""
    import torch

    from pytest_driveeval.raster import Rasterizer

    if params.map_type == "py_semantic" and semantic_map is None:
        raise DataError("Inputs: raster with MapType py_semantic needs the dataset's semantic map")
    raster = Rasterizer(params, log, scenes=scenes, semantic_map=semantic_map)
    # Drawn in place step after step while no earlier image is alive: a fresh (B, C, H, W) array each
    # step costs more in page faults than the drawing.  A policy that keeps its inputs (or a view of
    # them) keeps the canvas busy, and the next step draws on a new one.
    canvas = [raster.canvas(log.shape[0])]

    def inputs(rows: np.ndarray, t: int, driven_xy: np.ndarray, driven_yaw: np.ndarray, agents: Any = None) -> dict:
        if agents is not None and agents is not log:
            # Reactive agents: the engine's own copy of the log, where they moved.  Frame t is final
            # by now (the step before wrote it) and earlier frames were refreshed when they were t.
            raster.boxes.refresh(agents, rows, t)
        if not canvas[0].free or canvas[0].capacity < rows.size:
            canvas[0] = raster.canvas(max(rows.size, 1))
        return {"image": torch.from_numpy(raster(rows, np.full(rows.size, t), driven_xy, driven_yaw, out=canvas[0]))}

    return inputs


def semantic_map_files(dataset_path: str | os.PathLike, pb: str | None = None, meta: str | None = None,
                       folder: str | os.PathLike | None = None) -> tuple[Path, Path]:
    """The ``.pb`` and ``meta.json`` :func:`load_semantic_map` reads."""
    beside = Path(dataset_path).parent
    base = Path(folder) if folder is not None else Path.cwd()
    return (base / pb if pb else beside / "semantic_map.pb", base / meta if meta else beside / "meta.json")


def load_semantic_map(dataset_path: str | os.PathLike, pb: str | None = None, meta: str | None = None,
                      folder: str | os.PathLike | None = None) -> Any:
    """The semantic map of a dataset: ``pb`` / ``meta`` (relative to ``folder``, the scenario's),
    by default ``semantic_map.pb`` and ``meta.json`` beside the dataset, as l5kit lays them out."""
    from pytest_driveeval.io.l5.l5_semantic_map import read_semantic_map

    pb_path, meta_path = semantic_map_files(dataset_path, pb, meta, folder)
    for path, key in ((pb_path, "SemanticMap"), (meta_path, "Meta")):
        if not path.is_file():
            raise DataError(f"{path}: no such file (the semantic map of {dataset_path} for Inputs: raster, "
                            f"MapType py_semantic, or Inputs.Map; give Inputs.{key} to point elsewhere)")
    semantic_map = read_semantic_map(pb_path, meta_path)
    if len(semantic_map.lane_ids) == 0 and len(semantic_map.crosswalk_ids) == 0:
        # An empty message decodes as an empty map; the rasters would show no road and no error.
        raise DataError(f"{pb_path}: the semantic map holds no lanes and no crosswalks "
                        f"({pb_path.stat().st_size} bytes), so it cannot be the map of {dataset_path} "
                        "that Inputs: raster with MapType py_semantic draws; give Inputs.SemanticMap to point at "
                        "the dataset's map, or MapType: box_debug for rasters without one")
    return semantic_map


def semantic_map_for(inputs: Any, dataset_path: str | os.PathLike, folder: str | os.PathLike,
                     dataset: Any = None, ids: Any = None, *, kept: bool = False) -> Any:
    """The semantic map an ``Unroll.Inputs`` section needs (``py_semantic`` rasters, ``Map``), else None.  A
    dataset that carries its own map per scene (ScenarioNet) gives it for the scenes ``ids``.
    ``kept``: a chunk's map, which the next chunks in this process that name the same unchanged
    files get without reading them again (the map is only read, never written, by the rasters)."""
    raster = inputs.Kind == "raster" and inputs.MapType == "py_semantic"
    if not raster and getattr(inputs, "Map", None) is None:
        return None
    own = getattr(dataset, "semantic_map", None)
    if own is not None:
        # map inputs read each scene's own map (closed_loop.map_inputs.places); a raster draws one
        return own(list(ids)) if raster else None
    args = (dataset_path, inputs.SemanticMap, inputs.Meta, folder)
    if not kept:
        return load_semantic_map(*args)
    from pytest_driveeval.execute.reuse import reused

    key = tuple(str(a) if a is not None else None for a in args)
    return reused("semantic map", key, semantic_map_files(*args), lambda: load_semantic_map(*args), keep=KEPT_MAPS)
