"""The manual (docs/, mkdocs.yml) builds with mkdocs build --strict, as CI builds it, and that
build really fails on what a reader would trip over: a broken anchor, a link to no page, a page
left out of the navigation."""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from conftest import REPO_ROOT

pytest.importorskip("mkdocs", reason="mkdocs is not installed: pip install -e '.[docs]' (the test extra has it)")
pytest.importorskip("material", reason="mkdocs-material is not installed: pip install -e '.[docs]' (the test extra has it)")


def _build(root: Path, site: Path) -> subprocess.CompletedProcess:
    # From the root: the getting-started page includes the README's sections by a path from there.
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1"}
    return subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--config-file",
                           str(root / "mkdocs.yml"), "--site-dir", str(site)],
                          cwd=root, env=env, capture_output=True, text=True, timeout=300)


def _copy(tmp_path: Path) -> Path:
    """The manual's sources in a folder of their own, to break."""
    root = tmp_path / "repo"
    shutil.copytree(REPO_ROOT / "docs", root / "docs")
    for name in ("mkdocs.yml", "README.md"):
        shutil.copy(REPO_ROOT / name, root / name)
    return root


def test_the_manual_builds_strictly(tmp_path):
    done = _build(REPO_ROOT, tmp_path / "site")
    assert done.returncode == 0, done.stdout + done.stderr
    # The README's tour reached the site through the snippet include, not as the include's text.
    getting_started = (tmp_path / "site" / "getting-started" / "index.html").read_text()
    assert "A five-minute tour" in getting_started and "--8&lt;--" not in getting_started
    assert (tmp_path / "site" / "reference" / "scenario-keys" / "index.html").exists()


def test_the_strict_build_is_what_ci_runs():
    ci = (REPO_ROOT / ".ci" / "run").read_text()
    assert "mkdocs build --strict" in ci
    assert "strict: true" in (REPO_ROOT / "mkdocs.yml").read_text()


@pytest.mark.parametrize("broken, says", [
    ("[a heading that is not there](closed-loop.md#no-such-heading)",
     "does not contain an anchor '#no-such-heading'"),
    ("[a page that is not there](no-such-page.md)", "no-such-page.md"),
], ids=["anchor", "page"])
def test_a_broken_link_fails_the_strict_build(tmp_path, broken, says):
    root = _copy(tmp_path)
    page = root / "docs" / "options.md"
    page.write_text(page.read_text() + f"\nSee {broken}.\n")
    done = _build(root, tmp_path / "site")
    assert done.returncode != 0
    assert says in done.stdout + done.stderr


def test_a_page_left_out_of_the_navigation_fails_the_strict_build(tmp_path):
    root = _copy(tmp_path)
    (root / "docs" / "orphan.md").write_text("# A page nobody can reach\n")
    done = _build(root, tmp_path / "site")
    assert done.returncode != 0
    assert "orphan.md" in done.stdout + done.stderr
