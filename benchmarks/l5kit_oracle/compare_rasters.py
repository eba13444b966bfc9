"""Pixel agreement of pytest_driveeval.raster with l5kit 1.5.0's own rasters (issue 14).

l5kit runs in its venv (``oracle_venv.py``, created on first use) through
``rasterize.py``: ``EgoDataset.get_frame`` on each frame, the ego's logged
history.  The same frames are drawn here by
:class:`pytest_driveeval.raster.Rasterizer` from the logged history.  Cases:

* ``real_box``: the real L5 scene, ``box_debug``, 10 history frames;
* ``real_semantic``: the real scene, ``py_semantic``, on a map laid along the
  scene's own path whose faces are the scene's own (``bench_raster.scene_map``:
  no real L5 map of that place is public);
* ``generated_semantic``: generated scenes with the map ``generate_zarr``
  writes beside them, ``py_semantic``, six frames of each of four scenes.

Prints, per case, the pixels compared and how many differ (overall, box
channels, map channels).  Nothing is asserted here; tests/raster/test_l5kit_oracle.py
asserts on :func:`compare`.

    python benchmarks/l5kit_oracle/compare_rasters.py [--size 112] [--cases real_box ...]

On 2026-11-24 (112 x 112, 10 history frames): real_box 0 of 1,655,808
values differ; real_semantic 14 of 1,881,600 (map channels only, 99.9993 %);
generated_semantic 0 of 7,526,400.
"""
from __future__ import annotations

import argparse
import importlib.util
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
REAL_SCENE = ROOT / "fixtures" / "l5kit" / "single_scene.zarr"
CASES = ("real_box", "real_semantic", "generated_semantic")


def _load(name: str, path: Path):
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _ours(zarr: Path, scene_index: int, frames: list[int], params, map_dir: Path | None) -> np.ndarray:
    from pytest_driveeval.io.l5.l5_semantic_map import read_semantic_map
    from pytest_driveeval.io.l5.l5kit_zarr import L5Dataset
    from pytest_driveeval.raster import Rasterizer
    from pytest_driveeval.sim.logreplay import stack_scenes

    scene = L5Dataset.open(zarr).scene(scene_index)
    log = stack_scenes([scene])
    smap = read_semantic_map(map_dir / "semantic_map.pb", map_dir / "meta.json") if map_dir else None
    raster = Rasterizer(params, log, scenes=[scene], semantic_map=smap)
    return raster(np.zeros(len(frames), np.int64), np.asarray(frames), log.ego_xy, log.ego_yaw)


def compare(case: str, python: Path | None = None, size: int = 112, history: int = 10) -> dict:
    """One case's agreement: {pixels, differing, box_differing, map_differing, frames, scenes}."""
    from pytest_driveeval.raster import RasterParams

    oracle = _load("oracle_venv", HERE / "oracle_venv.py")
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        if case == "real_box":
            runs = [(REAL_SCENE, 0, [0, 3, 50, 120, 200, 247], None)]
        elif case == "real_semantic":
            from pytest_driveeval.io.l5.l5_semantic_map import write_semantic_map
            from pytest_driveeval.io.l5.l5kit_zarr import L5Dataset

            bench = _load("bench_raster", ROOT / "benchmarks" / "bench_raster.py")
            smap = bench.scene_map(L5Dataset.open(REAL_SCENE).scene(0))
            write_semantic_map(tmp / "semantic_map.pb", tmp / "meta.json", smap)
            runs = [(REAL_SCENE, 0, [0, 40, 90, 140, 190, 240], tmp)]
        elif case == "generated_semantic":
            from pytest_driveeval.synth.scenegen import generate_zarr

            zarr = generate_zarr(tmp / "gen.zarr", 4, num_frames=150, seed=3)
            runs = [(zarr, s, [0, 30, 60, 90, 120, 149], tmp) for s in range(4)]
        else:
            raise ValueError(f"unknown case {case!r}; one of {CASES}")
        map_type = "box_debug" if case == "real_box" else "py_semantic"
        params = RasterParams(map_type=map_type, raster_size=(size, size), pixel_size=(0.5, 0.5),
                              ego_center=(0.25, 0.5), history_num_frames=history, filter_agents_threshold=0.5)
        totals = dict(pixels=0, differing=0, box_differing=0, map_differing=0, frames=0, scenes=len(runs))
        for i, (zarr, scene_index, frames, map_dir) in enumerate(runs):
            out = tmp / f"oracle_{i}.npz"
            spec = {"mode": "rasterize", "zarr": str(zarr), "map_type": map_type, "raster_size": [size, size],
                    "pixel_size": [0.5, 0.5], "ego_center": [0.25, 0.5], "history_num_frames": history,
                    "filter_agents_threshold": 0.5, "scene_index": scene_index, "frames": frames, "out": str(out)}
            if map_dir is not None:
                spec.update(semantic_map=str(map_dir / "semantic_map.pb"), meta=str(map_dir / "meta.json"))
            oracle.run_rasterize(spec, python=python)
            theirs = np.load(out)["image"]
            ours = _ours(zarr, scene_index, frames, params, map_dir)
            if theirs.shape != ours.shape:
                raise AssertionError(f"{case}: l5kit's images are {theirs.shape}, ours {ours.shape}")
            differ = theirs != ours
            boxes = params.box_channels
            totals["pixels"] += differ.size
            totals["differing"] += int(differ.sum())
            totals["box_differing"] += int(differ[:, :boxes].sum())
            totals["map_differing"] += int(differ[:, boxes:].sum())
            totals["frames"] += len(frames)
        totals["agreement"] = 1.0 - totals["differing"] / max(totals["pixels"], 1)
        return totals


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=112)
    parser.add_argument("--history", type=int, default=10)
    parser.add_argument("--cases", nargs="*", default=list(CASES), choices=CASES)
    args = parser.parse_args()
    sys.path.insert(0, str(ROOT))
    python = _load("oracle_venv", HERE / "oracle_venv.py").oracle_python(quiet=True)
    for case in args.cases:
        result = compare(case, python, args.size, args.history)
        print(json.dumps({"case": case, **result}))


if __name__ == "__main__":
    main()
