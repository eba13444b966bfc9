"""benchmarks/bench_metrics.py runs with the demo's install, where shapely is missing."""
from __future__ import annotations

import subprocess
import sys

from conftest import REPO_ROOT

WITHOUT_SHAPELY = """\
import runpy, sys
sys.modules["shapely"] = None
sys.argv = sys.argv[1:]
runpy.run_path(sys.argv[0], run_name="__main__")
"""


def test_runs_without_shapely_and_says_the_reference_is_skipped():
    done = subprocess.run([sys.executable, "-c", WITHOUT_SHAPELY, str(REPO_ROOT / "benchmarks" / "bench_metrics.py"),
                           "--scenes", "2", "--repeat", "3"], capture_output=True, text=True, timeout=300, check=False)
    assert done.returncode == 0, done.stderr
    assert "shapely per-agent reference  : skipped, shapely is not installed" in done.stdout
    assert "ours, one scene per call" in done.stdout and "speed-up" not in done.stdout
