#!/usr/bin/env python3
"""CI's runs on the oldest and the newest Python that ``requires-python`` admits, without torch.

The CPU build of torch 2.13.0 that these machines hold is for Python 3.11 only; for other Pythons
the registries offer torch 2.13.0 only with CUDA (several GB).  So on each of these Pythons a venv
gets the package with every extra that needs no torch (``obstacle,plots,reports,benchmark``, xdist,
zarr, shapely) and runs the smoke subset (``pytest tests -m smoke -n 2``); the tests that need torch
skip, each saying so.  pytest's exit 5 (nothing ran) is a failure.  With ``--table FILE`` the run
phase writes what ran, per Python, between ``<!-- pythons:start -->`` and ``<!-- pythons:end -->``.

Phases, so that CI can build while its main run goes on: ``build`` makes the venvs, ``run`` runs the
smoke subset in them, ``all`` (the default) does both.  A Python that is not on this machine is
reported and not run: it is not a failure of the package.

Usage: ``python .ci/python_versions.py [build|run|all] [--folder .ci-venv/pythons] [--table FILE]``
"""
from __future__ import annotations

import argparse
import glob
import os
import re
import subprocess
import sys
import time
import tomllib
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from ci_steps import ROOT, new_venv, replace_between, run, smoke_subset  # noqa: E402

#: the newest Python this project tests; requires-python's upper bound is the next one
NEWEST = "3.13"
#: what the smoke subset needs beside the package, none of which pulls torch
EXTRAS = [".[obstacle,plots,reports,benchmark]", "pytest-xdist>=3.5", "zarr>=2.18,<3", "numcodecs>=0.12",
          "shapely>=2.0"]
START, END = "<!-- pythons:start -->", "<!-- pythons:end -->"


def claimed() -> tuple[str, str]:
    """The oldest Python ``requires-python`` admits, and NEWEST (checked to be admitted)."""
    spec = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["requires-python"]
    oldest = re.search(r">=\s*(3\.\d+)", spec)
    below = re.search(r"<\s*3\.(\d+)", spec)
    if oldest is None or below is None or int(NEWEST.split(".")[1]) >= int(below.group(1)):
        raise SystemExit(f"python_versions: requires-python {spec!r} should read '>=3.X,<3.Y' with {NEWEST} below 3.Y")
    return oldest.group(1), NEWEST


def interpreter(version: str) -> str | None:
    """An interpreter of ``version`` on this machine: on the PATH, or one pyenv installed."""
    roots = [os.environ.get("PYENV_ROOT", ""), str(Path.home() / ".pyenv")]
    candidates = [f"python{version}", *sorted(p for root in roots if root
                                             for p in glob.glob(f"{root}/versions/{version}.*/bin/python{version}"))]
    for candidate in candidates:
        try:
            done = subprocess.run([candidate, "-c", "import sys; print(sys.version_info[:2])"], capture_output=True,
                                  text=True, timeout=60)
        except (OSError, subprocess.TimeoutExpired):
            continue
        if done.returncode == 0 and done.stdout.strip() == str(tuple(int(x) for x in version.split("."))):
            return candidate
    return None


def venv_python(folder: Path, version: str) -> Path:
    return folder / version / "bin" / "python"


def build(folder: Path, version: str, base: str) -> int:
    venv = new_venv(base, folder / version)
    if venv is None:
        return 1
    uv, environment = venv
    return run([*uv, "-e", *EXTRAS], env=environment)


def full_version(folder: Path, version: str) -> str:
    done = subprocess.run([str(venv_python(folder, version)), "-c",
                           "import platform; print(platform.python_version())"], capture_output=True, text=True)
    return done.stdout.strip() or version


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("phase", nargs="?", choices=("build", "run", "all"), default="all")
    parser.add_argument("--folder", type=Path, default=ROOT / ".ci-venv" / "pythons", help="where the venvs are built")
    parser.add_argument("--table", type=Path, help="a page whose Python table the run phase rewrites")
    options = parser.parse_args()
    folder = options.folder.resolve()
    failed, rows = [], []
    for version in claimed():
        started = time.monotonic()
        base = interpreter(version)
        if base is None:
            print(f"python_versions: no Python {version} on this machine; not run", file=sys.stderr)
            rows.append(f"| {version} | not on the machine that ran this | not run |")
            continue
        if options.phase in ("build", "all") and build(folder, version, base):
            print(f"python_versions: Python {version}: the install failed", file=sys.stderr)
            failed.append(version)
            continue
        if options.phase in ("run", "all"):
            if not venv_python(folder, version).exists():
                print(f"python_versions: Python {version}: no venv in {folder} (run the build phase)", file=sys.stderr)
                failed.append(version)
            else:
                code, last = smoke_subset(venv_python(folder, version), f"python_versions: Python {version}")
                outcome = last.strip("= ").split(" in ")[0]   # "242 passed, 52 skipped", without the seconds
                rows.append(f"| {full_version(folder, version)} | the smoke subset, without torch | {outcome} |")
                if code:
                    failed.append(version)
        print(f"python_versions: Python {version} {options.phase}: {time.monotonic() - started:.0f} s", flush=True)
    if options.table and options.phase != "build":
        head = "| Python | what runs | outcome |\n|---|---|---|"
        replace_between(options.table, START, END, "\n".join([head, *rows]))
    if failed:
        print(f"python_versions: failed on Python {', '.join(failed)}", file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
