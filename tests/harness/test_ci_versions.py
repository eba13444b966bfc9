"""CI's version runs (.ci/lowest_versions.py, .ci/python_versions.py, .ci/demo.py) and the page they
write: the floors the page lists are pyproject.toml's, the Pythons are requires-python's ends, and the
demo's promised outcome is read from the README as CI checks it."""
from __future__ import annotations

import re
import sys

import pytest

tomllib = pytest.importorskip("tomllib")   # Python 3.11+: the CI scripts run on CI's 3.11
from packaging.requirements import Requirement  # noqa: E402
from packaging.version import Version  # noqa: E402

from conftest import REPO_ROOT, module_at  # noqa: E402

PAGE = REPO_ROOT / "docs" / "supported-versions.md"
sys.path.append(str(REPO_ROOT / ".ci"))   # the scripts import each other by name, as CI runs them
ci_steps = module_at(REPO_ROOT / ".ci" / "ci_steps.py", "ci_steps_module")
demo = module_at(REPO_ROOT / ".ci" / "demo.py", "ci_demo")
python_versions = module_at(REPO_ROOT / ".ci" / "python_versions.py", "ci_python_versions")
lowest_versions = module_at(REPO_ROOT / ".ci" / "lowest_versions.py", "ci_lowest_versions")


def floors() -> dict[str, Version]:
    """Each listed package's lowest declared version, over the dependencies and every extra."""
    project = tomllib.loads((REPO_ROOT / "pyproject.toml").read_text())["project"]
    found: dict[str, Version] = {}
    for text in [*project["dependencies"], *(r for extra in project["optional-dependencies"].values() for r in extra)]:
        requirement = Requirement(text)
        for spec in requirement.specifier:
            if spec.operator == ">=":
                found[requirement.name] = max(found.get(requirement.name, Version(spec.version)), Version(spec.version))
    return found


def table_rows(start: str, end: str) -> list[list[str]]:
    text = ci_steps.between(PAGE.read_text(), start, end)
    return [[cell.strip() for cell in line.strip("|").split("|")] for line in text.strip().splitlines()[2:]]


def test_the_pages_lowest_column_is_what_pyproject_declares():
    declared = floors()
    rows = {row[0]: row[1] for row in table_rows(lowest_versions.START, lowest_versions.END)}
    assert set(lowest_versions.PACKAGES) <= set(rows)
    checked = 0
    for name in lowest_versions.PACKAGES:
        if name == "torch":   # installed at 2.13.0 first: the floor torch>=2.1 pulls a CUDA build here
            assert rows[name].startswith("2.13.0")
            continue
        assert Version(rows[name]) == declared[name], name
        checked += 1
    assert checked == len(lowest_versions.PACKAGES) - 1


def test_the_pythons_are_the_ends_of_requires_python():
    oldest, newest = python_versions.claimed()
    spec = tomllib.loads((REPO_ROOT / "pyproject.toml").read_text())["project"]["requires-python"]
    assert f">={oldest}" in spec and Version(newest) < Version(re.search(r"<\s*([\d.]+)", spec).group(1))
    listed = [row[0] for row in table_rows(python_versions.START, python_versions.END)]
    assert [".".join(v.split(".")[:2]) for v in listed] == [oldest, newest]


def test_the_demos_promise_is_the_readmes_and_its_last_line_is_read_as_pytest_writes_it():
    promised = demo.promised()
    assert promised["passed"] > 0 and set(promised) <= {"passed", "xfailed"}
    assert f"It ends `{promised['passed']} passed" in (REPO_ROOT / "README.md").read_text()
    assert demo.counts("=== 33 passed, 13 xfailed in 139.83s (0:02:19) ===") == {"passed": 33, "xfailed": 13}
    assert demo.counts("1 failed, 32 passed, 12 xfailed, 1 xpassed in 9s") == {
        "failed": 1, "passed": 32, "xfailed": 12, "xpassed": 1}
    assert demo.counts("no tests ran in 0.01s") == {}


@pytest.mark.parametrize("spec, fine", [(">=3.10,<3.14", True), (">=3.10", False), (">=3.10,<3.13", False)])
def test_a_requires_python_without_a_tested_upper_end_is_refused(monkeypatch, tmp_path, spec, fine):
    (tmp_path / "pyproject.toml").write_text(f'[project]\nrequires-python = "{spec}"\n')
    monkeypatch.setattr(python_versions, "ROOT", tmp_path)
    if fine:
        assert python_versions.claimed() == ("3.10", "3.13")
    else:
        with pytest.raises(SystemExit, match="requires-python"):
            python_versions.claimed()
