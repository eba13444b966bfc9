"""Shared test configuration.

Real sample data lives outside the repository, in ``../shared/data`` next to the
clone (CI has it; a plain checkout may not).  Tests that need it take the
``shared_data`` fixture, which skips cleanly when the folder is absent.
"""
from __future__ import annotations

import os
from pathlib import Path

import pytest

pytest_plugins = ["pytester"]

REPO_ROOT = Path(__file__).resolve().parents[1]
SHARED_DATA = Path(os.environ.get("DRIVEEVAL_SHARED_DATA", REPO_ROOT.parent / "shared" / "data"))


@pytest.fixture(scope="session")
def shared_data() -> Path:
    if not SHARED_DATA.is_dir():
        pytest.skip(f"real sample data not found at {SHARED_DATA}")
    return SHARED_DATA
