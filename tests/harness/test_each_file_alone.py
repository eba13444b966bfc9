"""CI's check that each test file passes on its own (.ci/each_file_alone.py): which files, which
sample, and that a file passing only beside others is caught."""
from __future__ import annotations

import importlib.util

import pytest

from conftest import REPO_ROOT

SCRIPT = REPO_ROOT / ".ci" / "each_file_alone.py"


@pytest.fixture(scope="module")
def alone():
    spec = importlib.util.spec_from_file_location("each_file_alone", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def write(root, name: str, text: str):
    path = root / name
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def test_files_marked_slow_or_ray_as_a_whole_are_left_out(alone, tmp_path):
    write(tmp_path, "tests/test_plain.py", "def test_x():\n    pass\n")
    write(tmp_path, "tests/sub/test_ray.py", "import pytest\npytestmark = pytest.mark.ray\n")
    write(tmp_path, "tests/test_slow.py", "import pytest\npytestmark = [pytest.mark.slow]\n")
    write(tmp_path, "tests/test_one_slow.py", "import pytest\n\n@pytest.mark.slow\ndef test_x():\n    pass\n")
    write(tmp_path, "tests/helpers.py", "")
    assert [p.relative_to(tmp_path).as_posix() for p in alone.test_files(tmp_path)] == [
        "tests/test_one_slow.py", "tests/test_plain.py"]


def test_the_sample_is_the_same_for_one_seed_and_rotates_with_it(alone):
    files = [f"test_{i}.py" for i in range(40)]
    first = alone.sample(files, 5, seed=1234)
    assert first == alone.sample(files, 5, seed=1234)
    assert len(first) == 5 and first == sorted(first, key=files.index)
    assert len({tuple(alone.sample(files, 5, seed=s)) for s in range(10)}) > 1
    assert alone.sample(files[:3], 5, seed=1) == files[:3]


def test_a_file_that_imports_what_only_the_full_suite_put_on_the_path_fails_alone(alone, tmp_path):
    write(tmp_path, "tests/helpers.py", "VALUE = 1\n")
    needs = write(tmp_path, "tests/sub/test_needs_tests.py",
                  "from tests.helpers import VALUE\n\ndef test_x():\n    assert VALUE == 1\n")
    fine = write(tmp_path, "tests/sub/test_fine.py", "def test_x():\n    pass\n")
    deselected = write(tmp_path, "tests/sub/test_all_slow.py",
                       "import pytest\n\n@pytest.mark.slow\ndef test_x():\n    pass\n")
    write(tmp_path, "pytest.ini", "[pytest]\nmarkers =\n    slow: long\n    ray: cluster\n")
    ok, tail = alone.run_alone(needs, tmp_path)
    assert not ok and "ModuleNotFoundError: No module named 'tests" in tail
    assert alone.run_alone(fine, tmp_path)[0]
    assert alone.run_alone(deselected, tmp_path)[0]  # every test deselected (exit 5) is no failure


def test_the_ci_script_runs_it_and_fails_on_it():
    """CI runs five files alone in its checks chain, beside the suite; the chain's status is its last
    line's test, which takes the files' exit status, and a chain that fails fails CI."""
    run = (REPO_ROOT / ".ci" / "run").read_text()
    opening = "background checks bash -c '"
    chain = run[run.index(opening) + len(opening):]
    chain = chain[:chain.index("'\n")]
    assert "python .ci/each_file_alone.py --count 5\n    alone=$?" in chain
    assert '[ "$alone" -eq 0 ]' in chain.splitlines()[-1]
    assert 'CHAINS="$CHAINS checks"' in run
    assert 'echo "CI: $name failed (its log is above)" >&2\n    status=1' in run
