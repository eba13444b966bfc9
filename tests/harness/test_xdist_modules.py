"""The suite's own xdist scheduler (tests/xdist_modules.py): a module with module-scoped fixtures is one
unit of work, every other test its own, and it is used for a bare ``-n`` only."""
from __future__ import annotations

import os
import subprocess
import sys

import pytest

from conftest import REPO_ROOT
from xdist_modules import TESTS, modules_with_shared_fixtures, unit_of

pytest.importorskip("xdist")


def test_modules_that_share_fixtures_are_found_from_their_source(tmp_path):
    tests = tmp_path / "tests"
    (tests / "sub").mkdir(parents=True)
    (tests / "sub" / "test_shared.py").write_text('@pytest.fixture(scope="module")\ndef run(): ...\n')
    (tests / "test_pytester.py").write_text("from module_pytester import module_pytester\n")
    (tests / "test_class.py").write_text("@pytest.fixture(scope='class')\ndef c(): ...\n")
    (tests / "test_alone.py").write_text('@pytest.fixture(scope="session")\ndef s(): ...\n@pytest.fixture\ndef f(): ...\n')
    assert modules_with_shared_fixtures(tests, tmp_path) == {"tests/sub/test_shared.py", "tests/test_pytester.py",
                                                             "tests/test_class.py"}


def test_a_module_that_imports_a_helpers_shared_fixture_is_found_and_one_of_conftest_is_not(tmp_path):
    tests = tmp_path / "tests"
    (tests / "sub").mkdir(parents=True)
    (tests / "cluster_items.py").write_text('@pytest.fixture(scope="module")\ndef cluster(): ...\n')
    (tests / "sub" / "test_on_cluster.py").write_text("import cluster_items\n\ncluster = cluster_items.cluster\n")
    (tests / "test_from_helper.py").write_text("from cluster_items import cluster\n")
    (tests / "conftest.py").write_text('@pytest.fixture(scope="module")\ndef everywhere(): ...\n')
    (tests / "test_plain.py").write_text("from conftest import REPO_ROOT\nimport os\n")
    assert modules_with_shared_fixtures(tests, tmp_path) == {"tests/sub/test_on_cluster.py",
                                                             "tests/test_from_helper.py"}


def test_the_suites_heavy_modules_are_among_them():
    shared = modules_with_shared_fixtures(TESTS, REPO_ROOT)
    assert {"tests/metrics/test_nuplan_oracle.py", "tests/execute/test_ray_cluster.py",
            "tests/usecases/closed_loop/test_closed_loop_robustness.py",
            "tests/usecases/closed_loop/test_closed_loop_ray.py",
            "tests/usecases/policy_benchmark/test_policy_benchmark_ray.py"} <= shared
    assert "tests/harness/test_assertions.py" not in shared


def test_a_shared_modules_tests_are_one_unit_and_any_other_test_its_own():
    shared = frozenset({"tests/a/test_x.py"})
    assert unit_of("tests/a/test_x.py::test_one[1]", shared) == unit_of("tests/a/test_x.py::K::test_two", shared)
    assert unit_of("tests/a/test_x.py::test_one[1]", shared) == "tests/a/test_x.py"
    assert unit_of("tests/a/test_y.py::test_one[1]", shared) == "tests/a/test_y.py::test_one[1]"


GROUPED = '''
import os
import pytest

@pytest.fixture(scope="module")
def built():
    return os.environ["PYTEST_XDIST_WORKER"]

@pytest.mark.parametrize("n", range(6))
def test_shares(built, n):
    assert built == os.environ["PYTEST_XDIST_WORKER"]
    print("RAN", "shared", n, os.environ["PYTEST_XDIST_WORKER"])
'''


def _workers(tmp_path, *options):
    """{test id: worker} of a -n 2 run of a copy of the scheduler's module on a small test folder."""
    tests = tmp_path / "tests"
    tests.mkdir()
    (tests / "xdist_modules.py").write_text((TESTS / "xdist_modules.py").read_text())
    (tests / "conftest.py").write_text("from xdist_modules import pytest_xdist_make_scheduler  # noqa: F401\n")
    (tests / "test_grouped.py").write_text(GROUPED)
    (tests / "test_loose.py").write_text("import pytest\n\n@pytest.mark.parametrize('n', range(6))\n"
                                         "def test_loose(n):\n    pass\n")
    (tmp_path / "pytest.ini").write_text("[pytest]\n")
    done = subprocess.run([sys.executable, "-m", "pytest", "tests", "-n", "2", "-v", "-p", "no:cacheprovider",
                           "-p", "no:randomly", *options], cwd=tmp_path, capture_output=True, text=True, timeout=300,
                          env={k: v for k, v in os.environ.items() if k != "PYTEST_ADDOPTS"})
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    workers = {}
    for line in done.stdout.splitlines():
        if line.startswith("[gw") and " PASSED " in line:
            workers[line.split(" PASSED ", 1)[1].strip()] = line[1:4]
    return workers, done.stdout


def test_a_bare_n_keeps_a_modules_tests_on_one_worker(tmp_path):
    workers, out = _workers(tmp_path)
    assert "scheduling tests via ModuleFixtureScheduling" in out
    assert len([t for t in workers if "test_grouped" in t]) == 6 and len(workers) == 12
    # each test also asserts that the module's fixture was built on its own worker
    assert len({w for test, w in workers.items() if "test_grouped" in test}) == 1


def test_a_dist_of_the_users_is_used_as_given(tmp_path):
    _, out = _workers(tmp_path, "--dist", "load")
    assert "scheduling tests via LoadScheduling" in out
