"""The score's compiled kernels come from numba's cache in a new process, not compiled again: a kernel
defined inside a function and calling other compiled functions through its closure is never found in
the cache (its key holds the closure, which pickles differently in every process), and then every
process that scores (each xdist worker, each fresh session) paid about 4 s."""
from __future__ import annotations

import json
import subprocess
import sys

import pytest

from conftest import REPO_ROOT

pytest.importorskip("numba")

SCORE_THE_CASES = f"""
import json, sys
import numba  # loaded first, so the score takes its compiled paths
sys.path.insert(0, {str(REPO_ROOT / "benchmarks" / "nuplan_oracle")!r})
from cases import all_cases
from pytest_driveeval.metrics.nuplan_score import score_scene
from pytest_driveeval.metrics.nuplan_score.case import inputs_from_case
from pytest_driveeval.metrics.nuplan_score import kernels, route_kernel
for case in all_cases():
    score_scene(inputs_from_case(case))
dispatchers = {{name: value for name, value in vars(kernels.kernels()).items()
               if isinstance(value, numba.core.dispatcher.Dispatcher)}}
dispatchers["follow_route"] = route_kernel.follow()
print(json.dumps({{name: [sum(d.stats.cache_hits.values()), sum(d.stats.cache_misses.values())]
                  for name, d in dispatchers.items()}}))
"""


def scored_in_a_new_process() -> dict:
    done = subprocess.run([sys.executable, "-c", SCORE_THE_CASES], capture_output=True, text=True, timeout=600,
                          cwd=REPO_ROOT)
    assert done.returncode == 0, done.stderr[-2000:]
    return json.loads(done.stdout.strip().splitlines()[-1])


def test_a_second_process_loads_every_kernel_it_runs_from_the_cache():
    scored_in_a_new_process()  # compiles what the cache does not hold yet
    stats = scored_in_a_new_process()
    used = {name: (hits, misses) for name, (hits, misses) in stats.items() if hits or misses}
    assert len(used) >= 5, stats  # the synthetic cases reach most of the kernels
    assert {name for name, (_, misses) in used.items() if misses} == set(), used
