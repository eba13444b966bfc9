"""Items on a local Ray cluster against the same work run here (issue 15).

Two workloads, each run three ways and compared:

* policy benchmark: the shipped GNN on ``--episodes`` merging episodes (default 10,000);
* closed loop: the shipped planning model on ``--scenes`` generated scenes (default 1,000,
  written once to ``--data``), ``--steps`` steps each, judged as the use case judges them.

``one batch`` is the use case's local path (every episode or scene stepping together, the
default); ``chunks here`` the same chunks as the cluster's, one after the other in this
process (``Executor: {Kind: local, ChunkSize: N}``); ``cluster`` a head without CPUs and two
worker nodes of one CPU each (``ray.cluster_utils.Cluster``, torn down at the end, never ``ray
stop``), then a simulated larger cluster: ``--big-nodes`` nodes that each claim one CPU where
the machine has two cores (Ray wants whole CPUs per node; 8 nodes on 2 cores are nodes of
0.25 core each), so more nodes, raylets and worker processes share the same cores.

Figures: wall time; the cold start (worker processes starting and importing torch, on a
first tiny run); per-chunk overhead = (wall x cores used - the chunks' time here) / chunks,
the core time not spent on the chunks' own work (cores used: the cluster's CPUs, at most the
machine's);
parallel efficiency = (chunks here) / (wall x cores used).  On a 2-core machine the driver
shares the cores with the workers, so efficiency is bounded below 1.
Whether the results are identical is printed, never asserted.

    OMP_NUM_THREADS=1 python benchmarks/bench_ray.py [--episodes 10000] [--scenes 1000] [--steps 50] [--no-cluster]
                                                     [--smoke]
"""
from __future__ import annotations

import argparse
import contextlib
import logging
import os
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402
import torch  # noqa: E402

from pytest_driveeval.execute import ExecutorSpec, run_chunks  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
GNN = REPO / "fixtures" / "models" / "gnn_actor_merging.pt2"
PLANNING_MODEL = REPO / "fixtures" / "models" / "planning_model.pt2"
SMOKE_HELP = ("every part at tiny sizes in seconds, no cluster (the chunks run here only): checks the script runs, "
              "measures nothing")


@contextlib.contextmanager
def local_cluster(nodes: int, cpus: float):
    import ray
    from ray.cluster_utils import Cluster

    cluster = Cluster(initialize_head=True, connect=True, head_node_args={"num_cpus": 0})
    try:
        for _ in range(nodes):
            cluster.add_node(num_cpus=cpus)
        cluster.wait_for_nodes()
        logging.getLogger("ray").setLevel(logging.WARNING)
        yield cluster
    finally:
        ray.shutdown()
        cluster.shutdown()


def timed(fn, *args, **kwargs):
    begun = time.perf_counter()
    out = fn(*args, **kwargs)
    return out, time.perf_counter() - begun


def report(name: str, run, wall: float, slots: float, sequential: float, one_batch: float, same: str) -> None:
    inside = sum(p.seconds for p in run.placements)
    chunks = len(run.placements)
    # Against the chunks' own time on a quiet process: inside a chunk on an oversubscribed node
    # the seconds stretch, which is part of the cost.
    overhead = (wall * slots - sequential) / chunks
    print(f"  {name}: {wall:7.2f} s wall, {chunks} chunks on {len(run.nodes)} node(s), {slots:g} core(s); "
          f"inside chunks {inside:.1f} s; overhead per chunk {overhead * 1000:.0f} ms; parallel efficiency "
          f"{sequential / (wall * slots):.2f} (vs one batch {one_batch / (wall * slots):.2f}); speed-up over "
          f"one batch {one_batch / wall:.2f}x; {same}")


def on_clusters(args, work, task_fn, warm_work, compare, sequential: float, one_batch: float) -> None:
    if args.no_cluster:
        print("  clusters skipped (--no-cluster)")
        return
    cores = os.cpu_count() or 1
    for nodes in (2, args.big_nodes):
        label = f"{nodes} worker nodes x 1 CPU" + (f" (simulated: {cores / nodes:.2g} core each)" if nodes > cores
                                                   else "")
        with local_cluster(nodes, 1):
            spec = ExecutorSpec(Kind="ray")
            _, cold = timed(run_chunks, spec, warm_work, task_fn)
            run, wall = timed(run_chunks, spec, work, task_fn)
            print(f"  cluster of {label}: cold start (workers starting, first tiny run) {cold:.1f} s")
            report("cluster", run, wall, min(nodes, cores), sequential, one_batch, compare(run))


def policy_benchmark(args) -> None:
    from pytest_driveeval.policies.loading import load_model
    from pytest_driveeval.sim.blueprints import make_blueprint
    from pytest_driveeval.usecases.policy_benchmark.chunked import (PolicySource, episode_chunks, merged,
                                                                    run_episode_chunk)
    from pytest_driveeval.usecases.policy_benchmark.evaluate import run_policy, seeds_for

    print(f"policy benchmark: shipped GNN, merging, {args.episodes} episodes, chunks of {args.episode_chunk}")
    blueprint = make_blueprint("merging")
    seeds, strata = seeds_for(0, args.episodes, 8)
    whole, one_batch = timed(run_policy, blueprint, seeds, load_model(str(GNN)), "gnn", strata=strata)
    print(f"  one batch here: {one_batch:7.2f} s ({args.episodes / one_batch:.0f} episodes/s)")
    source = PolicySource(GNN.name, str(GNN.parent))
    work = episode_chunks("gnn", source, "merging", {}, seeds, 12, args.episode_chunk)
    here, sequential = timed(run_chunks, ExecutorSpec(), work, run_episode_chunk)

    def compare(run) -> str:
        done = merged(run.results)
        identical = all(np.array_equal(getattr(done, f), getattr(whole, f)) for f in ("outcome", "returns", "steps"))
        return "results identical to one batch" if identical else "RESULTS DIFFER from one batch"

    report("chunks here", here, sequential, 1, sequential, one_batch, compare(here))
    warm = episode_chunks("gnn", source, "merging", {}, seeds[:8], 12, 1)
    on_clusters(args, work, run_episode_chunk, warm, compare, sequential, one_batch)


def closed_loop(args) -> None:
    from pytest_driveeval.io.l5kit_zarr import L5Dataset
    from pytest_driveeval.policies.loading import load_model
    from pytest_driveeval.sim.torch_threads import one_torch_thread
    from pytest_driveeval.usecases.closed_loop import replayed_agents
    from pytest_driveeval.usecases.closed_loop.chunked import merged, run_scene_chunk, scene_chunks
    from pytest_driveeval.usecases.closed_loop.config import ClosedLoopConfig
    from pytest_driveeval.usecases.closed_loop.evaluate import judge_scene, unroll_scenes

    path = Path(args.data).expanduser() / f"bench_ray_{args.scenes}.zarr"
    if not path.exists():
        from pytest_driveeval.synth.scenegen import generate_zarr

        print(f"  generating {args.scenes} scenes x 100 frames into {path} (once)")
        generate_zarr(path, args.scenes, 100, seed=0)
    print(f"closed loop: shipped planning model, {args.scenes} generated scenes, {args.steps} steps from frame 10, "
          f"chunks of {args.scene_chunk}")
    config = ClosedLoopConfig.model_validate({
        "Model": str(PLANNING_MODEL), "Unroll": {"StartFrame": 10, "Steps": args.steps},
        "Conditions": {"Collisions": {"AtFaultOnly": True}, "Displacement": {"Max": 4.0}},
        "Artefacts": {"Animations": "none", "Charts": False}})
    dataset = L5Dataset.open(path)
    ids = list(range(dataset.num_scenes))

    def one_batch_run():
        with one_torch_thread():
            unroll = unroll_scenes(dataset, load_model(str(PLANNING_MODEL)), ids, **config.Unroll.unroll_options(),
                                   agents=replayed_agents(config.Unroll.Agents))
        return [judge_scene(unroll, row, config.Conditions) for row in range(len(ids))]

    whole, one_batch = timed(one_batch_run)
    print(f"  one batch here: {one_batch:7.2f} s ({len(ids) * args.steps / one_batch:.0f} scene-steps/s)")
    spec = ExecutorSpec(ChunkSize=args.scene_chunk)
    work = scene_chunks(str(path), ids, config, str(PLANNING_MODEL), None, str(REPO), spec)
    here, sequential = timed(run_chunks, ExecutorSpec(), work, run_scene_chunk)
    reference = merged(here.results).verdicts

    def differences(verdicts) -> tuple[int, int, float]:
        """(scenes whose verdict differs from one batch, scenes whose figures differ, the largest difference)"""
        verdict = sum(a.passed != b.passed for a, b in zip(verdicts, whole))
        figures = [max(abs(a.figures[k] - b.figures[k]) for k in a.figures) for a, b in zip(verdicts, whole)]
        return verdict, sum(f > 0 for f in figures), max(figures)

    def compare(run) -> str:
        verdicts = merged(run.results).verdicts
        same_as_chunks = all(a.passed == b.passed and a.figures == b.figures and
                             [f.to_json() for f in a.findings] == [f.to_json() for f in b.findings]
                             for a, b in zip(verdicts, reference))
        verdict, figures, largest = differences(verdicts)
        return (f"{'identical to' if same_as_chunks else 'DIFFERENT from'} the chunks run here; against one "
                f"batch: {verdict} verdict(s) differ, figures of {figures} scene(s) by <= {largest:.1e} "
                "(float32 rounding with the batch size)")

    report("chunks here", here, sequential, 1, sequential, one_batch, compare(here))
    warm = scene_chunks(str(path), ids[:2], config, str(PLANNING_MODEL), None, str(REPO), ExecutorSpec(ChunkSize=1))
    on_clusters(args, work, run_scene_chunk, warm, compare, sequential, one_batch)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--episodes", type=int, default=10_000)
    parser.add_argument("--episode-chunk", type=int, default=250)
    parser.add_argument("--scenes", type=int, default=1_000)
    parser.add_argument("--scene-chunk", type=int, default=50)
    parser.add_argument("--steps", type=int, default=50)
    parser.add_argument("--big-nodes", type=int, default=8)
    parser.add_argument("--data", default="~/.cache/driveeval-bench")
    parser.add_argument("--only", choices=("policy", "closed_loop"))
    parser.add_argument("--no-cluster", action="store_true", help="one batch and chunks here only")
    parser.add_argument("--smoke", action="store_true", help=SMOKE_HELP)
    args = parser.parse_args()
    if args.smoke:
        with tempfile.TemporaryDirectory() as data:
            args.episodes, args.episode_chunk, args.scenes, args.scene_chunk, args.steps = 16, 8, 4, 2, 5
            args.no_cluster, args.data = True, data
            print("smoke run: tiny sizes, no cluster, scenes generated in a temporary folder; the figures mean "
                  "nothing")
            run(args)
    else:
        run(args)


def run(args) -> None:
    torch.set_num_threads(1)
    print(f"{os.cpu_count()} cores; torch on 1 thread here and in every chunk")
    if args.only != "closed_loop":
        policy_benchmark(args)
    if args.only != "policy":
        closed_loop(args)


if __name__ == "__main__":
    main()
