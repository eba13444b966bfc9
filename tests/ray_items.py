"""What the use cases' Ray tests share: a real local cluster (a head and two worker nodes on
this machine), and the comparison of a run on it with a local run.  A test module imports
the ``cluster`` fixture and the helpers by name (``cluster = ray_items.cluster``; tests/ is
on the path, as for ``from conftest import REPO_ROOT``).  Under ``-n``, tests/xdist_modules.py
keeps a module that imports this one on one worker, so one cluster starts per module.

The head has no CPUs, so every chunk runs on a worker node; four chunks in flight need both
two-CPU nodes.  The cluster is torn down by ``Cluster.shutdown()``, never ``ray stop`` (which
kills every Ray process on the machine).
"""
from __future__ import annotations

import json
import re
from contextlib import contextmanager
from pathlib import Path

import pytest

WORKER_CPUS = 2
# Node deaths noticed within ~1.5 s instead of Ray's default ~30 s.
FAST_HEALTH_CHECKS = {"health_check_period_ms": 500, "health_check_failure_threshold": 3}


@contextmanager
def local_cluster():
    """A head without CPUs and two worker nodes, connected; shut down on exit.  The driver's
    ``print`` is given back on exit: Ray replaces ``builtins.print`` (tqdm_ray.safe_print) once a
    worker's log reaches the driver, and a later test that pickles ``print`` would see Ray's."""
    import builtins

    import ray
    from ray.cluster_utils import Cluster

    own_print = builtins.print

    cluster = Cluster(initialize_head=True, connect=True,
                      head_node_args={"num_cpus": 0, "_system_config": FAST_HEALTH_CHECKS})
    try:
        for _ in range(2):
            cluster.add_node(num_cpus=WORKER_CPUS)
        cluster.wait_for_nodes()
        yield cluster
    finally:
        ray.shutdown()       # the driver first: the head cannot be removed under it
        cluster.shutdown()
        builtins.print = own_print


@pytest.fixture(scope="module")
def cluster():
    pytest.importorskip("ray")
    with local_cluster() as running:
        yield running


def worker_nodes() -> set[str]:
    import ray

    return {n["NodeID"] for n in ray.nodes() if n["Alive"] and n["Resources"].get("CPU", 0) > 0}


def executor_section(**keys) -> str:
    return "  Executor: {" + ", ".join(f"{k}: {v}" for k, v in keys.items()) + "}\n"


def results(folder: Path) -> dict:
    data = json.loads((folder / "summary.json").read_text())
    return {r["nodeid"]: r for r in data["results"]}


def without_executor(record: dict) -> dict:
    """What a run on any executor must reproduce: everything but where its chunks ran, the
    run's output folder and the seconds a search took (no two runs share those)."""
    kept = {k: v for k, v in record.items() if k not in ("artefacts", "duration")}
    kept["details"] = {k: v for k, v in record["details"].items() if k != "executor"}
    text = json.dumps(kept, sort_keys=True)
    text = re.sub(r"/(local|remote)/runs/[^/]+/", "/OUTPUT/", text)
    text = re.sub(r"[0-9.]+ s\b", "0 s", re.sub(r"(seconds\W+)[0-9.]+", r"\g<1>0", text))
    return json.loads(text)


def artefact_bytes(folder: Path, record: dict) -> dict[str, bytes]:
    return {name: (folder / path).read_bytes() for name, path in record["artefacts"].items()}


def assert_same_items(local: Path, remote: Path, plain_local: bool = True) -> dict:
    """Every item of the run in ``remote`` has the record and the artefacts, byte for byte, of
    the same item in ``local``; returns the remote records.  ``plain_local``: the local run is
    the one-batch path (no chunks, so no executor in its report)."""
    here, there = results(local), results(remote)
    assert set(here) == set(there) and here
    for nodeid in here:
        assert without_executor(there[nodeid]) == without_executor(here[nodeid]), nodeid
        assert artefact_bytes(remote, there[nodeid]) == artefact_bytes(local, here[nodeid]), nodeid
        if plain_local:
            assert "executor" not in here[nodeid]["details"], "the local run is the plain one-batch path"
    return there
