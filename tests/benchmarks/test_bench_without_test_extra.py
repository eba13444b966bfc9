"""The benchmarks that have a reference needing the ``test`` extra (shapely) run with the demo's install
too: they skip that reference, say so, and print the rest."""
from __future__ import annotations

import os
import subprocess
import sys

from conftest import REPO_ROOT

# Modules only the test extra installs, made unimportable for the run.
WITHOUT_TEST_EXTRA = """\
import runpy, sys
for name in ("shapely", "zarr", "hypothesis", "playwright"):
    sys.modules[name] = None
sys.argv = sys.argv[1:]
runpy.run_path(sys.argv[0], run_name="__main__")
"""


def run_without_test_extra(script: str, *args: str, env: dict | None = None) -> str:
    env = dict(os.environ if env is None else env)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(REPO_ROOT), env.get("PYTHONPATH")]))
    done = subprocess.run([sys.executable, "-c", WITHOUT_TEST_EXTRA, str(REPO_ROOT / "benchmarks" / script), *args],
                          capture_output=True, text=True, timeout=600, check=False, env=env, cwd=REPO_ROOT)
    assert done.returncode == 0, done.stderr
    return done.stdout


def test_bench_unroll_runs_without_shapely_and_says_what_it_skipped():
    out = run_without_test_extra("bench_unroll.py", "--smoke",
                                 env={k: v for k, v in os.environ.items() if k != "OMP_NUM_THREADS"})
    assert "threads: torch 1, OMP_NUM_THREADS=1" in out  # set by the script when the caller did not
    assert "reference skipped: it is l5kit's detect_collision, which needs shapely" in out
    assert "engine,  2 scene(s) batched: 494 steps" in out
    assert "% of the total (median of 3" in out


def test_bench_metrics_runs_without_shapely_and_says_the_reference_is_skipped():
    out = run_without_test_extra("bench_metrics.py", "--smoke")
    assert "shapely per-agent reference  : skipped, shapely is not installed" in out
    assert "ours, one scene per call" in out and "speed-up" not in out
