"""Rasters and their speed from l5kit 1.5.0 itself, run inside the oracle venv (see oracle_venv.py).

This script must run with the venv's python and import nothing from
pytest_driveeval: it is the independent side of a comparison.  It builds the
rasterizer with l5kit's ``build_rasterizer`` from a cfg dict and asks l5kit's
``EgoDataset`` for the ego's sample at each frame, so the raster, its matrices
and the history slicing are l5kit's own code path.

Two modes (the spec's keys are listed in SPEC_DEFAULTS; README.md documents them):

* ``rasterize``: write an .npz with, per requested frame, the image as
  ``EgoDataset.get_frame`` returns it (N, C, H, W) float32, its RGB rendering,
  the raster/agent/world matrices and the seconds ``rasterizer.rasterize`` took.
* ``time``: rasterize every frame of the scene ``repeats`` times for each map
  type in ``timing_map_types`` and print one JSON line per map type with
  scene-steps/s, for the rasterizer alone and for the whole ``get_frame``.

Usage: ``python rasterize.py --spec spec.json`` or the same keys as flags
(``--zarr X --map-type box_debug --out out.npz``); flags override the file.
"""
from __future__ import annotations

import os

# One core, as every figure of the project is taken: set before numpy/torch/cv2 load their pools.
for _var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import importlib.metadata  # noqa: E402
import json  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402
from pathlib import Path  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402
# l5kit's own harmless warnings (get_scene_dataset's empty-path ChunkedDataset, torch's TypedStorage)
# would bury a real error in the stderr a caller reports.
warnings.filterwarnings("ignore", message="zarr dataset path should end with .zarr")
warnings.filterwarnings("ignore", message="TypedStorage is deprecated")

from l5kit.data import ChunkedDataset, LocalDataManager  # noqa: E402
from l5kit.dataset import EgoDataset  # noqa: E402
from l5kit.rasterization import build_rasterizer  # noqa: E402

SPEC_DEFAULTS: dict = {
    "mode": "rasterize",            # "rasterize" or "time"
    "zarr": None,                   # path to an l5kit .zarr (required)
    "semantic_map": None,           # semantic_map.pb, required by py_semantic
    "meta": None,                   # meta.json holding world_to_ecef, required by py_semantic
    "map_type": "box_debug",        # "box_debug" or "py_semantic"
    "raster_size": [112, 112],      # pixels, (width, height) as l5kit reads it
    "pixel_size": [0.5, 0.5],       # metres per pixel
    "ego_center": [0.25, 0.5],      # where the ego sits in the raster, fractions of its size
    "history_num_frames": 0,
    "filter_agents_threshold": 0.5,
    "set_origin_to_bottom": True,
    "render_ego_history": True,
    "disable_traffic_light_faces": False,
    "scene_index": 0,
    "frames": None,                 # frame indices within the scene; None means every frame
    "out": None,                    # .npz path for mode "rasterize"
    "repeats": 3,                   # passes over the scene per map type, mode "time"
    "timing_map_types": ["box_debug", "py_semantic"],
}
MAP_TYPES = ("box_debug", "py_semantic")
# What the image array holds: l5kit's rasterize() gives (H, W, C); EgoDataset.get_frame transposes it.
IMAGE_LAYOUT = "NCHW: EgoDataset.get_frame's transpose(2, 0, 1) of rasterize()'s HWC, float32 in [0, 1]"


class TimedRasterizer:
    """Passes rasterize() through to l5kit's rasterizer and keeps how long each call took."""

    def __init__(self, inner):
        self.inner = inner
        self.seconds: list[float] = []

    def rasterize(self, *args, **kwargs):
        start = time.perf_counter()
        image = self.inner.rasterize(*args, **kwargs)
        self.seconds.append(time.perf_counter() - start)
        return image

    def to_rgb(self, image, **kwargs):
        return self.inner.to_rgb(image, **kwargs)

    def num_channels(self) -> int:
        return self.inner.num_channels()


def l5kit_cfg(spec: dict, map_type: str) -> dict:
    """The cfg dict build_rasterizer and EgoDataset read; map keys are absolute paths (see data_manager)."""
    return {
        "model_params": {
            "history_num_frames": spec["history_num_frames"],
            # The ego's own future is not drawn; 1 keeps l5kit's target slicing cheap and valid.
            "future_num_frames": 1,
            "step_time": 0.1,
            "render_ego_history": spec["render_ego_history"],
        },
        "raster_params": {
            "raster_size": list(spec["raster_size"]),
            "pixel_size": list(spec["pixel_size"]),
            "ego_center": list(spec["ego_center"]),
            "map_type": map_type,
            "satellite_map_key": "",
            # box_debug reads the key but never the file, so a missing meta.json is fine there.
            "semantic_map_key": str(Path(spec["semantic_map"]).resolve()) if spec["semantic_map"] else "",
            "dataset_meta_key": str(Path(spec["meta"]).resolve()) if spec["meta"] else "meta.json",
            "filter_agents_threshold": spec["filter_agents_threshold"],
            "disable_traffic_light_faces": spec["disable_traffic_light_faces"],
            "set_origin_to_bottom": spec["set_origin_to_bottom"],
        },
    }


def check_spec(spec: dict, map_type: str) -> None:
    if spec["zarr"] is None:
        raise SystemExit("spec error: 'zarr' (path to an l5kit .zarr) is required")
    if not (Path(spec["zarr"]) / ".zgroup").is_file():
        raise SystemExit(f"spec error: {spec['zarr']} is not a zarr group (no .zgroup)")
    if map_type not in MAP_TYPES:
        raise SystemExit(f"spec error: map_type {map_type!r} is not one of {MAP_TYPES}")
    if map_type == "py_semantic":
        for key in ("semantic_map", "meta"):
            if spec[key] is None or not Path(spec[key]).is_file():
                raise SystemExit(f"spec error: py_semantic needs '{key}', got {spec[key]!r} (no such file)")


def scene_dataset(spec: dict) -> ChunkedDataset:
    """The scene copied into memory, as l5kit's closed-loop simulation holds it."""
    zarr_dataset = ChunkedDataset(str(spec["zarr"])).open()
    scenes = len(zarr_dataset.scenes)
    if not 0 <= spec["scene_index"] < scenes:
        raise SystemExit(f"spec error: scene_index {spec['scene_index']} out of range: {spec['zarr']} has {scenes}")
    return zarr_dataset.get_scene_dataset(spec["scene_index"])


def ego_dataset(spec: dict, map_type: str, scene: ChunkedDataset) -> tuple[dict, EgoDataset, TimedRasterizer]:
    cfg = l5kit_cfg(spec, map_type)
    # LocalDataManager joins its folder with each key; the keys are absolute, so the folder only has to exist.
    rasterizer = TimedRasterizer(build_rasterizer(cfg, LocalDataManager(tempfile.gettempdir())))
    return cfg, EgoDataset(cfg, scene, rasterizer), rasterizer


def frame_indices(spec: dict, scene: ChunkedDataset) -> list[int]:
    count = len(scene.frames)
    wanted = list(range(count)) if spec["frames"] is None else [int(i) for i in spec["frames"]]
    for i in wanted:
        if not 0 <= i < count:
            raise SystemExit(f"spec error: frame {i} out of range: scene {spec['scene_index']} of "
                             f"{spec['zarr']} has {count} frames")
    return wanted


def versions() -> dict:
    names = ("l5kit", "numpy", "zarr", "opencv-contrib-python-headless", "shapely", "torch")
    return {n: importlib.metadata.version(n) for n in names} | {"python": sys.version.split()[0]}


def rasterize(spec: dict) -> None:
    map_type = spec["map_type"]
    check_spec(spec, map_type)
    if spec["out"] is None:
        raise SystemExit("spec error: 'out' (.npz path) is required in mode rasterize")
    scene = scene_dataset(spec)
    cfg, dataset, rasterizer = ego_dataset(spec, map_type, scene)
    frames = frame_indices(spec, scene)
    fields: dict[str, list] = {k: [] for k in ("image", "rgb", "raster_from_world", "raster_from_agent",
                                               "world_from_agent", "centroid", "yaw")}
    for i in frames:
        sample = dataset.get_frame(0, i)
        fields["image"].append(sample["image"].astype(np.float32, copy=False))
        # to_rgb wants rasterize()'s own HWC layout back.
        fields["rgb"].append(rasterizer.to_rgb(sample["image"].transpose(1, 2, 0)))
        for key in ("raster_from_world", "raster_from_agent", "world_from_agent", "centroid", "yaw"):
            fields[key].append(np.asarray(sample[key], dtype=np.float64))
    out = Path(spec["out"])
    out.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(
        out, **{k: np.stack(v) for k, v in fields.items()},
        frame_index=np.asarray(frames, dtype=np.int64),
        rasterize_seconds=np.asarray(rasterizer.seconds, dtype=np.float64),
        image_layout=np.asarray(IMAGE_LAYOUT), cfg_json=np.asarray(json.dumps(cfg, sort_keys=True)),
        versions_json=np.asarray(json.dumps(versions(), sort_keys=True)))
    print(json.dumps({"out": str(out), "frames": len(frames), "image_shape": list(fields["image"][0].shape),
                      "rasterize_ms_median": 1e3 * statistics.median(rasterizer.seconds)}))


def time_scene(spec: dict) -> None:
    scene = scene_dataset(spec)
    frames = frame_indices({**spec, "frames": None}, scene)
    for map_type in spec["timing_map_types"]:
        check_spec(spec, map_type)
        cfg, dataset, rasterizer = ego_dataset(spec, map_type, scene)
        for i in frames[:5]:  # first calls pay for cv2's and numpy's lazy set-up
            dataset.get_frame(0, i)
        raster_rates, frame_rates = [], []
        for _ in range(spec["repeats"]):
            rasterizer.seconds.clear()
            start = time.perf_counter()
            for i in frames:
                dataset.get_frame(0, i)
            whole = time.perf_counter() - start
            raster_rates.append(len(frames) / sum(rasterizer.seconds))
            frame_rates.append(len(frames) / whole)
        print(json.dumps({
            "map_type": map_type, "frames": len(frames), "repeats": spec["repeats"],
            "rasterize_scene_steps_per_s": statistics.median(raster_rates),
            "get_frame_scene_steps_per_s": statistics.median(frame_rates),
            "rasterize_runs": raster_rates, "get_frame_runs": frame_rates,
            "cfg": cfg, "versions": versions()}), flush=True)


def parse_spec(argv: list[str]) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--spec", help="JSON file with any of the keys of SPEC_DEFAULTS")
    for key, default in SPEC_DEFAULTS.items():
        flag = "--" + key.replace("_", "-")
        if isinstance(default, list) or key == "frames":
            kind = str if key == "timing_map_types" else (float if key in ("pixel_size", "ego_center") else int)
            parser.add_argument(flag, dest=key, nargs="+", type=kind)
        elif isinstance(default, bool):
            parser.add_argument(flag, dest=key, type=lambda s: s.lower() in ("1", "true", "yes"))
        else:
            kind = float if isinstance(default, float) else (int if isinstance(default, int) else str)
            parser.add_argument(flag, dest=key, type=kind)
    args = parser.parse_args(argv)
    spec = dict(SPEC_DEFAULTS)
    if args.spec:
        try:
            given = json.loads(Path(args.spec).read_text())
        except (OSError, json.JSONDecodeError) as error:
            raise SystemExit(f"spec error: cannot read {args.spec}: {error}") from error
        unknown = set(given) - set(SPEC_DEFAULTS)
        if unknown:
            raise SystemExit(f"spec error: {args.spec} has unknown keys {sorted(unknown)}")
        spec.update(given)
    spec.update({k: v for k, v in vars(args).items() if k != "spec" and v is not None})
    return spec


def main(argv: list[str]) -> None:
    torch.set_num_threads(1)
    cv2.setNumThreads(1)
    spec = parse_spec(argv)
    if spec["mode"] == "rasterize":
        rasterize(spec)
    elif spec["mode"] == "time":
        time_scene(spec)
    else:
        raise SystemExit(f"spec error: mode {spec['mode']!r} is not 'rasterize' or 'time'")


if __name__ == "__main__":
    main(sys.argv[1:])
