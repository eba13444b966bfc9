"""benchmarks/bench_gnn.py keeps running, and its edge-list reference keeps computing our actions."""
from __future__ import annotations

import subprocess
import sys

import pytest
from conftest import REPO_ROOT

pytest.importorskip("torch")


def test_the_benchmark_runs_and_its_reference_agrees_with_the_actor():
    done = subprocess.run([sys.executable, str(REPO_ROOT / "benchmarks" / "bench_gnn.py"), "--batch", "16",
                           "--rounds", "1", "--calls", "2", "--episodes", "4"],
                          capture_output=True, text=True, timeout=300, check=False, cwd=REPO_ROOT)
    # The script checks the reference's actions against the actor's before it times anything.
    assert done.returncode == 0, done.stderr
    assert "threads: torch 1" in done.stdout
    assert "x the reference;" in done.stdout and "observations/s" in done.stdout
    assert "graph_observation + encode, 4 episodes x 12 agents" in done.stdout
