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

A process keeps the model (and semantic map) a chunk loaded for the next chunks of the same item
(execute.reuse, issue 25).  The warm-up run loads a copy of the model under another name, so a
measured run still loads the item's model once per worker process, as the chunks here load it
once in this process.  ``--reuse-off`` adds, in the same run, the chunks here and on the two-node
cluster with reuse turned off (``DRIVEEVAL_REUSE=0``: every chunk loads its own, as before);
efficiency is always against the chunks here with reuse, the cheapest way to run them here.
Each row names the machine's load average (1 min) when it ended: other jobs on the same cores
stretch the cluster's wall time more than the one-process reference's.

    OMP_NUM_THREADS=1 python benchmarks/bench_ray.py [--episodes 10000] [--scenes 1000] [--steps 50] [--no-cluster]
                                                     [--only policy|closed_loop] [--big-nodes 8 (0: none)]
                                                     [--reuse-off] [--smoke]
"""
from __future__ import annotations

import argparse
import contextlib
import logging
import os
import shutil
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402
import torch  # noqa: E402

from pytest_driveeval.execute import ExecutorSpec, run_chunks  # noqa: E402
from pytest_driveeval.execute.reuse import SWITCH  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
GNN = REPO / "fixtures" / "models" / "gnn_actor_merging.pt2"
PLANNING_MODEL = REPO / "fixtures" / "models" / "planning_model.pt2"
SMOKE_HELP = ("every part at tiny sizes in seconds, no cluster (the chunks run here only): checks the script runs, "
              "measures nothing")


#: Ray starts its workers at nice 15 (so that raylets and the GCS come first).  On a dedicated
#: cluster nothing else competes for the cores; on this machine, shared with other jobs at nice 0,
#: workers at nice 15 get a fraction of what the reference (chunks here, nice 0) gets, and the
#: efficiency measured the load of the other jobs.  0: the same priority as the reference.
WORKER_NICENESS = 0


@contextlib.contextmanager
def local_cluster(nodes: int, cpus: float, niceness: int | None = WORKER_NICENESS):
    import ray
    from ray.cluster_utils import Cluster

    config = {} if niceness is None else {"_system_config": {"worker_niceness": niceness}}
    cluster = Cluster(initialize_head=True, connect=True, head_node_args={"num_cpus": 0, **config})
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
    processes = len({(p.node_id, p.pid) for p in run.placements})
    # Against the chunks' own time on a quiet process: inside a chunk on an oversubscribed node
    # the seconds stretch, which is part of the cost.
    overhead = (wall * slots - sequential) / chunks
    print(f"  {name}: {wall:7.2f} s wall, {chunks} chunks on {len(run.nodes)} node(s), {processes} process(es), "
          f"{slots:g} core(s); inside chunks {inside:.1f} s; overhead per chunk {overhead * 1000:.0f} ms; parallel "
          f"efficiency {sequential / (wall * slots):.2f} (vs one batch {one_batch / (wall * slots):.2f}); speed-up "
          f"over one batch {one_batch / wall:.2f}x; {same}; load {os.getloadavg()[0]:.2f}")


REUSE_OFF = {"env_vars": {SWITCH: "0"}}
_TICK = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100


def _process_table() -> dict[int, tuple[int, str, float]]:
    """pid -> (parent pid, what it is, CPU seconds so far) of every process /proc shows."""
    table = {}
    for entry in Path("/proc").iterdir() if Path("/proc/self/stat").exists() else ():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
            command = (entry / "cmdline").read_bytes().split(b"\0")[0].decode(errors="replace")
        except OSError:
            continue
        fields = stat[stat.rindex(")") + 2:].split()
        seconds = (int(fields[11]) + int(fields[12])) / _TICK
        table[int(entry.name)] = (int(fields[1]), command, seconds)
    return table


def _kind(command: str) -> str:
    if command.startswith("ray::"):
        # ray::IDLE, ray::<task name>: worker processes; ray::DashboardAgent, ray::RuntimeEnvAgent: one per node
        return "Ray agents" if command.endswith("Agent") else "workers"
    for name in ("raylet", "gcs_server"):
        if command.endswith(name):
            return name + "s" if name == "raylet" else name
    return "other Ray processes"


def tree_cpu() -> dict[str, float]:
    """CPU seconds so far of this process and its descendants (the local cluster's), by kind."""
    table = _process_table()
    me = os.getpid()
    totals: dict[str, float] = {}
    for pid, (_, command, seconds) in table.items():
        ancestor, chain = pid, 0
        while ancestor not in (me, 0, 1) and ancestor in table and chain < 64:
            ancestor, chain = table[ancestor][0], chain + 1
        if ancestor == me:
            kind = "driver" if pid == me else _kind(command)
            totals[kind] = totals.get(kind, 0.0) + seconds
    return totals


def warmed(warm_run, run) -> str:
    """Whether the measured run's worker processes are those the warm-up started (a new one
    imports torch and compiles the numba kernels inside the measured run: seconds of CPU)."""
    ran = {(p.node_id, p.pid) for p in run.placements}
    warm = {(p.node_id, p.pid) for p in warm_run.placements}
    return f"{len(ran & warm)} of the measured run's {len(ran)} worker process(es) ran the warm-up"


def cpu_breakdown(before: dict[str, float], after: dict[str, float], sequential_cpu: float) -> str:
    """Where the cores went during a cluster run (processes that exited during it are missed)."""
    spent = {k: after.get(k, 0.0) - before.get(k, 0.0) for k in after}
    total = sum(spent.values())
    parts = ", ".join(f"{k} {v:.1f}" for k, v in sorted(spent.items(), key=lambda kv: -kv[1]) if v >= 0.05)
    return (f"    CPU seconds during it: {parts} (all {total:.1f}); the chunks here took {sequential_cpu:.1f} CPU s: "
            f"CPU efficiency {sequential_cpu / total:.2f}" if total > 0 else "    CPU seconds: /proc unreadable")


@contextlib.contextmanager
def reuse_off_here():
    before = os.environ.get(SWITCH)
    os.environ[SWITCH] = "0"
    try:
        yield
    finally:
        if before is None:
            del os.environ[SWITCH]
        else:
            os.environ[SWITCH] = before


def warm_copy(model: Path, folder: str) -> Path:
    """The model under another name: the warm-up run starts the workers and imports torch without
    leaving the measured run's model loaded in them."""
    copy = Path(folder) / f"warm_{model.name}"
    shutil.copyfile(model, copy)
    return copy


def on_clusters(args, work, task_fn, warm_work, compare, sequential: float, one_batch: float,
                sequential_cpu: float) -> None:
    if args.no_cluster:
        print("  clusters skipped (--no-cluster)")
        return
    cores = os.cpu_count() or 1
    for nodes in (2, args.big_nodes) if args.big_nodes else (2,):
        label = f"{nodes} worker nodes x 1 CPU" + (f" (simulated: {cores / nodes:.2g} core each)" if nodes > cores
                                                   else "")
        with local_cluster(nodes, 1):
            spec = ExecutorSpec(Kind="ray")
            warm_run, cold = timed(run_chunks, spec, warm_work, task_fn)
            before = tree_cpu()
            run, wall = timed(run_chunks, spec, work, task_fn)
            after = tree_cpu()
            print(f"  cluster of {label}: cold start (workers starting, first tiny run) {cold:.1f} s; "
                  f"{warmed(warm_run, run)}")
            report("cluster", run, wall, min(nodes, cores), sequential, one_batch, compare(run))
            print(cpu_breakdown(before, after, sequential_cpu))
            if args.reuse_off and nodes == 2:
                # Workers of another runtime env: started and warmed afresh.
                off = ExecutorSpec(Kind="ray", RuntimeEnv=REUSE_OFF)
                warm_run = run_chunks(off, warm_work, task_fn)
                before = tree_cpu()
                run, wall = timed(run_chunks, off, work, task_fn)
                after = tree_cpu()
                print(f"  {warmed(warm_run, run)}")
                report("cluster, reuse off", run, wall, min(nodes, cores), sequential, one_batch, compare(run))
                print(cpu_breakdown(before, after, sequential_cpu))


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
    cpu = time.process_time()
    here, sequential = timed(run_chunks, ExecutorSpec(), work, run_episode_chunk)
    sequential_cpu = time.process_time() - cpu

    def compare(run) -> str:
        done = merged(run.results)
        identical = all(np.array_equal(getattr(done, f), getattr(whole, f)) for f in ("outcome", "returns", "steps"))
        return "results identical to one batch" if identical else "RESULTS DIFFER from one batch"

    report("chunks here", here, sequential, 1, sequential, one_batch, compare(here))
    if args.reuse_off:
        with reuse_off_here():
            off, seconds = timed(run_chunks, ExecutorSpec(), work, run_episode_chunk)
        report("chunks here, reuse off", off, seconds, 1, sequential, one_batch, compare(off))
    with tempfile.TemporaryDirectory() as folder:
        warm_model = warm_copy(GNN, folder)
        warm = episode_chunks("gnn", PolicySource(warm_model.name, folder), "merging", {}, seeds[:8], 12, 1)
        on_clusters(args, work, run_episode_chunk, warm, compare, sequential, one_batch, sequential_cpu)


def closed_loop(args) -> None:
    from pytest_driveeval.io.l5.l5kit_zarr import L5Dataset
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
    cpu = time.process_time()
    here, sequential = timed(run_chunks, ExecutorSpec(), work, run_scene_chunk)
    sequential_cpu = time.process_time() - cpu
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
    if args.reuse_off:
        with reuse_off_here():
            off, seconds = timed(run_chunks, ExecutorSpec(), work, run_scene_chunk)
        report("chunks here, reuse off", off, seconds, 1, sequential, one_batch, compare(off))
    with tempfile.TemporaryDirectory() as folder:
        warm_model = warm_copy(PLANNING_MODEL, folder)
        warm = scene_chunks(str(path), ids[:2], config, str(warm_model), None, str(REPO), ExecutorSpec(ChunkSize=1))
        on_clusters(args, work, run_scene_chunk, warm, compare, sequential, one_batch, sequential_cpu)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--episodes", type=int, default=10_000)
    parser.add_argument("--episode-chunk", type=int, default=250)
    parser.add_argument("--scenes", type=int, default=1_000)
    parser.add_argument("--scene-chunk", type=int, default=50)
    parser.add_argument("--steps", type=int, default=50)
    parser.add_argument("--big-nodes", type=int, default=8, help="the simulated larger cluster's nodes (0: none)")
    parser.add_argument("--reuse-off", action="store_true",
                        help="also the chunks here and on two nodes with execute.reuse off (as before issue 25)")
    parser.add_argument("--data", default="~/.cache/driveeval-bench")
    parser.add_argument("--only", choices=("policy", "closed_loop"))
    parser.add_argument("--no-cluster", action="store_true", help="one batch and chunks here only")
    parser.add_argument("--smoke", action="store_true", help=SMOKE_HELP)
    args = parser.parse_args()
    if args.smoke:
        with tempfile.TemporaryDirectory() as data:
            # two chunks of each workload, the least that exercises merging them
            args.episodes, args.episode_chunk, args.scenes, args.scene_chunk, args.steps = 8, 4, 2, 1, 5
            args.no_cluster, args.data, args.reuse_off = True, data, True
            print("smoke run: tiny sizes, no cluster, scenes generated in a temporary folder; the figures mean "
                  "nothing")
            run(args)
    else:
        run(args)


def run(args) -> None:
    torch.set_num_threads(1)
    print(f"{os.cpu_count()} cores; torch on 1 thread here and in every chunk; load average (1, 5, 15 min) "
          f"{', '.join(f'{x:.2f}' for x in os.getloadavg())}")
    if args.only != "closed_loop":
        policy_benchmark(args)
    if args.only != "policy":
        closed_loop(args)


if __name__ == "__main__":
    main()
