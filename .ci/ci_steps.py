"""What CI's scripts share: running a command in the clone, a venv with uv, the smoke subset, and
the generated parts of a docs page (between two markers)."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from fast_install import uv_install

ROOT = Path(__file__).resolve().parent.parent


def run(command: list[str], **kwargs) -> int:
    """``command`` in the clone, its output as it comes; its exit code."""
    print("+", " ".join(command), flush=True)
    return subprocess.run(command, cwd=ROOT, **kwargs).returncode


def streamed(command: list[str]) -> tuple[int, str]:
    """Run ``command`` in the clone, echoing its output; its exit code and last non-blank line."""
    print("+", " ".join(command), flush=True)
    process = subprocess.Popen(command, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    last = ""
    for line in process.stdout:
        print(line, end="", flush=True)
        if line.strip():
            last = line.strip()
    return process.wait(), last


def new_venv(base: str, folder: Path) -> tuple[list[str], dict[str, str]] | None:
    """A venv in ``folder`` made by the Python ``base``, with uv in it: uv's install command into it (pip's
    sources, as .ci/fast_install.py passes them) and its environment; None when either step failed."""
    python = folder / "bin" / "python"
    if run([base, "-m", "venv", str(folder)]) or run([str(python), "-m", "pip", "install", "--quiet", "uv"]):
        return None
    uv, environment = uv_install(str(python))
    return [*uv, "--quiet"], environment


def smoke_subset(python: Path, label: str) -> tuple[int, str]:
    """``pytest tests -m smoke -n 2`` with ``python``: its exit code, pytest's exit 5 (nothing ran) made a
    failure, and pytest's last line."""
    code, last = streamed([str(python), "-m", "pytest", "tests", "-m", "smoke", "-n", "2", "-q",
                           "-p", "no:cacheprovider"])
    if code == 5:
        print(f"{label}: the smoke subset collected nothing; that is a failure", file=sys.stderr)
        return 1, last
    return code, last


def between(page: str, start: str, end: str) -> str:
    """The text of ``page`` between the markers ``start`` and ``end``."""
    return page.split(start, 1)[1].split(end, 1)[0]


def replace_between(path: Path, start: str, end: str, text: str) -> None:
    """Write ``text`` into the page at ``path`` between the markers ``start`` and ``end``.  The page is
    replaced whole (a new file renamed over it): CI writes it while the suite's tests read it."""
    page = path.read_text()
    before, rest = page.split(start, 1)
    _, after = rest.split(end, 1)
    written = path.with_name(f".{path.name}.writing")
    written.write_text(f"{before}{start}\n{text}\n{end}{after}")
    os.replace(written, path)
