"""What the reference venvs of the benchmarks and oracles share (l5kit_oracle, nuplan_oracle and its
commonroad-crime check): find Python 3.11, make the venv, see what is installed in it, pip-install
pins.  Standard library only, so that a script running inside one of those venvs can load it too.
Never part of the package's requirements.
"""
from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path
from typing import Callable, Dict, List, Optional


def say_to(label: str, quiet: bool) -> Callable[[str], None]:
    """Progress lines "[<label> venv] ...", or nothing when ``quiet``."""
    return (lambda *_: None) if quiet else (lambda msg: print(f"[{label} venv] {msg}", flush=True))


def base_interpreter(label: str) -> str:
    found = shutil.which("python3.11")
    if found is None:
        raise RuntimeError(f"python3.11 is not on PATH: the {label} venv needs Python 3.11")
    return found


def venv_python(venv: Path, label: str, say: Callable[[str], None]) -> Path:
    """The venv's python, making the venv first if it is not there."""
    python = venv / "bin" / "python"
    if not python.exists():
        say(f"creating {venv} with {base_interpreter(label)}")
        subprocess.run([base_interpreter(label), "-m", "venv", str(venv)], check=True)
    else:
        say(f"{venv} exists")
    return python


def requirement(name: str, version: Optional[str]) -> str:
    return name if version is None else f"{name}=={version}"


def pip_install(python: Path, args: List[str]) -> None:
    # pip's output is kept for a failure only: the extra local indexes make it warn for every package.
    done = subprocess.run([str(python), "-m", "pip", "install", "-q", *args], capture_output=True, text=True)
    if done.returncode != 0:
        raise RuntimeError(f"pip install {' '.join(args)} failed in {python}:\n{done.stdout}{done.stderr}")


def installed(python: Path, names: List[str]) -> Dict[str, Optional[str]]:
    """The version of each of ``names`` installed in ``python``'s environment, None where absent."""
    script = ("import importlib.metadata as m, json, sys\n"
              "out = {}\n"
              "for n in sys.argv[1:]:\n"
              "    try: out[n] = m.version(n)\n"
              "    except m.PackageNotFoundError: out[n] = None\n"
              "print(json.dumps(out))")
    done = subprocess.run([str(python), "-c", script, *names], check=True, capture_output=True, text=True)
    return json.loads(done.stdout)


def install_pins(python: Path, pins: Dict[str, Optional[str]], say: Callable[[str], None]) -> None:
    """Install ``pins`` into ``python``'s environment when any is absent or at another version."""
    wrong = mismatched(installed(python, list(pins)), pins)
    if not wrong:
        say("pinned dependencies present")
        return
    say("installing " + " ".join(requirement(n, pins[n]) for n in wrong))
    # All pins in one resolve, so that no dependency pulls another version of a pinned one.
    pip_install(python, [requirement(n, v) for n, v in pins.items()])


def import_check(python: Path, args: List[str], what: str, venv: Path) -> str:
    """Run ``python args`` (an import check that prints what it found); its output, or an error that
    says ``what`` does not import in ``venv``."""
    done = subprocess.run([str(python), *args], capture_output=True, text=True)
    if done.returncode != 0:
        raise RuntimeError(f"{what} does not import in {venv}:\n{done.stderr}")
    return done.stdout


def mismatched(have: Dict[str, Optional[str]], wanted: Dict[str, Optional[str]]) -> List[str]:
    """The pinned names absent or at another version; a local-version tag (torch's "+cpu") still satisfies
    its pin."""
    return [n for n, v in wanted.items()
            if have.get(n) is None or (v is not None and have[n].split("+")[0] != v)]
