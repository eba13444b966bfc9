"""policy_benchmark items on a real local Ray cluster (a head and two worker nodes on this
machine, tests/ray_items.py) give the outcome, figures and artefacts of the same
items run locally."""
from __future__ import annotations

import math
import os
import signal
import threading
import time
from pathlib import Path

import pytest

pytest.importorskip("torch")
pytest.importorskip("scipy")
ray = pytest.importorskip("ray")

import ray_items  # noqa: E402  (tests/ray_items.py)
from conftest import NO_HYPOTHESIS_PLUGIN  # noqa: E402
from ray_items import WORKER_CPUS, assert_same_items, executor_section, worker_nodes  # noqa: E402

# the module's fixture: a head and two worker nodes, one cluster for all of the module's tests (the
# scheduler keeps a module that imports ray_items on one xdist worker)
cluster = ray_items.cluster

pytestmark = pytest.mark.ray

REPO = Path(__file__).resolve().parents[3]
GNN = REPO / "fixtures" / "models" / "gnn_actor_merging.pt2"

BENCHMARK = """\
ScenarioFormatVersion: 3.0.0
ScenarioName: bench
Evaluation:
  UseCaseName: policy_benchmark
  UseCaseFormatVersion: 0.1.0
  Blueprint: {{Name: merging}}
  Episodes: {episodes}
  Policies:
    gnn: {gnn}
    random: random
    constant: constant
  Judged: [gnn]
  Conditions:
    GoalRate: {{AtLeast: 50}}
    Beats: [{{Baseline: random, Metric: goal_rate}}, {{Baseline: constant, Metric: goal_rate}}]
  Artefacts: {{Animations: all, ComparisonPlot: false}}
{executor}"""

SEARCH = """\
ScenarioFormatVersion: 3.0.0
ScenarioName: search
Evaluation:
  UseCaseName: policy_benchmark
  UseCaseFormatVersion: 0.1.0
  Blueprint: {{Name: merging}}
  Episodes: 16
  Policies:
    constant: constant
  Perturbation:
    Lateral: [-0.5, 0.5]
    Heading: [-0.05, 0.05]
    SpeedScale: [0.8, 1.2]
    GapScale: [0.7, 1.5]
    Examples: 24
    Batch: 12
    FailOn: [collision]   # it leaves the road unperturbed: the search would end at its first example
  Artefacts: {{Animations: all}}
{executor}"""


def test_the_session_option_runs_the_chunks_on_both_nodes_with_the_local_outcome(cluster, pytester):
    # The Ray run in a separate process, as a CI job would be: it connects to the cluster by its
    # address.  The local run needs no fresh process (nor its second torch import).  Each chunk takes
    # a whole two-CPU node (NumCpus: 2), so two in flight need both nodes, and only two workers of the
    # new process's job import torch and load the model (each worker of a new job does, ~5 s).
    pytester.makefile(".scenario.yaml", bench=BENCHMARK.format(episodes=6, gnn=GNN, executor=""))
    local = pytester.runpytest("-p", "no:randomly", "--driveeval-output", "local")
    option = f"{{Kind: ray, Address: '{cluster.address}', ChunkSize: 3, MaxInFlight: 2, NumCpus: 2}}"
    remote = pytester.runpytest_subprocess("-p", "no:randomly", *NO_HYPOTHESIS_PLUGIN, "--driveeval-output",
                                           "remote", "--driveeval-executor", option)
    local.assert_outcomes(passed=3)
    remote.assert_outcomes(passed=3)
    records = assert_same_items(pytester.path / "local", pytester.path / "remote")
    judged = records["bench.scenario.yaml::policy_benchmark[gnn]"]
    where = judged["details"]["executor"]
    # 6 episodes in chunks of 3 for the judged policy and each of the two baselines it beats: six
    # chunks, two of them in flight at once, each of two CPUs: more than one two-CPU node can run
    assert len(where["chunks"]) == 3 * 2 and [c["chunk"] for c in where["chunks"]] == list(range(6))
    assert where["chunks"][0]["work"] == "gnn seeds 0..2" and where["chunks"][-1]["work"] == "constant seeds 3..5"
    assert {c["node"] for c in where["chunks"]} == worker_nodes(), "two two-CPU chunks in flight need both nodes"
    assert "6 chunks on ray" in where["summary"] and "2 node(s)" in where["summary"]
    assert any(name.endswith("_gif") for name in judged["artefacts"]), "the episode GIF is drawn on the driver"
    # the Ray connection the session opened is closed with it; the cluster stays up
    assert len(worker_nodes()) == 2


def test_the_scenarios_executor_section_and_a_robustness_search_match_local(cluster, pytester):
    pytester.makefile(".scenario.yaml", search=SEARCH.format(executor=""))
    local = pytester.runpytest("-p", "no:randomly", "--driveeval-output", "local", "--driveeval-search-profile", "ci")
    pytester.makefile(".scenario.yaml", search=SEARCH.format(executor=executor_section(Kind="ray", ChunkSize=4)))
    remote = pytester.runpytest("-p", "no:randomly", "--driveeval-output", "remote", "--driveeval-search-profile",
                                "ci")
    assert local.ret == remote.ret
    records = assert_same_items(pytester.path / "local", pytester.path / "remote")
    details = records["search.scenario.yaml::policy_benchmark[constant]"]["details"]
    where, examples = details["executor"], details["search"]["examples"]
    # the generations' examples went out in chunks of at most 4 (ChunkSize)
    assert examples > 12 and sum(where["chunks_per_node"].values()) >= math.ceil(examples / 4)
    assert "batch(es) on ray" in where["summary"]


def _running_chunk(raylet_pid: int) -> int | None:
    """The pid of a worker under that raylet that is running a chunk (Ray titles a worker after
    the task it runs: ``ray::driveeval chunk 3``), read from /proc."""
    children: dict[int, list[int]] = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        children.setdefault(int(fields[1]), []).append(int(stat.parent.name))
    below, found = [raylet_pid], []
    while below:
        pid = below.pop()
        for child in children.get(pid, []):
            below.append(child)
            found.append(child)
    for pid in found:
        try:
            if b"driveeval chunk" in Path(f"/proc/{pid}/cmdline").read_bytes():
                return pid
        except OSError:
            continue
    return None


def test_a_worker_node_killed_mid_item_costs_retries_not_the_outcome(cluster, pytester):
    doomed = cluster.add_node(num_cpus=WORKER_CPUS)
    cluster.wait_for_nodes()
    raylet = doomed.all_processes["raylet"][0].process.pid
    killed, stop = threading.Event(), threading.Event()

    def kill_once_a_chunk_runs_there():
        # As a machine that dies: its raylet and the worker under way on a chunk go together
        # (a worker outlives its raylet for a while and could still deliver).
        while not (killed.is_set() or stop.is_set()):
            worker = _running_chunk(raylet)
            if worker is not None:
                cluster.remove_node(doomed, allow_graceful=False)
                try:
                    os.kill(worker, signal.SIGKILL)
                except ProcessLookupError:
                    pass
                killed.set()
            time.sleep(0.01)

    # 6 chunks of 8 episodes per policy (a few tenths of a second each), six at a time over three
    # nodes: a chunk Ray gives the new node waits there for its first worker, so one runs there
    pytester.makefile(".scenario.yaml", bench=BENCHMARK.format(episodes=48, gnn=GNN, executor=""))
    local = pytester.runpytest("-p", "no:randomly", "--driveeval-output", "local", "-k", "gnn")
    pytester.makefile(".scenario.yaml", bench=BENCHMARK.format(
        episodes=48, gnn=GNN, executor=executor_section(Kind="ray", ChunkSize=8, MaxInFlight=6, Retries=3)))
    killer = threading.Thread(target=kill_once_a_chunk_runs_there, daemon=True)
    killer.start()
    try:
        remote = pytester.runpytest("-p", "no:randomly", "--driveeval-output", "remote", "-k", "gnn")
    finally:
        stop.set()
        killer.join()
    assert killed.is_set(), "no chunk ran on the third node while the item ran"
    local.assert_outcomes(passed=1)
    remote.assert_outcomes(passed=1)
    assert not any(n["NodeID"] == doomed.node_id and n["Alive"] for n in ray.nodes())
    records = assert_same_items(pytester.path / "local", pytester.path / "remote")
    chunks = records["bench.scenario.yaml::policy_benchmark[gnn]"]["details"]["executor"]["chunks"]
    retried = [c for c in chunks if c["attempts"] > 1]
    assert retried, "a chunk was running on the killed node: it needed another attempt"
    assert all(c["node"] != doomed.node_id for c in retried)
