"""What the reuse tests share (tests/execute/test_reuse.py, tests/usecases/*/test_*_reuse.py):
nothing kept from one test to the next, and files old enough for execute.reuse to keep what
was read from them.  A test module imports them by name (``from reuse_items import nothing_kept``;
tests/ is on the path, as for ray_items)."""
from __future__ import annotations

import os
import shutil
import time
from pathlib import Path

import pytest

from pytest_driveeval.execute import reuse


@pytest.fixture(autouse=True)
def nothing_kept(monkeypatch):
    monkeypatch.delenv(reuse.SWITCH, raising=False)
    reuse.forget()
    yield
    reuse.forget()


def settle(path: Path, age: float = 60.0) -> Path:
    """``path`` with its mtime ``age`` seconds ago (older than reuse.RACY_SECONDS)."""
    then = time.time() - age
    os.utime(path, (then, then))
    return path


def settled_copy(source: Path, target: Path) -> Path:
    """``source`` copied to ``target``, its mtime a minute ago."""
    target.parent.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(source, target)
    return settle(target)
