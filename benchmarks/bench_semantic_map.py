"""Time read_semantic_map on a generated map about the size of the real L5 one.

Run: ``python benchmarks/bench_semantic_map.py [--lanes 15000] [--points 30] [--repeat 3] [--smoke]``.

The map is a grid of gently curved lanes (``--points`` vertices per boundary),
one crosswalk per 15 lanes and a traffic light with three faces per 10 lanes,
written with write_semantic_map in l5kit's world frame; the best of
``--repeat`` reads is printed.  Nothing is asserted.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from pytest_driveeval.io.l5.l5_semantic_map import (  # noqa: E402
    GREEN, RED, YELLOW, Polylines, SemanticMap, read_semantic_map, write_semantic_map)
from pytest_driveeval.synth.scenegen import WORLD_TO_ECEF  # noqa: E402

SMOKE_HELP = "every part at tiny sizes in seconds, reference venvs skipped: checks the script runs, measures nothing"


def big_map(num_lanes: int, points: int, seed: int = 0) -> SemanticMap:
    rng = np.random.default_rng(seed)
    side = int(np.ceil(np.sqrt(num_lanes)))
    origin = np.stack(np.divmod(np.arange(num_lanes), side), 1) * 60.0 - side * 30.0
    s = np.linspace(0.0, 50.0, points)
    bend = rng.uniform(-0.01, 0.01, num_lanes)[:, None]
    centre = origin[:, None, :] + np.stack([s + 0 * bend, bend * s**2], -1)
    normal = np.stack([-2 * bend * s, np.ones_like(bend * s)], -1)
    normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
    left, right = centre + 1.75 * normal, centre - 1.75 * normal
    lights = np.arange(0, num_lanes, 10)
    face_ids = np.array([f"f{k}_{c}" for k in lights for c in "ryg"])
    controls = [[f"tl{i}", f"f{i}_r", f"f{i}_y", f"f{i}_g"] if i % 10 == 0 else [] for i in range(num_lanes)]
    walks = origin[::15]
    square = np.array([[0, 0], [4, 0], [4, 8], [0, 8]], float)
    return SemanticMap(
        lane_ids=np.array([f"lane{i}" for i in range(num_lanes)]),
        lanes_left=Polylines.from_list(left), lanes_right=Polylines.from_list(right),
        lane_control_offsets=np.concatenate([[0], np.cumsum([len(c) for c in controls])]),
        lane_control_ids=np.array([c for cs in controls for c in cs], dtype=str),
        crosswalk_ids=np.array([f"cw{j}" for j in range(len(walks))]),
        crosswalks=Polylines.from_list([w + square for w in walks]),
        face_ids=face_ids, face_colours=np.tile(np.array([RED, YELLOW, GREEN], np.int8), len(lights)),
        world_to_ecef=WORLD_TO_ECEF,
        traffic_light_ids=np.array([f"tl{k}" for k in lights]),
        face_light_index=np.repeat(np.arange(len(lights)), 3),
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--lanes", type=int, default=15_000)
    parser.add_argument("--points", type=int, default=30)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--smoke", action="store_true", help=SMOKE_HELP)
    args = parser.parse_args()
    if args.smoke:
        args.lanes, args.points, args.repeat = 100, 5, 1
        print("smoke run: tiny sizes; the figures mean nothing")
    smap = big_map(args.lanes, args.points)
    with tempfile.TemporaryDirectory() as tmp:
        pb, meta = Path(tmp) / "semantic_map.pb", Path(tmp) / "meta.json"
        t0 = time.perf_counter()
        write_semantic_map(pb, meta, smap)
        write_s = time.perf_counter() - t0
        times = []
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            back = read_semantic_map(pb, meta)
            times.append(time.perf_counter() - t0)
        size = pb.stat().st_size
    err = np.abs(back.lanes_left.points - smap.lanes_left.points).max()
    print(f"{args.lanes} lanes x {args.points} points per boundary, {len(smap.crosswalks)} crosswalks, "
          f"{len(smap.face_ids)} faces: {size / 1e6:.1f} MB")
    print(f"write {write_s:.2f} s; read best of {args.repeat}: {min(times):.2f} s; max coordinate error {err * 100:.2f} cm")


if __name__ == "__main__":
    main()
