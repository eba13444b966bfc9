"""Time the closed-loop bird's-eye GIF of one scene with and without its map drawn under the boxes.

Run: ``python benchmarks/bench_birdseye_map.py [--scene sd_....pkl] [--frames 150] [--repeat 5] [--smoke]``.

With ``--scene`` (a ScenarioNet scenario file), its logged self-driving car is the ego, its other
tracks the agents and its map (as the closed-loop use case draws it) the map; without, a generated
street grid about the size of a nuScenes scene's map (a few hundred lane polygons over 600 m).  The
GIF is drawn as scene_gif draws it (at most 80 of the frames, 320 px); the best CPU time of
``--repeat`` (CPU time: other work on a shared machine skews wall time) is printed for each, and
the ratio of the two: the reference, the GIF without a map, is measured in the same run.  Nothing
is asserted.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from pytest_driveeval.report.birdseye import render_unroll_gif  # noqa: E402
from pytest_driveeval.report.map_layers import DrawnMap  # noqa: E402

SMOKE_HELP = "every part at tiny sizes in seconds: checks the script runs, measures nothing"


def street_grid(blocks: int = 6, block: float = 100.0, lane: float = 3.5) -> DrawnMap:
    """Two-lane streets on a grid: each street a lane polygon per 20 m per direction, a centre line,
    two edges, a crosswalk at each crossing."""
    surfaces, lines, edges, walks = [], [], [], []
    extent = blocks * block
    for k in range(blocks + 1):
        for along in (0, 1):  # streets along x, then along y
            c = k * block
            for s in np.arange(0.0, extent, 20.0):
                for side in (-1, 1):
                    a, b = sorted((c, c + side * lane))
                    rect = np.array([[s, a], [s + 20, a], [s + 20, b], [s, b]])
                    surfaces.append(rect if along == 0 else rect[:, ::-1])
            ts = np.linspace(0.0, extent, 31)
            for offset, out in ((0.0, lines), (-lane, edges), (lane, edges)):
                line = np.stack([ts, np.full_like(ts, c + offset)], 1)
                out.append(line if along == 0 else line[:, ::-1])
        for m in range(blocks + 1):
            walks.append(np.array([[k * block + 5, m * block - lane], [k * block + 8, m * block - lane],
                                   [k * block + 8, m * block + lane], [k * block + 5, m * block + lane]]))
    return DrawnMap(surfaces, lines, edges, walks)


def generated_scene(frames: int, agents: int = 30, seed: int = 0):
    rng = np.random.default_rng(seed)
    t = np.arange(frames) * 0.1
    ego = np.stack([50 + 10.0 * t, np.full(frames, 101.75)], 1)  # along a street at 10 m/s
    start = np.stack([rng.uniform(0, 400, agents), 100 + rng.choice([-1.75, 1.75], agents)], 1)
    speed = rng.uniform(0, 12, agents)
    xy = start[None] + np.stack([speed[None] * t[:, None], np.zeros((frames, agents))], -1)
    return ego, np.zeros(frames), xy, np.zeros((frames, agents)), np.ones((frames, agents), bool), street_grid()


def scenario_scene(path: Path, frames: int):
    from pytest_driveeval.io.scenarionet.scenarionet import read_scenario
    from pytest_driveeval.usecases.closed_loop.scene_map import drawn_map

    scene = read_scenario(path)
    start = time.process_time()
    drawn = drawn_map(scene)
    print(f"building the map from the scenario: {(time.process_time() - start) * 1000:.0f} ms (once per GIF)")
    tr, ego = scene.tracks, scene.sdc
    others = [i for i in range(len(tr.ids)) if i != ego]
    n = min(frames, scene.steps)
    return (tr.position[ego, :n, :2], tr.heading[ego, :n], tr.position[others, :n, :2].transpose(1, 0, 2),
            tr.heading[others, :n].T, tr.valid[others, :n].T, drawn)


def best_of(repeat: int, run) -> float:
    times = []
    for _ in range(repeat):
        start = time.process_time()
        run()
        times.append(time.process_time() - start)
    return min(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", type=Path, help="a ScenarioNet scenario file (default: a generated street grid)")
    parser.add_argument("--frames", type=int, default=150)
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--smoke", action="store_true", help=SMOKE_HELP)
    args = parser.parse_args()
    if args.smoke:
        args.frames, args.repeat, args.scene = 12, 1, None
        print("smoke run: tiny sizes; the figures mean nothing")
    ego, yaw, xy, agent_yaw, live, drawn = (scenario_scene(args.scene, args.frames) if args.scene
                                            else generated_scene(args.frames))
    extent = np.broadcast_to(np.array([4.5, 1.9]), xy.shape)
    print(f"{len(ego)} frames, {xy.shape[1]} agents; map: {len(drawn.lane_surfaces)} lane surfaces, "
          f"{len(drawn.road_lines)} road lines, {len(drawn.road_edges)} road edges, {len(drawn.crosswalks)} crosswalks"
          f" ({args.scene.name if args.scene else 'generated street grid'})")
    with tempfile.TemporaryDirectory() as folder:
        def gif(with_map: bool) -> None:
            render_unroll_gif(Path(folder) / "s.gif", ego, yaw, np.array([4.9, 1.9]), ego, xy, agent_yaw, extent,
                              live, np.zeros(len(ego), bool), title="scene 0",
                              drawn_map=drawn if with_map else None)

        gif(True)  # fonts and Pillow's plugins load once, in neither figure
        bare = best_of(args.repeat, lambda: gif(False))
        mapped = best_of(args.repeat, lambda: gif(True))
    print(f"without the map: {bare * 1000:.0f} ms per GIF (CPU time, best of {args.repeat})")
    print(f"with the map   : {mapped * 1000:.0f} ms per GIF")
    print(f"map / no map: {mapped / bare:.2f}x")


if __name__ == "__main__":
    main()
