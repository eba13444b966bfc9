"""Under ``-n``, the tests that share a module-scoped fixture run on one worker.

xdist's default distribution ('load') hands tests out one at a time, so the tests of one module
alternate between the two workers and each worker builds the module's fixtures again: the nuPlan
oracle's real scenes (two protocols, ~50 s each) were built four times, a robustness search or a
Ray cluster twice.  Its 'loadgroup' mode keeps the tests that carry one ``xdist_group`` mark on one
worker and hands out every other test as before; this marks each test that uses a module-, class- or
package-scoped fixture with its module's name, and chooses 'loadgroup' when ``-n`` is given with no
``--dist`` of the user's (an explicit one is left alone).

The hooks are the root conftest's (tests/conftest.py imports them).
"""
from __future__ import annotations

import os

import pytest

SHARED_SCOPES = frozenset({"module", "class", "package"})
WORKER_KEY = "driveeval_tests_loadgroup"


def pytest_cmdline_main(config: pytest.Config) -> None:
    # After xdist's own (tryfirst) hook, which turned a bare -n into --dist load.
    if getattr(config.option, "dist", "no") != "load":
        return
    given = " ".join([*config.invocation_params.args, os.environ.get("PYTEST_ADDOPTS", ""),
                      *config.getini("addopts")])
    if "--dist" not in given and "-d " not in f"{given} ":
        config.option.dist = "loadgroup"


@pytest.hookimpl(optionalhook=True)
def pytest_configure_node(node) -> None:
    # A worker parses the command line again and would see plain 'load': it is told here.
    if node.config.option.dist == "loadgroup":
        node.workerinput[WORKER_KEY] = True


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    # tryfirst: on a worker, xdist's own modifyitems hook reads the marks (and config.option.loadgroup)
    # to name each test's group in its node id, which is how the controller keeps a group together.
    if getattr(config, "workerinput", {}).get(WORKER_KEY):
        config.option.loadgroup = True
    if not getattr(config.option, "loadgroup", False):
        return
    for item in items:
        if uses_shared_fixture(item):
            item.add_marker(pytest.mark.xdist_group(group_of(item)))


def uses_shared_fixture(item: pytest.Item) -> bool:
    info = getattr(item, "_fixtureinfo", None)
    if info is None:
        return False
    return any(getattr(definition, "scope", None) in SHARED_SCOPES
               for definitions in info.name2fixturedefs.values() for definition in definitions)


def group_of(item: pytest.Item) -> str:
    """The module's path below tests/, without .py: xdist appends it to the node id (``@metrics/test_x``)."""
    module = item.nodeid.split("::", 1)[0]
    return module.removeprefix("tests/").removesuffix(".py")
