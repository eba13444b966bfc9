"""Our vectorised map keys (sim.logreplay.map_inputs) against l5kit 1.5.0's ``Vectorizer``, value for value.

The real L5 scene on a map laid along its own path (``bench_raster.scene_map``: no real L5 map of
that place is public), with a traffic light added over each three of the scene's own faces and
listed by the lanes those faces control, so that the traffic-light feature is exercised; written
as ``semantic_map.pb`` and read back by both sides (the file stores whole centimetres).  l5kit runs
in its venv (``oracle_venv.py``) through ``vectorize.py``: ``EgoDatasetVectorized.get_frame`` on the
logged ego.  Prints one JSON line: per key the values compared, how many differ beyond ``atol``
(coordinates) or at all (availabilities, traffic-light feature), and the largest coordinate
difference.  tests/sim/test_map_inputs_l5kit.py asserts on :func:`compare`.

    python benchmarks/l5kit_oracle/compare_vectors.py [--frames 0 40 ...]
"""
from __future__ import annotations

import argparse
import dataclasses
import importlib.util
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
REAL_SCENE = ROOT / "fixtures" / "l5kit" / "single_scene.zarr"
FRAMES = (0, 20, 40, 60, 90, 120, 140, 160, 190, 220, 240, 247)
KEYS = ("lanes", "lanes_availabilities", "lanes_mid", "lanes_mid_availabilities", "crosswalks",
        "crosswalks_availabilities")


def _load(name: str, path: Path):
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def lit_map(scene):
    """``bench_raster.scene_map`` with a traffic light per three of its faces, listed by their lanes."""
    smap = _load("bench_raster", ROOT / "benchmarks" / "bench_raster.py").scene_map(scene)
    lights = np.arange(len(smap.face_ids)) // 3
    light_ids = np.array([f"tl{k}" for k in range(int(lights.max()) + 1 if len(lights) else 0)], dtype="<U16")
    face_light = dict(zip(smap.face_ids.tolist(), lights.tolist()))
    controls = []
    for i in range(len(smap.lane_ids)):
        own = smap.lane_controls(i).tolist()
        controls.append(own + sorted({str(light_ids[face_light[f]]) for f in own}))
    return dataclasses.replace(
        smap, traffic_light_ids=light_ids, face_light_index=lights.astype(np.int64),
        lane_control_offsets=np.r_[0, np.cumsum([len(c) for c in controls])].astype(np.int64),
        lane_control_ids=np.array([c for cs in controls for c in cs], dtype="<U16"))


def ours(zarr: Path, map_dir: Path, frames: list[int]) -> dict:
    from pytest_driveeval.io.l5.l5_semantic_map import read_semantic_map
    from pytest_driveeval.io.l5.l5kit_zarr import L5Dataset
    from pytest_driveeval.raster.semantic import active_faces
    from pytest_driveeval.sim.logreplay import stack_scenes
    from pytest_driveeval.sim.logreplay.map_inputs import VectorMap

    scene = L5Dataset.open(zarr).scene(0)
    log = stack_scenes([scene])
    vector = VectorMap(read_semantic_map(map_dir / "semantic_map.pb", map_dir / "meta.json"))
    faces = active_faces([scene], log.ego_xy.shape[1])
    at = np.asarray(frames)
    lit = np.zeros((len(at), len(vector.face_ids)), bool)
    for b, t in enumerate(frames):
        index = vector.face_index(faces.ids[faces.offsets[t]:faces.offsets[t + 1]])
        lit[b, index[index >= 0]] = True
    yaw = log.ego_yaw[0, at]
    out, _ = vector(log.ego_xy[0, at], np.cos(yaw), np.sin(yaw), lit)
    return out


def compare(python: Path | None = None, frames=FRAMES, atol: float = 1e-4) -> dict:
    from pytest_driveeval.io.l5.l5_semantic_map import write_semantic_map
    from pytest_driveeval.io.l5.l5kit_zarr import L5Dataset

    oracle = _load("oracle_venv", HERE / "oracle_venv.py")
    python = python or oracle.oracle_python(quiet=True)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        write_semantic_map(tmp / "semantic_map.pb", tmp / "meta.json", lit_map(L5Dataset.open(REAL_SCENE).scene(0)))
        spec = {"zarr": str(REAL_SCENE), "semantic_map": str(tmp / "semantic_map.pb"), "meta": str(tmp / "meta.json"),
                "frames": list(frames), "out": str(tmp / "l5kit.npz")}
        (tmp / "spec.json").write_text(json.dumps(spec))
        done = subprocess.run([str(python), str(HERE / "vectorize.py"), "--spec", str(tmp / "spec.json")],
                              capture_output=True, text=True, timeout=900)
        if done.returncode != 0:
            raise RuntimeError(f"vectorize.py failed:\n{done.stderr[-4000:]}")
        theirs = dict(np.load(tmp / "l5kit.npz"))
        mine = ours(REAL_SCENE, tmp, list(frames))
    result: dict = {"frames": len(frames), "l5kit_dtypes": json.loads(str(theirs["dtypes_json"]))}
    for key in KEYS:
        a, b = mine[key], theirs[key]
        if a.shape != b.shape:
            raise AssertionError(f"{key}: ours {a.shape}, l5kit's {b.shape}")
        entry = {"values": int(a.size), "dtype": str(a.dtype)}
        if key.endswith("availabilities"):
            entry["differing"] = int((a != b).sum())
            entry["available"] = int(b.sum())
        else:
            gap = np.abs(a[..., :2] - b[..., :2])
            entry["differing"] = int((gap > atol).sum())
            entry["max_difference"] = float(gap.max())
            entry["third_differing"] = int((a[..., 2] != b[..., 2]).sum())
            entry["third_values"] = sorted({float(v) for v in np.unique(b[..., 2])})
        result[key] = entry
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, nargs="*", default=list(FRAMES))
    args = parser.parse_args()
    sys.path.insert(0, str(ROOT))
    print(json.dumps(compare(frames=args.frames)))


if __name__ == "__main__":
    main()
