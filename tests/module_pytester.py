"""A pytester for a whole test module: an inner session that several tests only read runs once.

pytest's ``pytester`` fixture is function-scoped, so each test that reads an expensive inner session
(an unroll, an inner ``-n 2``) ran its own. ``module_pytester`` gives a module-scoped fixture the same
object (``runpytest``, ``makefile``, the ``RunResult``s): inside the ``with`` block it works in its
folder as pytester does; on leaving, the working folder, the environment and ``sys.modules`` are put
back, and the folder with the sessions' outputs stays for the tests to read
(``from module_pytester import module_pytester``)."""
from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

import pytest


class _ModuleRequest:
    """What Pytester takes from its request, for a module's fixture: Pytester reads ``function`` (a
    module-scoped request raises there) to name its folder and needs ``addfinalizer`` to undo itself."""

    function = None

    def __init__(self, request: pytest.FixtureRequest) -> None:
        self.node, self.config = request.node, request.config
        self.finalizers: list = []

    def addfinalizer(self, finalizer) -> None:
        self.finalizers.append(finalizer)


@contextmanager
def module_pytester(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> Iterator[pytest.Pytester]:
    # matplotlib's font cache stays the outer session's (MPLCONFIGDIR, fixed by tests/conftest.py) though
    # pytester moves HOME
    with pytest.MonkeyPatch.context() as monkeypatch:
        proxy = _ModuleRequest(request)
        pytester = pytest.Pytester(proxy, tmp_path_factory, monkeypatch, _ispytest=True)
        try:
            yield pytester
        finally:
            for finalizer in reversed(proxy.finalizers):
                finalizer()
