"""Closed-loop unroll throughput and loading: batched engine vs the seed notebook's way and vs l5kit.

The reference figures, from issue 14 (measured on this machine, the real
sample scene, one thread): l5kit's own closed loop runs 804-842 scene-steps/s
with a no-op raster and 16 scene copies; with its 112x112 box raster 123-154
for one scene and 190-223 for 16-64 copies.  The engine then ran about
14,000-16,000 scene-steps/s for 64 scenes, and loading those 64 scenes into
arrays took 3.7 s, longer than unrolling them (1.0 s).  Targets: the engine
unrolls >= 40,000 scene-steps/s for 64 scenes with vector inputs, metrics
included, and loading the scenes costs less than unrolling them.

Part 1, on the real sample scene (all of its agents): scene-steps per second
of harness time (model time excluded, the per-frame metrics included) for

* a reference written like the l5kit seed notebook: one scene at a time, one
  forward per frame, inputs built per frame in Python the way l5kit's
  ``generate_agent_sample_vectorized`` does (per-agent, per-frame track-id
  lookups), and l5kit's ``detect_collision`` (a shapely polygon test per
  agent in range, edge lengths with LineStrings);
* :func:`pytest_driveeval.sim.logreplay.unroll` on the same scene, alone and as
  64 copies stepping together (median of ``--repeats`` runs), against the
  40,000 target and l5kit's 804-842;
* loading the 64 scenes: opening a zarr that holds 64 copies of the scene
  (written to a temporary directory first, so each chunk is decoded once, as
  reading 64 scenes of a real dataset does), ``L5Dataset.scene(i)`` for each,
  and ``stack_scenes``; against unrolling them (harness + model).  Reading the
  sample's one scene 64 times is printed beside it: its chunks are decoded
  once and then come from the store's chunk cache.

Part 2, 64 generated scenes batched: share of harness time in the total with
a given model (``--model``, e.g. the shipped .pt2; default: the constant-velocity
baseline), and the harness rate.  Targets: >= 50x the seed-notebook reference
(part 1), harness <= 20 % (part 2).  Nothing is asserted: the figures are
printed.

The compiled (numba) paths are on from the start (``jit.start()``): a process
pays about 0.5 s once for starting numba, here in the warm-ups, and without
that call a small unroll takes the numpy paths rather than pay it.

Both parts run single-threaded (``--threads``, default 1, and
OMP_NUM_THREADS=1 unless set): with more intra-op threads than free cores,
torch's threads wait on each other at every parallel region, so the model
time, and with it the harness share, follows the machine's load.  The
shipped model on a 2-core machine, 2 threads: 17.8 % quiet, 3.7-10.3 %
beside two busy processes; 1 thread: 10.8 % and 10.9 %.

Part 1's reference uses shapely, which only the ``test`` extra installs;
without it part 1 prints the engine's rates alone and says so.

    python benchmarks/bench_unroll.py [--model policy.pt] [--scenes 64] [--frames 250] [--threads 1] [--repeats 5] [--smoke]
"""
from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")  # before numpy and torch start their thread pools

import numpy as np
import torch

try:
    from shapely.geometry import LineString, Polygon
except ImportError:  # pip install -e ".[test]" brings it
    LineString = Polygon = None

from pytest_driveeval.geometry import box_corners
from pytest_driveeval.io.l5.l5kit_zarr import L5Dataset, L5Scene, write_l5_zarr
from pytest_driveeval.policies.baselines import ConstantVelocityPolicy
from pytest_driveeval.policies.loading import load_model
from pytest_driveeval.sim.logreplay import (EGO_EXTENT, LogArrays, UnrollConfig, jit, scenes_from_arrays,
                                            stack_scenes, unroll)
from pytest_driveeval.synth.scenegen import generate_scenes

# The repository's copy of l5kit's test scene (fixtures/SOURCES.md), so a plain checkout has it.
SAMPLE = Path(__file__).resolve().parents[1] / "fixtures" / "l5kit" / "single_scene.zarr"
H, F, N, RADIUS, DT = 10, 12, 30, 35.0, 0.1
KEEP = np.arange(3, 16)  # l5kit's PERCEPTION_LABELS_TO_KEEP
SMOKE_HELP = "every part at tiny sizes in seconds, reference venvs skipped: checks the script runs, measures nothing"
CONFIG = UnrollConfig(history_frames=H, future_frames=F, max_agents=N, agents_radius=RADIUS,
                      drift_threshold=10.0, freeze_on_collision=True)
TARGET_RATE = 40_000  # scene-steps/s for 64 scenes, metrics included (issue 14)
L5KIT_RATE = "804-842"  # l5kit's closed loop, no-op raster, 16 copies (issue 14)


# --------------------------------------------------------------------------- reference (seed notebook style)

def _pose(xy, yaw):
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, xy[0]], [s, c, xy[1]], [0.0, 0.0, 1.0]])


def _relative(points, agent_from_world):
    return points @ agent_from_world[:2, :2].T + agent_from_world[:2, 2]


def _agents_of(scene, t):
    a0, a1 = scene.frames["agent_index_interval"][t]
    return scene.agents[a0:a1]


def _by_labels(agents):
    probs = agents["label_probabilities"]
    return agents[(probs[:, KEEP] > 0.5).any(axis=1)]


def _relative_poses(frames_idx, track_id, per_frame, agent_from_world, yaw0):
    pos, yaws, ext, avail = (np.zeros((len(frames_idx), 2)), np.zeros((len(frames_idx), 1)),
                             np.zeros((len(frames_idx), 2)), np.zeros(len(frames_idx)))
    for i, agents in enumerate(per_frame):
        hit = agents[np.nonzero(agents["track_id"] == track_id)[0]]
        if len(hit) == 0:
            continue
        pos[i], yaws[i], ext[i], avail[i] = hit[0]["centroid"], hit[0]["yaw"], hit[0]["extent"][:2], 1.0
    pos = _relative(pos, agent_from_world) * avail[:, None]
    yaws = ((yaws - yaw0 + np.pi) % (2 * np.pi) - np.pi) * avail[:, None]
    return pos, yaws, ext, avail


def _reference_input(scene, frames_xy, frames_yaw, t):
    n = scene.num_frames
    hist = [f for f in range(t, t - H - 1, -1) if f >= 0]
    fut = [f for f in range(t + 1, t + F + 1) if f < n]
    centroid, yaw = frames_xy[t], frames_yaw[t]
    world_from_agent = _pose(centroid, yaw)
    agent_from_world = np.linalg.inv(world_from_agent)
    hp = np.zeros((H + 1, 2))
    hy = np.zeros((H + 1, 1))
    ha = np.zeros(H + 1)
    for i, f in enumerate(hist):  # ego history: from the (mutated) frames
        hp[i], hy[i], ha[i] = frames_xy[f], frames_yaw[f], 1.0
    hp = _relative(hp, agent_from_world) * ha[:, None]
    hy = ((hy - yaw + np.pi) % (2 * np.pi) - np.pi) * ha[:, None]
    tp, ty, ta = np.zeros((F, 2)), np.zeros((F, 1)), np.zeros(F)
    logged_xy, logged_yaw = scene.ego_positions(), scene.ego_yaws()
    for i, f in enumerate(fut):
        tp[i], ty[i], ta[i] = logged_xy[f], logged_yaw[f], 1.0
    tp = _relative(tp, agent_from_world) * ta[:, None]
    hist_agents = [_agents_of(scene, f) for f in hist]
    fut_agents = [_agents_of(scene, f) for f in fut]
    flat = _by_labels(np.concatenate(hist_agents))
    d = np.linalg.norm(flat["centroid"] - centroid, axis=-1)
    flat = flat[d < RADIUS][np.argsort(d[d < RADIUS])]
    cur = _by_labels(hist_agents[0])
    d = np.linalg.norm(cur["centroid"] - centroid, axis=-1)
    cur = cur[d < RADIUS][np.argsort(d[d < RADIUS])]
    taken: list = []
    for tid in np.concatenate([cur["track_id"], flat["track_id"]]):
        if len(taken) >= N:
            break
        if tid not in taken:
            taken.append(tid)
    ap, ay, ae, aa = np.zeros((N, H + 1, 2)), np.zeros((N, H + 1, 1)), np.zeros((N, H + 1, 2)), np.zeros((N, H + 1))
    types = np.zeros(N)
    for k, tid in enumerate(taken):
        ap[k, :len(hist)], ay[k, :len(hist)], ae[k, :len(hist)], aa[k, :len(hist)] = _relative_poses(
            hist, tid, hist_agents, agent_from_world, yaw)
        _relative_poses(fut, tid, fut_agents, agent_from_world, yaw)  # l5kit computes the agents' futures too
        row = flat[flat["track_id"] == tid][0]
        types[k] = np.argmax(row["label_probabilities"])
    prev = frames_xy[t - 1] if t > 0 else frames_xy[t] - (logged_xy[1] - logged_xy[0])
    speed = np.linalg.norm(frames_xy[t] - prev) / DT
    sample = {"speed": np.array(speed), "extent": EGO_EXTENT, "history_positions": hp, "history_yaws": hy, "history_availabilities": ha, "target_positions": tp,
              "target_yaws": ty, "target_availabilities": ta, "centroid": centroid, "yaw": np.array(yaw),
              "world_from_agent": world_from_agent, "agent_from_world": agent_from_world,
              "all_other_agents_history_positions": ap, "all_other_agents_history_yaws": ay,
              "all_other_agents_history_extents": ae, "all_other_agents_history_availability": aa,
              "all_other_agents_types": types}
    return {k: torch.from_numpy(np.asarray(v, dtype=np.float32))[None] for k, v in sample.items()}


def _reference_collision(centroid, yaw, agents):
    """l5kit.planning.utils.detect_collision: shapely, first agent in range that intersects."""
    ego = Polygon(box_corners(centroid, yaw, EGO_EXTENT))
    ego_diag = np.linalg.norm(EGO_EXTENT[:2])
    for agent in agents:
        if np.linalg.norm(agent["centroid"] - centroid) >= 0.5 * (ego_diag + np.linalg.norm(agent["extent"][:2])):
            continue
        poly = Polygon(box_corners(agent["centroid"], agent["yaw"], agent["extent"]))
        if ego.intersects(poly):
            c = np.asarray(ego.exterior.coords)
            edges = [LineString([c[i], c[i + 1]]) for i in (0, 2, 3, 1)]  # front, rear, left, right
            side = int(np.argmax([poly.intersection(e).length for e in edges]))
            return ("front", "rear", "side", "side")[side], agent["track_id"]
    return "", -1


def reference_unroll(scene: L5Scene, policy, drift_threshold: float = 10.0) -> tuple[float, float, int]:
    """One scene, one forward per frame; returns (total s, model s, steps)."""
    t0 = time.perf_counter()
    model = 0.0
    xy, yaw = scene.ego_positions().copy(), scene.ego_yaws().copy()
    logged = scene.ego_positions()
    steps = 0
    with torch.no_grad():
        for t in range(scene.num_frames):
            batch = _reference_input(scene, xy, yaw, t)
            tic = time.perf_counter()
            out = policy(batch)
            model += time.perf_counter() - tic
            steps += 1
            pos = out["positions"][0].numpy().astype(np.float64)
            pred = _relative(pos[:1], batch["world_from_agent"][0].double().numpy())[0]
            pred_yaw = yaw[t] + float(out["yaws"][0, 0, 0])
            kind, _ = _reference_collision(xy[t], yaw[t], _agents_of(scene, t))
            if kind or t + 1 >= scene.num_frames:
                continue
            if np.linalg.norm(pred - logged[t + 1]) > drift_threshold:
                continue
            xy[t + 1], yaw[t + 1] = pred, pred_yaw
    return time.perf_counter() - t0, model, steps


# --------------------------------------------------------------------------- generated scenes

def generated_log(num_scenes: int, num_frames: int, seed: int = 0) -> LogArrays:
    return stack_scenes(scenes_from_arrays(generate_scenes(num_scenes, num_frames, seed=seed)))


def _rate(result) -> float:
    return result.scene_steps / result.harness_time


def write_copies(sample: str, copies: int, path: Path) -> Path:
    """A zarr holding ``copies`` copies of the sample's scenes, back to back (intervals shifted)."""
    scenes, frames, agents, faces = L5Dataset.open(sample).read_all()
    n_f, n_a, n_l = len(frames), len(agents), len(faces)
    scenes, frames = np.concatenate([scenes] * copies), np.concatenate([frames] * copies)
    copy = np.arange(copies)
    scenes["frame_index_interval"] += np.repeat(copy * n_f, len(scenes) // copies)[:, None]
    frames["agent_index_interval"] += np.repeat(copy * n_a, n_f)[:, None]
    frames["traffic_light_faces_index_interval"] += np.repeat(copy * n_l, n_f)[:, None]
    return write_l5_zarr(path, scenes, frames, np.concatenate([agents] * copies), np.concatenate([faces] * copies))


def load(store: Path, count: int, repeat_first: bool = False) -> tuple[float, LogArrays]:
    """Seconds to read ``count`` scenes (scene 0 each time with ``repeat_first``) and stack them."""
    t0 = time.perf_counter()
    dataset = L5Dataset.open(store)
    log = stack_scenes([dataset.scene(0 if repeat_first else i) for i in range(count)])
    return time.perf_counter() - t0, log


def _median_run(log: LogArrays, policy, repeats: int) -> tuple[object, list]:
    """The run with the median harness time of ``repeats`` (after a warm-up), and all of them."""
    unroll(log, policy, CONFIG)  # warm-up (numba kernels load from their cache or compile here)
    runs = sorted((unroll(log, policy, CONFIG) for _ in range(repeats)), key=lambda r: r.harness_time)
    return runs[len(runs) // 2], runs


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--model", help="policy for part 2, as load_model reads it: .pt2, TorchScript, ... "
                        "(default: constant velocity)")
    parser.add_argument("--scenes", type=int, default=64)
    parser.add_argument("--frames", type=int, default=250)
    parser.add_argument("--sample", default=str(SAMPLE))
    parser.add_argument("--copies", type=int, default=64, help="copies of the real scene batched in part 1")
    parser.add_argument("--threads", type=int, default=1, help="torch threads (the figures are comparable at 1)")
    parser.add_argument("--repeats", type=int, default=5, help="unrolls timed per engine figure (median)")
    parser.add_argument("--smoke", action="store_true", help=SMOKE_HELP)
    args = parser.parse_args()
    if args.smoke:
        args.copies, args.scenes, args.frames, args.repeats = 2, 2, 30, 1
        print("smoke run: tiny sizes; the figures mean nothing")
    torch.set_num_threads(args.threads)
    print(f"threads: torch {torch.get_num_threads()}, OMP_NUM_THREADS={os.environ['OMP_NUM_THREADS']}")
    # Steady state: the compiled paths from the start (a process pays ~0.5 s once for numba, in the warm-ups).
    print(f"numba paths: {'on' if jit.start() else 'off (numba is not installed: the numpy paths)'}")
    cv = torch.jit.script(ConstantVelocityPolicy(F))

    print("== part 1: real sample scene, constant-velocity policy, harness time only")
    scene = L5Dataset.open(args.sample).scene(0)
    ref_rate = None
    if Polygon is None:
        print("reference skipped: it is l5kit's detect_collision, which needs shapely "
              "(pip install -e \".[test]\"); the engine's rates follow without a ratio")
    else:
        total, model, steps = reference_unroll(scene, cv)
        ref_rate = steps / (total - model)
        print(f"reference (seed notebook style): {steps} steps, harness {total - model:.3f} s, model {model:.3f} s "
              f"-> {ref_rate:,.0f} scene-steps/s")
    for copies in dict.fromkeys((1, args.copies)):
        res, runs = _median_run(stack_scenes([scene] * copies), cv, args.repeats)
        ratio = f" = {_rate(res) / ref_rate:.1f}x the reference" if ref_rate else ""
        rates = [_rate(r) for r in runs]
        print(f"engine, {copies:2d} scene(s) batched: {res.scene_steps} steps, harness {res.harness_time:.3f} s "
              f"(metrics included), model {res.model_time:.3f} s -> {_rate(res):,.0f} scene-steps/s "
              f"(median of {len(runs)}, {min(rates):,.0f}-{max(rates):,.0f}){ratio}")
    print(f"engine vs issue 14: {_rate(res):,.0f} scene-steps/s for {args.copies} scenes, metrics included "
          f"(target >= {TARGET_RATE:,}: {'met' if _rate(res) >= TARGET_RATE else 'NOT met'}; "
          f"{_rate(res) / 842:.0f}-{_rate(res) / 804:.0f}x l5kit's {L5KIT_RATE} with a no-op raster)")

    with tempfile.TemporaryDirectory() as tmp:
        store = write_copies(args.sample, args.copies, Path(tmp) / "copies.zarr")
        load(store, args.copies)  # warm-up: the store's files in the page cache, as for a dataset read before
        loads = sorted(load(store, args.copies)[0] for _ in range(3))
        _, loaded = load(store, args.copies)
        same = sorted(load(Path(args.sample), args.copies, repeat_first=True)[0] for _ in range(3))
    res = _median_run(loaded, cv, 3)[0]
    unrolled = res.total_time
    print(f"loading {args.copies} scenes into arrays (read from a {args.copies}-scene zarr + stack_scenes): "
          f"{loads[1]:.3f} s (median of 3, {loads[0]:.3f}-{loads[2]:.3f}; the sample's scene read {args.copies} "
          f"times: {same[1]:.3f} s) vs unrolling them {unrolled:.3f} s (harness + model, metrics included): "
          f"loading = {loads[1] / unrolled:.2f}x unrolling (target < 1; issue 14: 3.7 s vs 1.0 s)")

    print(f"\n== part 2: {args.scenes} generated scenes x {args.frames} frames batched")
    model = load_model(args.model) if args.model else cv
    log = generated_log(args.scenes, args.frames)
    unroll(log.take(np.arange(min(2, args.scenes))), model, CONFIG)  # warm-up
    runs = sorted((unroll(log, model, CONFIG) for _ in range(3)), key=lambda r: r.harness_time / r.total_time)
    res = runs[1]  # the median share of three runs
    share = res.harness_time / res.total_time
    print(f"model {args.model or 'constant velocity (TorchScript)'}: {res.forwards} forwards, "
          f"{res.scene_steps} scene-steps, total {res.total_time:.3f} s, model {res.model_time:.3f} s, "
          f"harness {res.harness_time:.3f} s = {100 * share:.1f}% of the total (median of 3, "
          f"{min(100 * r.harness_time / r.total_time for r in runs):.1f}-"
          f"{max(100 * r.harness_time / r.total_time for r in runs):.1f}%); "
          f"harness rate {_rate(res):,.0f} scene-steps/s")


if __name__ == "__main__":
    main()
