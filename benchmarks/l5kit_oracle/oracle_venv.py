"""Create or check the venv that holds l5kit 1.5.0, the oracle for rasters and their speed.

l5kit 1.5.0 pins numpy~=1.19, torch<2, shapely<2 and more that no longer install
on Python 3.11, so it goes in with ``--no-deps`` beside a set of newer pins under
which it still imports and rasterizes (issue 14).  The venv lives at
``~/.cache/driveeval-bench/l5kit``, is made on first use and is never part of the
package's requirements.  Run it as a script (``python benchmarks/l5kit_oracle/oracle_venv.py``)
or call ``oracle_python()`` from a benchmark or test: both are idempotent and
print what they did.
"""
from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmarks/: the venv helpers they share
from reference_venvs import import_check, install_pins, installed, pip_install, say_to, venv_python  # noqa: E402

VENV = Path.home() / ".cache" / "driveeval-bench" / "l5kit"
RASTERIZE = Path(__file__).with_name("rasterize.py")
L5KIT = "l5kit==1.5.0"
# torch is pinned to the served CPU wheel: an unpinned torch pulls a CUDA build of several GB.
PINS = {
    "numpy": "1.23.5",
    "zarr": "2.18.2",
    "numcodecs": "0.12.1",
    "opencv-contrib-python-headless": "4.8.1.78",
    "shapely": "2.0.2",
    "scipy": "1.10.1",
    "matplotlib": "3.7.5",
    "protobuf": "3.20.3",
    "pymap3d": "3.1.0",
    "transforms3d": "0.4.2",
    "torch": "2.13.0",
    "imageio": None,
    "tqdm": None,
    "pyyaml": None,
    "ptable": None,
}
# Imported by the check: the modules rasterize.py uses.
CHECK = ("import l5kit, l5kit.data, l5kit.dataset, l5kit.rasterization, numpy, torch;"
         "import importlib.metadata as m;"
         "print(__import__('json').dumps({n: m.version(n) for n in %r}))")


def oracle_python(venv: Path = VENV, quiet: bool = False) -> Path:
    """The venv's python, after creating the venv and installing what is missing or differs."""
    say = say_to("l5kit", quiet)
    python = venv_python(venv, "l5kit oracle", say)
    install_pins(python, PINS, say)  # l5kit's imports need nothing beyond them (checked by CHECK below)
    if installed(python, ["l5kit"])["l5kit"] != L5KIT.split("==")[1]:
        say(f"installing {L5KIT} --no-deps")
        pip_install(python, ["--no-deps", L5KIT])
    else:
        say(f"{L5KIT} present")
    found = import_check(python, ["-c", CHECK % (["l5kit", *PINS],)], "l5kit", venv)
    say("imports fine: " + found.strip())
    return python


def existing_python(venv: Path = VENV) -> Path | None:
    """The venv's python if l5kit 1.5.0 is installed there, else None; creates nothing (for skips)."""
    python = venv / "bin" / "python"
    installed_l5kit = list(venv.glob("lib/python3.11/site-packages/l5kit-1.5.0.dist-info"))
    return python if python.exists() and installed_l5kit else None


def run_rasterize(spec: dict, python: Path | None = None, timeout: float = 1800) -> list[dict]:
    """Run rasterize.py in the venv with ``spec`` (keys of its SPEC_DEFAULTS); its JSON stdout lines, parsed."""
    python = python or oracle_python(quiet=True)
    with tempfile.TemporaryDirectory() as tmp:
        spec_path = Path(tmp) / "spec.json"
        spec_path.write_text(json.dumps(spec))
        done = subprocess.run([str(python), str(RASTERIZE), "--spec", str(spec_path)],
                              capture_output=True, text=True, timeout=timeout)
    if done.returncode != 0:
        raise RuntimeError(f"{RASTERIZE.name} failed on {json.dumps(spec)}:\n{done.stderr[-4000:]}")
    return [json.loads(line) for line in done.stdout.splitlines() if line.startswith("{")]


if __name__ == "__main__":
    print(oracle_python())
    sys.exit(0)
