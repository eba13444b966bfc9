"""The Ray path on a real local cluster: a head and two worker nodes on this machine.

The head has no CPUs, so every task runs on a worker node, and each worker node has two:
four tasks in flight cannot all fit on one node.  The cluster is torn down by
``Cluster.shutdown()`` (never ``ray stop``, which kills every Ray process on the machine).
"""
from __future__ import annotations

import os
import signal
import sys
import threading
import time

import numpy as np
import pytest

from pytest_driveeval.execute import ChunkError, ExecutorSpec, disconnect, run_chunks, split

ray = pytest.importorskip("ray")
from ray_items import WORKER_CPUS, local_cluster, worker_nodes  # noqa: E402  (tests/ray_items.py)

pytestmark = pytest.mark.ray


@pytest.fixture(scope="module")
def cluster():
    # The workers cannot import this test module by name (it is not on their path):
    # its task functions travel by value instead.
    ray.cloudpickle.register_pickle_by_value(sys.modules[__name__])
    try:
        with local_cluster() as running:
            yield running
    finally:
        ray.cloudpickle.unregister_pickle_by_value(sys.modules[__name__])


def seeded_scenes(chunk):
    """Deterministic numpy work that also takes a chunk-dependent time."""
    seed, scenes, pause = chunk
    time.sleep(pause)
    return np.stack([np.random.default_rng((seed, s)).normal(size=(32, 4)).cumsum(axis=0) for s in scenes])


def finishing_after(chunk):
    """seeded_scenes, then a mark ``done-<index>`` in ``marks``; with ``after`` set, the chunk first waits
    for that chunk's mark, so the two finish in that order however loaded the machine is.  Returns the
    values and whether the awaited chunk had finished (a bounded wait: a scheduler that never runs the
    two together fails the assertion instead of hanging)."""
    marks, index, after, inner = chunk
    values = seeded_scenes(inner)
    awaited = after is None
    deadline = time.monotonic() + 120.0
    while not awaited and time.monotonic() < deadline:
        awaited = (marks / f"done-{after}").exists()
        time.sleep(0.02)
    (marks / f"done-{index}").touch()
    return values, awaited


def counting_in_flight(chunk):
    """Marks itself running in ``marks`` for a second and returns the most chunks it saw running
    meanwhile (itself included), counted from the marks, not from clocks.  Chunk 0 stays (bounded)
    until a second chunk runs beside it, so the bound is reached however loaded the machine is."""
    marks, index = chunk
    mine = marks / f"{index}.running"
    mine.touch()
    seen = 0
    stay = time.monotonic() + 1.0
    give_up = time.monotonic() + 120.0
    while time.monotonic() < stay or (index == 0 and seen < 2 and time.monotonic() < give_up):
        seen = max(seen, len(list(marks.glob("*.running"))))
        time.sleep(0.02)
    mine.unlink()
    return seen


def fails_on_three(chunk):
    time.sleep(0.05 * chunk)
    if chunk == 3:
        raise ValueError("scene 3 has no ego track")
    return chunk


def scaled(chunk, shared):
    return shared * chunk


def work(pauses):
    return [(11, scenes, pause) for scenes, pause in zip(split(len(pauses) * 3, 3), pauses)]


def unpaused(chunks):
    """The same chunks without their pauses: the values depend on the seed and scenes alone, so the
    local run that gives the expected values need not wait."""
    return [(seed, scenes, 0.0) for seed, scenes, _ in chunks]


def test_results_match_a_local_run_in_chunk_order_across_both_nodes(cluster, tmp_path):
    chunks = work([0.9, 0.2, 0.5, 0.3, 0.4, 0.2, 0.3, 0.2])
    progress = []
    spec = ExecutorSpec(Kind="ray", MaxInFlight=4)
    # The first chunk waits for the second's mark: it finishes last of the two, and its result must
    # still come first.
    ordered = [(tmp_path, i, 1 if i == 0 else None, c) for i, c in enumerate(chunks)]
    run = run_chunks(spec, ordered, finishing_after, progress=lambda done, total: progress.append(done))
    local = run_chunks(ExecutorSpec(), unpaused(chunks), seeded_scenes)

    assert all(np.array_equal(a[0], b) for a, b in zip(run.results, local.results))
    assert run.results[0][1], "the first chunk should have finished after the second"
    assert progress == list(range(len(chunks) + 1))
    # four tasks at once need both two-CPU nodes; placements name them
    assert run.nodes == worker_nodes() and len(run.nodes) == 2
    assert all(p.attempts == 1 and p.seconds >= 0.2 and p.wall_seconds >= p.seconds for p in run.placements)
    assert "2 node(s)" in run.summary()
    disconnect()
    assert ray.is_initialized(), "a connection this package did not open is not its to close"


def test_no_more_tasks_in_flight_than_allowed(cluster, tmp_path):
    run = run_chunks(ExecutorSpec(Kind="ray", MaxInFlight=2), [(tmp_path, i) for i in range(4)], counting_in_flight)
    # the cluster has four CPUs free, enough for all four chunks at once: only the bound keeps it at two
    assert max(run.results) == 2


def test_shared_data_travels_through_the_object_store(cluster):
    run = run_chunks(ExecutorSpec(Kind="ray"), [1, 2, 3], scaled, shared=np.arange(4.0))
    assert [r.tolist() for r in run.results] == [[0, 1, 2, 3], [0, 2, 4, 6], [0, 3, 6, 9]]


def test_a_failing_chunk_is_named_and_the_others_are_kept(cluster):
    with pytest.raises(ChunkError) as caught:
        run_chunks(ExecutorSpec(Kind="ray", MaxInFlight=3), list(range(8)), fails_on_three)
    error = caught.value
    assert error.chunk == 3 and list(error.failures) == [3]
    assert isinstance(error.cause, ValueError)
    assert "chunk 3 of 8 (3) failed on a Ray worker" in str(error) and "scene 3 has no ego track" in str(error)
    # nothing new starts after the failure; what was running finishes and is kept
    assert {0, 1, 2} <= set(error.results) and 3 not in error.results
    assert all(error.results[i] == i for i in error.results)


def seeded_scenes_marked(chunk):
    """seeded_scenes that first leaves a mark naming the node it runs on."""
    marks, index, inner = chunk
    if marks is not None:
        node = ray.get_runtime_context().get_node_id()
        (marks / f"{node}-{index}-{os.getpid()}").touch()
    return seeded_scenes(inner)


def doomed_alive(node):
    return any(n["NodeID"] == node.node_id and n["Alive"] for n in ray.nodes())


def test_a_worker_node_killed_mid_run_costs_a_retry_not_the_run(cluster, tmp_path):
    doomed = cluster.add_node(num_cpus=WORKER_CPUS)
    cluster.wait_for_nodes()
    inner = work([1.2] * 7)
    killed = threading.Event()

    def kill_once_a_chunk_runs_there():
        # Killed as soon as a chunk is under way on it, with most of its 1.2 s still to go: its
        # raylet and the worker running the chunk (a worker outlives its raylet for a while
        # and could still deliver; a machine that dies takes its workers with it).
        while not killed.is_set():
            running = [p.name for p in tmp_path.iterdir() if p.name.startswith(doomed.node_id)]
            if running:
                cluster.remove_node(doomed, allow_graceful=False)
                os.kill(int(running[0].rsplit("-", 1)[1]), signal.SIGKILL)
                killed.set()
            time.sleep(0.02)

    killer = threading.Thread(target=kill_once_a_chunk_runs_there, daemon=True)
    killer.start()
    try:
        run = run_chunks(ExecutorSpec(Kind="ray", MaxInFlight=6, Retries=2),
                         [(tmp_path, i, c) for i, c in enumerate(inner)], seeded_scenes_marked)
    finally:
        killed.set()
        killer.join()
    local = run_chunks(ExecutorSpec(), [(None, i, c) for i, c in enumerate(unpaused(inner))], seeded_scenes_marked)
    # Killed without grace, the node is marked dead only when the head's health checks miss it, which
    # can be seconds after the run: wait for that (bounded), rather than for a fixed time.
    deadline = time.monotonic() + 60.0
    while doomed_alive(doomed) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert not doomed_alive(doomed), "the head still lists the killed node as alive after 60 s"
    assert all(np.array_equal(a, b) for a, b in zip(run.results, local.results))
    assert run.retried, "a chunk was running on the killed node: it needed a second attempt"
    assert all(run.placements[i].node_id != doomed.node_id for i in run.retried)
    assert "retried" in run.summary()


def dies(chunk):
    if chunk == 1:
        os._exit(1)   # the worker process goes, as if killed by the kernel
    return chunk


def test_a_chunk_whose_worker_always_dies_fails_after_its_retries(cluster):
    with pytest.raises(ChunkError) as caught:
        run_chunks(ExecutorSpec(Kind="ray", Retries=1), [0, 1, 2], dies)
    error = caught.value
    assert list(error.failures) == [1] and error.results == {0: 0, 2: 2}
    assert "chunk 1 of 3 (1) failed: its worker died 2 times (Retries: 1)" in str(error)


def test_a_connection_it_opens_is_closed_and_the_cluster_stays_up(cluster):
    ray.shutdown()
    try:
        run = run_chunks(ExecutorSpec(Kind="ray", Address=cluster.address), [1, 2], scaled, shared=np.ones(2))
        assert [r.tolist() for r in run.results] == [[1, 1], [2, 2]]
        assert ray.is_initialized()
        disconnect()
        assert not ray.is_initialized()
    finally:
        ray.init(address=cluster.address)
    assert len(worker_nodes()) >= 2, "disconnecting must not take the cluster down"
