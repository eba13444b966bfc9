#!/usr/bin/env python3
"""Run test files each on its own, as a person runs the one file they are working on.

The full suite hides a file that only passes beside others (a module another file imported
first, a fixture of another folder's conftest.py): ``pytest tests/sim/test_x.py`` alone then
fails with ``No module named 'tests'``.  CI runs a sample of the files, each alone, after the
suite: a different sample per commit (the commit hash seeds it) and the same sample every time
for one commit, so a red build is reproduced by running this again.  ``--all`` runs every file.

Files whose module is marked slow or ray (``pytestmark``) are left out, and in the others the
slow and ray tests are deselected: the sample is to stay cheap.  Each file runs through the
``pytest`` command, not ``python -m pytest``, which would put the working directory on the import
path and hide exactly the imports this looks for.

Exit status: 0 when every file run passed, 1 when one did not (each is named, with its last
lines), 2 for a usage error.
"""
from __future__ import annotations

import argparse
import random
import re
import shutil
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DESELECT = "not slow and not ray"
#: a module marked as a whole: ``pytestmark = pytest.mark.ray`` or a list naming slow or ray
MODULE_MARK = re.compile(r"^pytestmark\s*=.*\bmark\.(slow|ray)\b", re.MULTILINE)
#: pytest's exit code when every test of the file was deselected (all slow or ray): not a failure
NO_TESTS_RAN = 5
#: a file that runs longer than this alone is reported as failed (a hang would hold CI for hours)
TIMEOUT_SECONDS = 1200


def test_files(root: Path) -> list[Path]:
    """Every test file under ``root``/tests whose module is not marked slow or ray, sorted."""
    files = sorted((root / "tests").rglob("test_*.py"))
    return [f for f in files if not MODULE_MARK.search(f.read_text(encoding="utf-8", errors="replace"))]


def commit_seed(root: Path) -> int:
    """The commit's hash as a number; 0 outside a git checkout (the same sample every time then)."""
    try:
        head = subprocess.run(["git", "-C", str(root), "rev-parse", "HEAD"], capture_output=True, text=True,
                              check=True).stdout.strip()
        return int(head[:12], 16)
    except (OSError, subprocess.CalledProcessError, ValueError):
        return 0


def sample(files: list[Path], count: int, seed: int) -> list[Path]:
    """``count`` of ``files`` chosen by ``seed``, in file order."""
    if count >= len(files):
        return list(files)
    chosen = set(random.Random(seed).sample(range(len(files)), count))
    return [f for i, f in enumerate(files) if i in chosen]


def pytest_command() -> list[str]:
    """The ``pytest`` script of this Python (a venv's bin/), else the one on PATH."""
    beside = Path(sys.executable).parent / "pytest"
    found = str(beside) if beside.is_file() else shutil.which("pytest")
    if found is None:
        raise SystemExit("each_file_alone: no 'pytest' command beside this Python or on PATH; install pytest")
    return [found]


def run_alone(path: Path, root: Path) -> tuple[bool, str]:
    """Whether ``path`` passes on its own, and why not (:func:`excerpt`)."""
    command = pytest_command() + [str(path.relative_to(root)), "-q", "-rfE", "-p", "no:cacheprovider",
                                  "-m", DESELECT]
    try:
        done = subprocess.run(command, cwd=root, capture_output=True, text=True, timeout=TIMEOUT_SECONDS,
                              stdin=subprocess.DEVNULL)
    except subprocess.TimeoutExpired:
        return False, f"still running after {TIMEOUT_SECONDS} s"
    return done.returncode in (0, NO_TESTS_RAN), excerpt(done.stdout + done.stderr)


def excerpt(output: str, most: int = 12) -> str:
    """Why a run failed, in a few lines: pytest's ``E`` lines (the exception of each failure or
    collection error: a collection error's summary line names no reason), then its last line."""
    lines = output.strip().splitlines()
    why = [line for line in lines if line.startswith("E ")][:most]
    named = [line for line in lines if line.startswith(("FAILED ", "ERROR "))][:most]
    return "\n".join(why + named + lines[-1:])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("paths", nargs="*", type=Path,
                        help="test files or folders to choose from (default: all of tests/)")
    parser.add_argument("--all", action="store_true", help="run every file, not a sample")
    parser.add_argument("--count", type=int, default=5, help="how many files the sample has (default 5)")
    parser.add_argument("--seed", type=int, help="the sample's seed (default: from the commit hash)")
    parser.add_argument("--jobs", type=int, default=2,
                        help="files run at the same time, each in its own process (default 2: CI's cores)")
    parser.add_argument("--list", action="store_true", help="name the files that would run, and run none")
    args = parser.parse_args(argv)
    if args.count < 1:
        parser.error(f"--count must be at least 1, not {args.count}")
    if args.jobs < 1:
        parser.error(f"--jobs must be at least 1, not {args.jobs}")
    files = test_files(ROOT)
    if args.paths:
        wanted = [p.resolve() for p in args.paths]
        missing = [str(p) for p in args.paths if not p.exists()]
        if missing:
            parser.error(f"no such file or folder: {', '.join(missing)}")
        files = [f for f in files if any(f == w or w in f.parents for w in wanted)]
    seed = commit_seed(ROOT) if args.seed is None else args.seed
    chosen = files if args.all else sample(files, args.count, seed)
    what = "every file" if args.all else f"{len(chosen)} of {len(files)} files (seed {seed})"
    print(f"each_file_alone: {what}, each alone with -m '{DESELECT}'", flush=True)
    if args.list:
        print("\n".join(str(f.relative_to(ROOT)) for f in chosen))
        return 0
    failed = []
    # Side by side: each file is its own process (nothing shared but the disk), and the runs are
    # reported in file order, whichever finishes first.
    with ThreadPoolExecutor(max_workers=args.jobs) as pool:
        outcomes = pool.map(lambda path: run_alone(path, ROOT), chosen)
        for path, (ok, tail) in zip(chosen, outcomes):
            name = path.relative_to(ROOT)
            print(f"  {'passed' if ok else 'FAILED'}  {name}", flush=True)
            if not ok:
                failed.append(name)
                print("\n".join("      " + line for line in tail.splitlines()), flush=True)
    if failed:
        print(f"each_file_alone: {len(failed)} file(s) fail when run alone: {', '.join(map(str, failed))}; "
              f"run one as 'pytest <file>' to see why", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
