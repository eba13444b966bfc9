"""Under ``-n``, the tests of a module with module-scoped fixtures run on one worker.

xdist's default distribution ('load') hands tests out one at a time, so the tests of one module
alternate between the two workers and each worker builds the module's fixtures again: the nuPlan
oracle's real scenes (two protocols, ~50 s each) were built four times, a robustness search or a
Ray cluster twice.  Here the controller's scheduler keeps such a module's tests together as one unit
of work and hands out every other test on its own, as 'load' does.

xdist's own 'loadgroup' mode would do this from ``xdist_group`` marks, but it names a test's group by
rewriting ``item._nodeid``, which pytest 9.2 no longer reads (node ids live in ``item._id``): the
marks are then silently ignored.  The controller does not collect tests, so which modules to keep
together is read from their source: a module that declares a module-, class- or package-scoped
fixture or uses tests/module_pytester.py, or imports a helper module of the suite that declares one
(``cluster = ray_items.cluster``: tests/ray_items.py's Ray cluster).

Chosen only for a bare ``-n`` (an explicit ``--dist`` of the user's is left alone).  The hook is the
root conftest's (tests/conftest.py imports it).
"""
from __future__ import annotations

import os
import re
from pathlib import Path

import pytest

TESTS = Path(__file__).resolve().parent
SHARED_FIXTURE = re.compile(r"""scope\s*=\s*["'](module|class|package)["']|\bmodule_pytester\b""")


#: ``import name`` / ``from name import ...`` at the start of a line: the suite's helpers are imported by name
IMPORTED = re.compile(r"^\s*(?:from|import)\s+(\w+)", re.MULTILINE)


def modules_with_shared_fixtures(tests: Path, rootdir: Path) -> frozenset[str]:
    """The test modules under ``tests`` that share fixtures across tests, as node ids give their paths
    (relative to ``rootdir``): their own, or a helper module's they import (not conftest.py's, which
    every module may import names from)."""
    sources = {path: path.read_text(encoding="utf-8", errors="replace") for path in tests.rglob("*.py")}
    helpers = {path.stem for path, text in sources.items()
               if not path.name.startswith("test_") and path.name != "conftest.py" and SHARED_FIXTURE.search(text)}
    found = set()
    for path, text in sources.items():
        if path.name.startswith("test_") and (SHARED_FIXTURE.search(text)
                                              or helpers.intersection(IMPORTED.findall(text))):
            found.add(path.relative_to(rootdir).as_posix())
    return frozenset(found)


def unit_of(nodeid: str, shared: frozenset[str]) -> str:
    """The unit of work a test belongs to: its module's path when the module shares fixtures, else itself."""
    module = nodeid.split("::", 1)[0]
    return module if module in shared else nodeid


def _dist_given(config: pytest.Config) -> bool:
    given = " ".join([*config.invocation_params.args, os.environ.get("PYTEST_ADDOPTS", ""),
                      *config.getini("addopts")])
    return "--dist" in given or "-d " in f"{given} "


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_make_scheduler(config: pytest.Config, log):
    if config.getoption("dist") != "load" or _dist_given(config):
        return None
    from xdist.scheduler import LoadScopeScheduling

    if not TESTS.is_relative_to(config.rootpath):
        return None
    shared = modules_with_shared_fixtures(TESTS, config.rootpath)

    class ModuleFixtureScheduling(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            return unit_of(nodeid, shared)

    return ModuleFixtureScheduling(config, log)
