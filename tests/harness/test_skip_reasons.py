"""The project's own run says why a test skips and what makes it run (pyproject's -rfEs)."""
from __future__ import annotations

import os
import subprocess
import sys

from conftest import REPO_ROOT


def test_a_skip_for_absent_real_data_says_so_in_the_summary(tmp_path):
    env = {**os.environ, "DRIVEEVAL_SHARED_DATA": str(tmp_path / "absent")}
    run = subprocess.run([sys.executable, "-m", "pytest", "tests/io/test_tf.py", "-k", "real_bag", "-q",
                          "-p", "no:cacheprovider", "-p", "no:randomly", "--driveeval-output", str(tmp_path / "out")],
                         cwd=REPO_ROOT, env=env,
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stdout + run.stderr
    skipped = [line for line in run.stdout.splitlines() if line.startswith("SKIPPED")]
    assert len(skipped) == 1 and "real sample data absent" in skipped[0], run.stdout
    assert str(tmp_path / "absent") in skipped[0] and "DRIVEEVAL_SHARED_DATA" in skipped[0]
