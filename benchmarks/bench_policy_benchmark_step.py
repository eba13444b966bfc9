"""Policy-benchmark step throughput on one core: the batched simulator vs highway-env 1.12.

Ours: :meth:`pytest_driveeval.sim.episodes.Episodes.step` (IDM + MOBIL traffic,
kinematic bicycle ego, collision, off-road and goal checks) with 12 agents per
episode and E episodes batched, plus the graph observation of
``pytest_driveeval.policies.graph`` when that module is importable (see the
HOOK below).  The driving policy is outside the timing: a lane keeper that
brakes for whatever is ahead.  Target: >= 300,000 live agent-steps/s at E = 16,
and no fewer per agent at E = 256.

Both are compiled with numba where it is installed (``sim.episodes_jit``,
``policies.graph_jit``; loaded up front here, the first call's compilation or
cache load outside the timing); ``--numpy`` also times the numpy and torch
paths they replace, in the same run, and prints the ratio.

Reference, in the same run: highway-env (``highway-fast-v0``, ``merge-v0``,
``intersection-v0``), rendering off, stepped at 5 Hz with one simulation
step per policy step, so one env step is one 0.2 s step as ours; the
highway keeps 11 other vehicles (12 with the ego); merge and intersection keep
their own counts.  highway-env goes into its own venv under
``~/.cache/driveeval-bench/highway-env`` (created on first use, never part of
our requirements); its agent-steps count the vehicles on the road at each step.

Two rates are printed for ours: agent *slots* (E x 12 per step, what the arrays
hold, padding included) and *live* agent-steps (valid agents of episodes still
running), the one compared with highway-env.  Nothing is asserted.

    python benchmarks/bench_policy_benchmark_step.py [--episodes 1 16 64 256] [--steps 50] [--batches 4]
                                                     [--no-reference] [--no-graph] [--numpy] [--smoke]
"""
from __future__ import annotations

import os

# One core, set before numpy or torch start a thread pool.
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMEXPR_NUM_THREADS"):
    os.environ[_var] = "1"
if hasattr(os, "sched_setaffinity"):
    os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from pytest_driveeval.sim import episodes_jit
from pytest_driveeval.sim.blueprints import make_blueprint
from pytest_driveeval.sim.episodes import Episodes, reset

AGENTS = 12
numba_installed = episodes_jit.AVAILABLE
BLUEPRINT_OF = {"highway-fast-v0": "highway", "merge-v0": "merging", "intersection-v0": "intersection"}
# Spawn spans widened from the defaults (BARK-ML's merging spans hold about 6 vehicles, the intersection's
# about 9) so that all 12 agents of an episode are live and "12 agents" means twelve.
FILL = {"highway": {}, "merging": {"main_span": (0.0, 95.0), "merge_span": (0.0, 60.0)},
        "intersection": {"traffic_span": (-95.0, 40.0)}}
HIGHWAY_ENV = "highway-env==1.12.1"  # the newest 1.x on PyPI when this was written
REFERENCE_VENV = Path.home() / ".cache" / "driveeval-bench" / "highway-env"
SMOKE_HELP = "every part at tiny sizes in seconds, reference venvs skipped: checks the script runs, measures nothing"


# --------------------------------------------------------------------------- HOOK: graph observation
# The use case's own observer (graph_observation + encode), inside the timing: what run_policy does each step.
def graph_observer(episodes: Episodes):
    """(callable(episodes) -> flat observation, what happened) or (None, why not)."""
    try:
        import torch

        from pytest_driveeval.usecases.policy_benchmark.evaluate import observer
    except ImportError as exc:
        return None, f"not measured ({exc})"
    torch.set_num_threads(1)
    return observer(episodes, episodes.agent_limit), "graph_observation + encode"


# --------------------------------------------------------------------------- ours
def stop_line(episodes: Episodes, lane: np.ndarray) -> np.ndarray:
    """(E,) arclength on ``lane`` where the lane keeper stops: a lane's end, or the junction's edge."""
    bp = episodes.blueprint
    if bp.name == "intersection":
        return np.full(len(lane), bp.params.arm_length - bp.params.lane_width)
    return bp.road.end_s[lane]


def lane_keeper(episodes: Episodes) -> np.ndarray:
    """Steer to the nearest lane's centre, 10 m/s, brake for valid agents ahead in the lane and stop
    before a lane end or a junction, so episodes last and every step times live agents."""
    road = episodes.blueprint.road
    ego_xy, ego_yaw, v = episodes.xy[:, 0], episodes.yaw[:, 0], episodes.speed[:, 0]
    proj = road.project(ego_xy)
    lane = np.argmin(np.abs(proj.d), axis=1)[:, None]
    d = np.take_along_axis(proj.d, lane, 1)[:, 0]
    heading = np.take_along_axis(proj.heading, lane, 1)[:, 0]
    to_stop = stop_line(episodes, lane[:, 0]) - np.take_along_axis(proj.s, lane, 1)[:, 0] - 2.25 - 1.0
    err = (ego_yaw - heading + np.pi) % (2 * np.pi) - np.pi
    steer = np.clip(-0.1 * d - 1.0 * err, -0.5, 0.5)
    rel = episodes.xy[:, 1:] - ego_xy[:, None]
    along = rel[..., 0] * np.cos(ego_yaw)[:, None] + rel[..., 1] * np.sin(ego_yaw)[:, None]
    across = rel[..., 1] * np.cos(ego_yaw)[:, None] - rel[..., 0] * np.sin(ego_yaw)[:, None]
    ahead = episodes.valid[:, 1:] & (along > 0) & (np.abs(across) < 2.5)
    gap = np.minimum(np.where(ahead, along - 4.5, np.inf).min(axis=1), to_stop + 2.0)
    # IDM towards 10 m/s, taking whatever is ahead as standing still.
    wanted = 2.0 + 1.5 * v + v * v / (2.0 * np.sqrt(15.0))
    accel = 3.0 * (1.0 - (v / 10.0) ** 4 - (wanted / np.maximum(gap, 0.1)) ** 2)
    return np.stack([accel, steer], axis=1)


def measure_ours(name: str, episodes_n: int, steps: int, batches: int, with_graph: bool,
                 compiled: bool = True) -> dict:
    # With numba loaded wanted() says yes unless AVAILABLE is off: the switch for the numpy paths.
    episodes_jit.AVAILABLE = compiled and numba_installed
    episodes_jit.start()
    warm = reset(make_blueprint(name, **FILL[name]), np.arange(2), AGENTS)
    warm.step(lane_keeper(warm))
    if with_graph:
        graph_observer(warm)[0](warm)
    sim_time, graph_time, slots, live, ended = 0.0, 0.0, 0, 0, 0
    status = "off"
    for b in range(batches):
        episodes = reset(make_blueprint(name, **FILL[name]), np.arange(b * episodes_n, (b + 1) * episodes_n), AGENTS)
        observe, status = graph_observer(episodes) if with_graph else (None, "off")
        for _ in range(steps):
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
            slots += episodes_n * AGENTS
        ended += int(np.count_nonzero(episodes.done))
    total, n = sim_time + graph_time, steps * batches
    return {"slots_per_s": slots / total, "live_per_s": live / total, "sim_live_per_s": live / sim_time,
            "sim_ms": 1e3 * sim_time / n, "graph_ms": 1e3 * graph_time / n, "ended": ended / (episodes_n * batches),
            "graph": status}


# --------------------------------------------------------------------------- highway-env
REFERENCE_SCRIPT = r"""
import json, sys, time
import gymnasium as gym
import highway_env  # noqa: F401  registers the environments
steps = int(sys.argv[1])
configs = {
    "highway-fast-v0": {"vehicles_count": 11, "lanes_count": 4, "duration": 40},
    "merge-v0": {},
    "intersection-v0": {"duration": 40},
}
out = {}
for env_id, extra in configs.items():
    config = {"simulation_frequency": 5, "policy_frequency": 5, **extra}
    env = gym.make(env_id, render_mode=None, config=config)
    env.reset(seed=0)
    idle = 1  # DiscreteMetaAction IDLE in all three
    total, agent_steps, episodes = 0.0, 0, 1
    for i in range(steps):
        t0 = time.perf_counter()
        _, _, terminated, truncated, _ = env.step(idle)
        total += time.perf_counter() - t0
        agent_steps += len(env.unwrapped.road.vehicles)
        if terminated or truncated:
            env.reset(seed=i + 1)
            episodes += 1
    out[env_id] = {"agent_steps_per_s": agent_steps / total, "ms_per_step": 1e3 * total / steps,
                   "vehicles_per_step": agent_steps / steps, "episodes": episodes}
print(json.dumps({"version": highway_env.__version__ if hasattr(highway_env, "__version__") else "?",
                  "results": out}))
"""


def reference_python() -> Path:
    python = REFERENCE_VENV / "bin" / "python"
    if not python.exists():
        print(f"creating {REFERENCE_VENV} ...", flush=True)
        subprocess.run([sys.executable, "-m", "venv", str(REFERENCE_VENV)], check=True)
    if subprocess.run([str(python), "-c", "import highway_env"], capture_output=True, check=False).returncode != 0:
        print(f"installing {HIGHWAY_ENV} into it (first run only) ...", flush=True)
        subprocess.run([str(python), "-m", "pip", "install", "-q", HIGHWAY_ENV], check=True)
    return python


def measure_reference(steps: int) -> dict:
    python = reference_python()
    version = subprocess.run([str(python), "-c", "import importlib.metadata as m; print(m.version('highway-env'))"],
                             check=True, capture_output=True, text=True).stdout.strip()
    done = subprocess.run([str(python), "-c", REFERENCE_SCRIPT, str(steps)], check=True, capture_output=True,
                          text=True, env={**os.environ, "SDL_VIDEODRIVER": "dummy", "PYGAME_HIDE_SUPPORT_PROMPT": "1"})
    result = json.loads(done.stdout.strip().splitlines()[-1])
    result["version"] = version
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--episodes", type=int, nargs="+", default=[1, 16, 64, 256])
    parser.add_argument("--steps", type=int, default=50, help="steps per batch (0.2 s each)")
    parser.add_argument("--batches", type=int, default=4, help="fresh batches per figure (resets not timed)")
    parser.add_argument("--reference-steps", type=int, default=600)
    parser.add_argument("--no-reference", action="store_true")
    parser.add_argument("--no-graph", action="store_true", help="time the simulator alone")
    parser.add_argument("--smoke", action="store_true", help=SMOKE_HELP)
    parser.add_argument("--numpy", action="store_true", help="also time the numpy/torch paths numba replaces")
    args = parser.parse_args()
    if args.smoke:
        args.episodes, args.steps, args.batches, args.no_reference = [2], 3, 1, True
        print("smoke run: tiny sizes, highway-env's venv skipped; the figures mean nothing")

    print(f"one core: cpu {sorted(os.sched_getaffinity(0)) if hasattr(os, 'sched_getaffinity') else '?'}, "
          f"OMP_NUM_THREADS={os.environ['OMP_NUM_THREADS']}, numpy {np.__version__}; {AGENTS} agents per episode")
    print("spawn spans widened so every agent is live:", {k: v for k, v in FILL.items() if v})
    print("numba paths:", "on" if episodes_jit.start() else "off (numba is not installed: the numpy paths)")
    paths = ["numba", "numpy"] if args.numpy and numba_installed else ["numba" if numba_installed else "numpy"]
    ours: dict[tuple[str, int], dict] = {}
    if not args.no_graph:
        print("graph observation:", graph_observer(reset("highway", [0], AGENTS))[1])
    for name in BLUEPRINT_OF.values():
        for e in args.episodes:
            for path in paths:
                r = measure_ours(name, e, args.steps, args.batches, not args.no_graph, path == "numba")
                if path == paths[0]:
                    ours[name, e] = r
                print(f"  ours {name:13s} E={e:4d}: {r['live_per_s']:>9,.0f} live agent-steps/s "
                      f"({r['slots_per_s']:>9,.0f} slots/s; simulator alone {r['sim_live_per_s']:>9,.0f})  "
                      f"{r['sim_ms']:5.2f} + {r['graph_ms']:5.2f} ms/step sim + graph  ended {r['ended']:.0%}  {path}"
                      + (f", numba x{ours[name, e]['live_per_s'] / r['live_per_s']:.1f}" if path != paths[0] else ""),
                      flush=True)
        per_agent = {e: ours[name, e]["live_per_s"] for e in args.episodes}
        if 16 in per_agent and 256 in per_agent:
            print(f"  ours {name:13s} E=256 / E=16 per agent: x{per_agent[256] / per_agent[16]:.2f}")
    if args.no_reference:
        return
    ref = measure_reference(args.reference_steps)
    print(f"highway-env {ref['version']} (5 Hz, one simulation step per env step, rendering off):")
    for env_id, r in ref["results"].items():
        name = BLUEPRINT_OF[env_id]
        print(f"  {env_id:16s}: {r['agent_steps_per_s']:>10,.0f} agent-steps/s  {r['ms_per_step']:6.2f} ms/step  "
              f"({r['vehicles_per_step']:.1f} vehicles)")
        for e in args.episodes:
            print(f"      ours {name} E={e}: x{ours[name, e]['live_per_s'] / r['agent_steps_per_s']:.1f} "
                  "(live agent-steps/s)")


if __name__ == "__main__":
    main()
