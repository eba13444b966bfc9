"""The point-cloud filter under test in this folder: the demo ground/height filter of
examples/ground_filter.py, given as a callable so the use case streams the raw lidar sweeps
through it (and a Perturbation section can search what breaks it)."""
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[3] / "examples"))
from ground_filter import ground_height_filter  # noqa: E402


@pytest.fixture
def driveeval_pointclouds():
    return ground_height_filter
