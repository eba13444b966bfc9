#!/usr/bin/env python3
"""CI's second run: the declared lowest versions of every dependency, on CI's Python.

Builds a venv in FOLDER with uv (pip's local indexes and constraints passed on, as
``.ci/fast_install.py`` does): ``torch==2.13.0`` first (the local CPU wheel; any other torch pulls
a multi-GB CUDA build), then the package with its test extras, each direct requirement at the
lowest version ``pyproject.toml`` allows (``--resolution lowest-direct``).  Runs the demo
(``.ci/demo.py``: it must end as the README says) and ``pytest tests -m smoke -n 2`` in it; pytest's
exit 5 (nothing ran) is a failure.  Phases, so that CI can build while its main run goes on:
``--phase build`` makes the venv, ``--phase run`` runs in it, ``all`` (the default) does both.
Prints the versions it ran and writes them, beside the newest run's (``--newest PYTHON``: the CI
venv's python), as a markdown table into ``--table FILE`` between the markers
``<!-- versions:start -->`` and ``<!-- versions:end -->`` (docs/supported-versions.md).

Usage: ``python .ci/lowest_versions.py .ci-venv-lowest [--phase build|run|all]
[--newest .ci-venv/bin/python] [--table docs/supported-versions.md]``
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from ci_steps import new_venv, replace_between, run, smoke_subset  # noqa: E402
from demo import run_demo  # noqa: E402

#: what the table lists: distribution name -> row label
PACKAGES = ["numpy", "torch", "pytest", "pydantic", "hypothesis", "pytest-xdist", "numba", "scipy", "rosbags", "ray",
            "pytest-html", "allure-pytest"]
START, END = "<!-- versions:start -->", "<!-- versions:end -->"
VERSIONS = """
import importlib.metadata as m, json, platform
names = {names!r}
found = {{}}
for name in names:
    try:
        found[name] = m.version(name)
    except m.PackageNotFoundError:
        found[name] = "not installed"
found["Python"] = platform.python_version()
print(json.dumps(found))
"""


def build(folder: Path) -> int:
    venv = new_venv(sys.executable, folder)
    if venv is None:
        return 1
    uv, environment = venv
    # torch first, alone: resolved with the rest, a lowest resolution would look for torch 2.1
    if run([*uv, "torch==2.13.0"], env=environment):
        return 1
    return run([*uv, "--resolution", "lowest-direct", "torch==2.13.0", "-e", ".[test]"], env=environment)


def versions(python: Path) -> dict[str, str]:
    done = subprocess.run([str(python), "-c", VERSIONS.format(names=PACKAGES)], capture_output=True, text=True,
                          check=True)
    return json.loads(done.stdout)


def table(lowest: dict[str, str], newest: dict[str, str] | None) -> str:
    head = "| package | lowest (declared floors) |" + (" newest |" if newest else "")
    rule = "|---|---|" + ("---|" if newest else "")
    rows = [f"| {name} | {lowest[name]} |" + (f" {newest.get(name, '?')} |" if newest else "")
            for name in ["Python", *PACKAGES]]
    return "\n".join([head, rule, *rows])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder", type=Path, help="where the lowest-versions venv is built")
    parser.add_argument("--phase", choices=("build", "run", "all"), default="all")
    parser.add_argument("--newest", type=Path, help="the newest-versions run's python (CI's venv)")
    parser.add_argument("--table", type=Path, help="a page whose versions table is rewritten")
    options = parser.parse_args()
    folder = options.folder.resolve()
    python = folder / "bin" / "python"
    started = time.monotonic()
    if options.phase in ("build", "all"):
        status = build(folder)
        print(f"lowest_versions: installed in {time.monotonic() - started:.0f} s", flush=True)
        if status:
            print("lowest_versions: the lowest versions could not be installed", file=sys.stderr)
            return 1
    if options.phase == "build":
        return 0
    if not python.exists():
        print(f"lowest_versions: no venv in {folder} (run --phase build)", file=sys.stderr)
        return 1
    # numba's cache in this venv's own folder: its files are named by function and Python version
    # alone, so numba 0.61 here and the newest numba of CI's main run, beside it, would each find the
    # other's index and compile everything again
    os.environ["NUMBA_CACHE_DIR"] = str(folder / "numba-cache")
    demo = run_demo(str(python), folder / "demo-results")
    smoke, _ = smoke_subset(python, "lowest_versions")
    lowest = versions(python)
    newest = versions(options.newest) if options.newest else None
    print("lowest versions run:", ", ".join(f"{k} {v}" for k, v in lowest.items()))
    print(table(lowest, newest))
    if options.table:
        replace_between(options.table, START, END, table(lowest, newest))
    print(f"lowest_versions: demo {'passed' if demo == 0 else 'FAILED'}, smoke exit {smoke}, "
          f"{time.monotonic() - started:.0f} s", flush=True)
    return 1 if demo or smoke else 0


if __name__ == "__main__":
    sys.exit(main())
