"""Raster throughput: box_debug and py_semantic scene-steps per second, one core.

The real sample scene (``single_scene.zarr``), every frame rasterized in
turn, the scene alone and as ``--copies`` copies stepping together (one
``Rasterizer`` call per step for all of them), at 112 x 112 with
``--history`` frames (default 10: 22 box channels).  py_semantic needs a map
of the scene's streets, which the sample does not ship: ``scene_map`` lays
lanes along the ego's path (and its neighbours), side streets across it,
crosswalks, and traffic-light faces named after the scene's own faces, so
the lights switch as logged.  l5kit's figure for its 112 x 112 box raster in
closed loop on this machine: 123-154 scene-steps/s (one scene), 190-223
(16-64 copies); the target is 20x that.  Each is timed drawing a new array
every step and drawing again into one ``Canvas`` (what the closed loop's
raster inputs do).  Nothing is asserted.

    python benchmarks/bench_raster.py [--copies 64] [--history 10] [--repeats 3] [--smoke]
    python benchmarks/bench_raster.py --write-map DIR   # the map as semantic_map.pb + meta.json, for l5kit
"""
from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from pytest_driveeval.io.l5.l5_semantic_map import Polylines, SemanticMap, write_semantic_map  # noqa: E402
from pytest_driveeval.io.l5.l5kit_zarr import L5Dataset, L5Scene  # noqa: E402
from pytest_driveeval.raster import RasterParams, Rasterizer  # noqa: E402
from pytest_driveeval.sim.logreplay.logarrays import stack_scenes  # noqa: E402

# The repository's copy of l5kit's test scene (fixtures/SOURCES.md), so a plain checkout has it.
SCENE = Path(__file__).resolve().parents[1] / "fixtures" / "l5kit" / "single_scene.zarr"
SMOKE_HELP = "every part at tiny sizes in seconds, reference venvs skipped: checks the script runs, measures nothing"
# A Lyft meta.json's world_to_ecef (Palo Alto), so the map round-trips through l5kit's reader.
WORLD_TO_ECEF = np.array([[0.846617444, 0.323463078, -0.422623402, -2698767.44],
                          [-0.532201938, 0.514559352, -0.672301845, -4293151.58],
                          [-3.05311332e-16, 0.794103464, 0.6077826, 3855164.76],
                          [0.0, 0.0, 0.0, 1.0]])


def scene_map(scene: L5Scene, lane_width: float = 3.5) -> SemanticMap:
    """Lanes every ~15 m along the ego's logged path (five abreast), side streets every
    ~60 m, a crosswalk at each side street; each face id of the scene gets a colour and
    controls a few lanes."""
    path = scene.ego_positions()
    step = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(path, axis=0), axis=1))]
    along = np.arange(0.0, step[-1], 1.0)
    centre = np.stack([np.interp(along, step, path[:, 0]), np.interp(along, step, path[:, 1])], 1)
    tangent = np.gradient(centre, axis=0)
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    normal = np.stack([-tangent[:, 1], tangent[:, 0]], 1)
    left, right, crosswalks = [], [], []
    for start in range(0, len(centre) - 2, 15):
        piece = slice(start, min(start + 16, len(centre)))
        for k in range(-2, 3):
            mid = centre[piece] + normal[piece] * (k * lane_width)
            left.append(mid + normal[piece] * lane_width / 2)
            right.append(mid - normal[piece] * lane_width / 2)
        if start % 60 == 0:
            c, t, n = centre[start], tangent[start], normal[start]
            across = c + np.outer(np.linspace(-40, 40, 9), n)
            left.append(across + t * lane_width / 2)
            right.append(across - t * lane_width / 2)
            crosswalks.append(c + np.array([[-1, -1], [-1, 1], [1, 1], [1, -1]]) @ np.stack([t * 1.5, n * 9.0]))
    face_ids = np.unique(scene.traffic_light_faces["face_id"]) if len(scene.traffic_light_faces) else np.zeros(0, "<U16")
    faces = [[face_ids[(i * 3 + j) % len(face_ids)] for j in range(i % 3)] if len(face_ids) else []
             for i in range(len(left))]
    return SemanticMap(
        lane_ids=np.array([f"lane{i}" for i in range(len(left))]),
        lanes_left=Polylines.from_list(left), lanes_right=Polylines.from_list(right),
        lane_control_offsets=np.r_[0, np.cumsum([len(f) for f in faces])].astype(np.int64),
        lane_control_ids=np.array([f for fs in faces for f in fs], dtype="<U16"),
        crosswalk_ids=np.array([f"cw{i}" for i in range(len(crosswalks))]),
        crosswalks=Polylines.from_list(crosswalks),
        face_ids=face_ids.astype("<U16"), face_colours=(np.arange(len(face_ids)) % 3 + 1).astype(np.int8),
        world_to_ecef=WORLD_TO_ECEF)


def rate(raster: Rasterizer, log, copies: int, repeats: int, canvas: bool) -> float:
    """Best of ``repeats`` passes over every frame, in scene-steps per second; a new array each
    step, or (``canvas``) drawn again into one, as the closed loop does."""
    out = raster.canvas(copies) if canvas else None
    rows = np.arange(copies)
    n = int(log.num_frames[0])
    best = np.inf
    for _ in range(repeats):
        start = time.perf_counter()
        for frame in range(n):
            raster(rows, np.full(copies, frame), log.ego_xy, log.ego_yaw, out=out)
        best = min(best, time.perf_counter() - start)
    return copies * n / best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--zarr", type=Path, default=SCENE)
    parser.add_argument("--copies", type=int, default=64)
    parser.add_argument("--history", type=int, default=10)
    parser.add_argument("--size", type=int, default=112)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--write-map", type=Path, help="write the scene's map for l5kit and stop")
    parser.add_argument("--smoke", action="store_true", help=SMOKE_HELP)
    args = parser.parse_args()
    if args.smoke:
        args.copies, args.history, args.repeats = 2, 2, 1
        print("smoke run: tiny sizes; the figures mean nothing")
    scene = L5Dataset.open(args.zarr).scene(0)
    smap = scene_map(scene)
    if args.write_map:
        args.write_map.mkdir(parents=True, exist_ok=True)
        write_semantic_map(args.write_map / "semantic_map.pb", args.write_map / "meta.json", smap)
        print(f"wrote {args.write_map}: {len(smap.lane_ids)} lanes, {len(smap.crosswalk_ids)} crosswalks, "
              f"{len(smap.face_ids)} faces")
        return
    print(f"{args.zarr.name}: {scene.num_frames} frames; {args.size} x {args.size} px, history {args.history}; "
          f"map: {len(smap.lane_ids)} lanes, {len(smap.crosswalk_ids)} crosswalks; one core")
    for map_type in ("box_debug", "py_semantic"):
        params = RasterParams(map_type=map_type, raster_size=(args.size, args.size),
                              history_num_frames=args.history)
        figures = {}
        for copies in (1, args.copies):
            log = stack_scenes([scene] * copies)
            raster = Rasterizer(params, log, scenes=[scene] * copies, semantic_map=smap)
            raster(np.zeros(1, np.int64), np.zeros(1, np.int64), log.ego_xy, log.ego_yaw)  # compile
            for canvas in (False, True):
                figures[copies, canvas] = rate(raster, log, copies, args.repeats, canvas)
        for canvas in (False, True):
            line = ", ".join(f"{c} scene{'s' if c > 1 else ''}: {r:,.0f}/s ({1e3 / r:.3f} ms)"
                             for (c, into), r in figures.items() if into == canvas)
            print(f"{map_type:12s} {params.num_channels} channels, {'into a canvas' if canvas else 'new arrays  '}  "
                  f"{line}")


if __name__ == "__main__":
    main()
