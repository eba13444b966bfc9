#!/usr/bin/env python3
"""Install requirements as ``pip install`` would, with uv doing the unpacking.

pip installed the test extras (torch, ray, scipy, matplotlib, ... 1.7 GB) in 105-130 s on the
two-core CI machine, a tenth of CI's 20-minute budget; uv installs the same set in about 10 s,
since it unpacks in parallel and links files from its cache.  uv does not read pip's
configuration, so this passes pip's on: its find-links, index and extra-index URLs, constraint
files and certificate (on these machines the CPU build of torch lies in a local index that only
pip's configuration names; without it a registry serves the multi-GB CUDA build).  The index
strategy is pip's: the best match across every index, not the first index that has the name.

Usage: ``python .ci/fast_install.py ARGS...`` with pip install's requirement arguments
(``torch==2.13.0 -e ".[test]"``).  When uv cannot be had or fails, pip installs instead, so a
missing uv costs time and never the run.
"""
from __future__ import annotations

import os
import re
import subprocess
import sys

#: pip's option -> uv's, for the options that say where packages come from
FLAGS = {"find-links": "--find-links", "extra-index-url": "--extra-index-url", "index-url": "--index-url",
         "constraint": "--constraint"}
ENTRY = re.compile(r"^(?:[\w:]*)\.([\w-]+)='(.*)'$")


def pip(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "pip", *args], capture_output=True, text=True)


def pip_sources() -> tuple[list[str], dict[str, str]]:
    """uv's arguments and environment for the sources pip's configuration (files and PIP_*) names."""
    args: list[str] = []
    env: dict[str, str] = {}
    for line in pip("config", "list").stdout.splitlines():
        found = ENTRY.match(line.strip())
        if not found:
            continue
        key, value = found.groups()
        if key in FLAGS:
            for item in value.split():
                if not _listed(args, FLAGS[key], item):
                    args += [FLAGS[key], item]
        elif key == "cert":
            env["SSL_CERT_FILE"] = value
    return args, env


def _listed(args: list[str], flag: str, item: str) -> bool:
    return any(args[i] == flag and args[i + 1] == item for i in range(0, len(args) - 1, 2))


def uv_install(python: str) -> tuple[list[str], dict[str, str]]:
    """uv's install command into ``python``'s environment (uv run by that Python, which has it), with
    pip's sources and pip's index strategy, and the environment to run it in."""
    sources, env = pip_sources()
    return ([python, "-m", "uv", "pip", "install", "--python", python, "--index-strategy", "unsafe-best-match",
             *sources], {**os.environ, **env})


def main(requirements: list[str]) -> int:
    if pip("install", "--quiet", "uv").returncode == 0:
        command, env = uv_install(sys.executable)
        if subprocess.run([*command, *requirements], env=env).returncode == 0:
            return 0
        print("fast_install: uv failed; pip installs instead", file=sys.stderr)
    else:
        print("fast_install: uv could not be installed; pip installs instead", file=sys.stderr)
    return subprocess.run([sys.executable, "-m", "pip", "install", *requirements]).returncode


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
