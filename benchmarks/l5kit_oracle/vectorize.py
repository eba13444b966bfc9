"""l5kit 1.5.0's vectorised map keys for chosen frames of a scene, run inside the oracle venv (oracle_venv.py).

Imports nothing from pytest_driveeval: it is the independent side of the comparison in
compare_vectors.py.  The sample is l5kit's own code path: ``MapAPI`` on the semantic map,
``Vectorizer`` with the given ``lane_params``, ``EgoDatasetVectorized(...).get_frame(scene, frame)``
for the ego.  Writes an .npz with, per requested frame (N of them, in order): ``lanes``,
``lanes_availabilities``, ``lanes_mid``, ``lanes_mid_availabilities``, ``crosswalks``,
``crosswalks_availabilities`` stacked on a first axis, plus ``centroid`` (N, 2) and ``yaw`` (N,),
and the dtypes l5kit returned as ``dtypes_json``.

    python vectorize.py --spec spec.json

Spec keys: zarr, semantic_map, meta (meta.json with world_to_ecef), out, frames (list),
scene_index (0), lane_params (l5kit's names; its Urban Driver values by default).
"""
from __future__ import annotations

import json
import sys
import warnings

import numpy as np

warnings.filterwarnings("ignore")

from l5kit.data import ChunkedDataset  # noqa: E402
from l5kit.data.map_api import MapAPI  # noqa: E402
from l5kit.dataset import EgoDatasetVectorized  # noqa: E402
from l5kit.vectorization.vectorizer import Vectorizer  # noqa: E402

KEYS = ("lanes", "lanes_availabilities", "lanes_mid", "lanes_mid_availabilities", "crosswalks",
        "crosswalks_availabilities")
LANE_PARAMS = {"max_num_lanes": 30, "max_points_per_lane": 20, "max_points_per_crosswalk": 20,
               "max_retrieval_distance_m": 35, "max_num_crosswalks": 20}


def main() -> None:
    if len(sys.argv) != 3 or sys.argv[1] != "--spec":
        sys.exit("usage: vectorize.py --spec spec.json")
    with open(sys.argv[2]) as f:
        spec = json.load(f)
    unknown = set(spec) - {"zarr", "semantic_map", "meta", "out", "frames", "scene_index", "lane_params"}
    if unknown:
        sys.exit(f"spec error: unknown keys {sorted(unknown)}")
    with open(spec["meta"]) as f:
        world_to_ecef = np.asarray(json.load(f)["world_to_ecef"], dtype=np.float64)
    cfg = {
        "model_params": {"history_num_frames_ego": 1, "history_num_frames_agents": 1, "future_num_frames": 1,
                         "step_time": 0.1, "filter_agents_threshold": 0.5, "render_ego_history": True},
        "raster_params": {"filter_agents_threshold": 0.5, "disable_traffic_light_faces": False},
        "data_generation_params": {"other_agents_num": 30, "max_agents_distance": 35,
                                   "lane_params": {**LANE_PARAMS, **spec.get("lane_params", {})}},
    }
    map_api = MapAPI(spec["semantic_map"], world_to_ecef)
    dataset = ChunkedDataset(spec["zarr"]).open()
    ego = EgoDatasetVectorized(cfg, dataset, Vectorizer(cfg, map_api))
    samples = [ego.get_frame(int(spec.get("scene_index", 0)), int(i)) for i in spec["frames"]]
    out = {key: np.stack([s[key] for s in samples]) for key in KEYS}
    out["centroid"] = np.stack([s["centroid"] for s in samples])
    out["yaw"] = np.array([float(s["yaw"]) for s in samples])
    dtypes = {key: str(samples[0][key].dtype) for key in KEYS}
    np.savez(spec["out"], dtypes_json=json.dumps(dtypes), **out)
    print(json.dumps({"out": spec["out"], "frames": len(samples), "dtypes": dtypes,
                      "shapes": {key: list(out[key].shape[1:]) for key in KEYS}}))


if __name__ == "__main__":
    main()
