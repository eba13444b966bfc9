"""Policy-benchmark step throughput on one core in a CommonRoad scene, against the blueprints in the same run.

Ours on CommonRoad: :class:`pytest_driveeval.sim.commonroad_episodes.CommonRoadEpisodes` stepping E
episodes of one planning problem (kinematic bicycle ego, every obstacle replayed from the recording,
collision with each obstacle's box, off-road on the lanelets' raster, CommonRoad's goal test), plus the
graph observation of the use case (``observer``: graph_observation + encode) inside the timing, as in
``bench_policy_benchmark_step.py``, whose conventions this copies: one core, 12 agents observed, the
driving policy outside the timing (a lane keeper on the nearest lanelet's centre line, IDM towards the
initial speed for whatever is ahead, so episodes last), fresh batches per figure (resets not timed).
Episodes that end keep their last state and stay in the batch, as in the use case; a batch is stepped
until all its episodes have ended (at the latest the scene's step limit), as ``run_policy`` does.

The scene: USA_US101-3_3_T-1 from the shared data (12 recorded cars) if present, else USA_Lanker, else the
fixture ZAM_Tutorial.  *Live* agent-steps count the ego and the obstacles present, in episodes still
running; the blueprints' figure is ``bench_policy_benchmark_step.measure_ours`` on the same machine in
the same run.  Target: >= 50,000 live agent-steps/s at E = 16 with the recording replayed.  A second line
times ``Traffic: reactive`` (the recorded cars on their paths at IDM speed).  Nothing is asserted.

    python benchmarks/bench_commonroad_step.py [--episodes 16] [--batches 8] [--scene PATH] [--smoke]
"""
from __future__ import annotations

import os

# One core, set before numpy or torch start a thread pool.
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMEXPR_NUM_THREADS"):
    os.environ[_var] = "1"
if hasattr(os, "sched_setaffinity"):
    os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from bench_policy_benchmark_step import AGENTS, graph_observer, measure_ours  # noqa: E402

from pytest_driveeval.sim.commonroad_scene import CommonRoadScene, commonroad_scene, read_cached  # noqa: E402
from pytest_driveeval.sim.episodes import reset  # noqa: E402

SHARED = Path(os.environ.get("DRIVEEVAL_SHARED_DATA", ROOT.parent / "shared" / "data")) / "commonroad"
CANDIDATES = ("USA_US101-3_3_T-1.xml", "USA_Lanker-1_1_T-1.xml")
FIXTURE = ROOT / "fixtures" / "commonroad" / "ZAM_Tutorial-1_2_T-1.xml"
SMOKE_HELP = "every part at tiny sizes in seconds: checks the script runs, measures nothing"


def scene_path(given: str | None) -> Path:
    if given:
        return Path(given)
    for name in CANDIDATES:
        if (SHARED / name).is_file():
            return SHARED / name
    return FIXTURE


def lane_keeper(episodes) -> np.ndarray:
    """Steer onto the nearest lanelet's centre line, IDM towards the start speed behind whatever is ahead."""
    road = episodes.blueprint.road
    ego_xy, ego_yaw, v = episodes.xy[:, 0], episodes.yaw[:, 0], episodes.speed[:, 0]
    proj = road.project(ego_xy)
    aligned = np.cos(proj.heading - ego_yaw[:, None]) > 0.5
    lane = np.argmin(np.where(aligned, np.abs(proj.d), np.inf), axis=1)[:, None]
    d = np.take_along_axis(proj.d, lane, 1)[:, 0]
    heading = np.take_along_axis(proj.heading, lane, 1)[:, 0]
    err = (ego_yaw - heading + np.pi) % (2 * np.pi) - np.pi
    steer = np.clip(-0.1 * d - 1.0 * err, -0.2, 0.2)
    rel = episodes.xy[:, 1:] - ego_xy[:, None]
    along = rel[..., 0] * np.cos(ego_yaw)[:, None] + rel[..., 1] * np.sin(ego_yaw)[:, None]
    across = rel[..., 1] * np.cos(ego_yaw)[:, None] - rel[..., 0] * np.sin(ego_yaw)[:, None]
    ahead = episodes.valid[:, 1:] & (along > 0) & (np.abs(across) < 2.5)
    gap = np.where(ahead, along - 4.5, np.inf).min(axis=1)
    v0 = max(float(episodes.blueprint.problem.initial.velocity), 5.0)
    wanted = 2.0 + 1.5 * v + v * v / (2.0 * np.sqrt(15.0))
    accel = 3.0 * (1.0 - (v / v0) ** 4 - (wanted / np.maximum(gap, 0.1)) ** 2)
    return np.stack([accel, steer], axis=1)


def measure_commonroad(scene: CommonRoadScene, episodes_n: int, batches: int, with_graph: bool) -> dict:
    sim_time, graph_time, live, steps_done, ended = 0.0, 0.0, 0, 0, 0
    outcomes = np.zeros(5, np.int64)
    status = "off"
    for b in range(batches):
        episodes = reset(scene, np.arange(b * episodes_n, (b + 1) * episodes_n), AGENTS)
        observe, status = graph_observer(episodes) if with_graph else (None, "off")
        for _ in range(scene.max_steps):
            if episodes.done.all():  # as run_policy: a batch whose episodes all ended is not stepped
                break
            actions = lane_keeper(episodes)
            running = ~episodes.done
            live += int(np.count_nonzero(episodes.valid[running]))
            t0 = time.perf_counter()
            episodes.step(actions)
            t1 = time.perf_counter()
            if observe is not None:
                observe(episodes)
            graph_time += time.perf_counter() - t1
            sim_time += t1 - t0
            steps_done += 1
        ended += int(np.count_nonzero(episodes.done))
        outcomes += np.bincount(episodes.outcome, minlength=5)
    total = sim_time + graph_time
    return {"live_per_s": live / total, "sim_live_per_s": live / sim_time, "sim_ms": 1e3 * sim_time / steps_done,
            "graph_ms": 1e3 * graph_time / steps_done, "ended": ended / (episodes_n * batches), "graph": status,
            "live_per_step": live / steps_done, "outcomes": outcomes.tolist()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--episodes", type=int, default=16)
    parser.add_argument("--batches", type=int, default=8, help="fresh batches per figure (resets not timed)")
    parser.add_argument("--blueprint-steps", type=int, default=50, help="steps per blueprint batch")
    parser.add_argument("--scene", help="a CommonRoad XML file (default: US101 or Lanker from the shared data)")
    parser.add_argument("--no-graph", action="store_true", help="time the simulators alone")
    parser.add_argument("--smoke", action="store_true", help=SMOKE_HELP)
    args = parser.parse_args()
    if args.smoke:
        args.episodes, args.batches, args.blueprint_steps = 2, 1, 3
        print("smoke run: tiny sizes; the figures mean nothing")
    path = scene_path(args.scene)
    problem = next(iter(read_cached(path).planning_problems))
    scene = commonroad_scene(path, problem, **({"max_steps": 3} if args.smoke else {}))
    print(f"one core: cpu {sorted(os.sched_getaffinity(0)) if hasattr(os, 'sched_getaffinity') else '?'}, "
          f"OMP_NUM_THREADS={os.environ['OMP_NUM_THREADS']}, numpy {np.__version__}; {AGENTS} agents observed")
    print(f"scene: {path.name}, planning problem {problem}: {len(scene.obstacle_ids)} obstacles, "
          f"{scene.max_steps} steps of {scene.dt} s, {len(scene.lanelet_outlines)} lanelets")
    print("graph observation:", "off" if args.no_graph else graph_observer(reset(scene, [0], AGENTS))[1])
    cr = measure_commonroad(scene, args.episodes, args.batches, not args.no_graph)
    print(f"  ours commonroad E={args.episodes:4d}: {cr['live_per_s']:>9,.0f} live agent-steps/s "
          f"(simulator alone {cr['sim_live_per_s']:>9,.0f})  {cr['sim_ms']:5.2f} + {cr['graph_ms']:5.2f} ms/step "
          f"sim + graph  {cr['live_per_step']:.1f} live agents/step  ended {cr['ended']:.0%} "
          f"(running/goal/collision/off-road/limit {cr['outcomes']})", flush=True)
    reactive = commonroad_scene(path, problem, traffic="reactive", **({"max_steps": 3} if args.smoke else {}))
    rr = measure_commonroad(reactive, args.episodes, args.batches, not args.no_graph)
    print(f"  ours commonroad, Traffic: reactive E={args.episodes:4d}: {rr['live_per_s']:>9,.0f} live agent-steps/s "
          f"(simulator alone {rr['sim_live_per_s']:>9,.0f})  {rr['sim_ms']:5.2f} + {rr['graph_ms']:5.2f} ms/step "
          f"(running/goal/collision/off-road/limit {rr['outcomes']})", flush=True)
    blue = {}
    for name in ("highway", "merging", "intersection"):
        r = blue[name] = measure_ours(name, args.episodes, args.blueprint_steps, args.batches, not args.no_graph)
        print(f"  ours {name:13s} E={args.episodes:4d}: {r['live_per_s']:>9,.0f} live agent-steps/s "
              f"(simulator alone {r['sim_live_per_s']:>9,.0f})  {r['sim_ms']:5.2f} + {r['graph_ms']:5.2f} ms/step",
              flush=True)
    mean_blue = float(np.mean([r["live_per_s"] for r in blue.values()]))
    print(f"commonroad: {cr['live_per_s']:,.0f} live agent-steps/s per core; blueprints' mean {mean_blue:,.0f} "
          f"(x{cr['live_per_s'] / mean_blue:.2f}); target 50,000")


if __name__ == "__main__":
    main()
