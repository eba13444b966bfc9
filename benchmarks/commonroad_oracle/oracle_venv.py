"""Create or check the venv that holds commonroad-io, the oracle for pytest_driveeval.io.commonroad.

commonroad-io pins protobuf 3.20.2 and brings rtree, omegaconf, networkx, lxml, iso3166 and the
vehicle models, which is why the package reads CommonRoad XML itself and commonroad-io lives only
here, at ``~/.cache/driveeval-bench/commonroad``, never in the package's requirements. Run it as a
script or call ``oracle_python()``: both are idempotent and print what they did. ``read_scenario``
runs read_scenario.py in the venv and returns its JSON.

``check_trajectories`` runs check_trajectory.py in the other venv, the crime venv of
benchmarks/nuplan_oracle/crime_ttc.py, which has the drivability checker (``checker_python``).
"""
from __future__ import annotations

import argparse
import importlib.util
import json
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmarks/: the venv helpers they share
from reference_venvs import import_check, install_pins, say_to, venv_python  # noqa: E402

VENV = Path.home() / ".cache" / "driveeval-bench" / "commonroad"
READER = Path(__file__).with_name("read_scenario.py")
CHECKER = Path(__file__).with_name("check_trajectory.py")
READY = "oracle-ready.json"  # written after the import check passes; existing_python() looks for it
PINS = {"commonroad-io": "2026.1"}
CHECK = ("import json, importlib.metadata as m;"
         "from commonroad.common.file_reader import CommonRoadFileReader;"
         "print(json.dumps({n: m.version(n) for n in ['commonroad-io', 'numpy', 'shapely', 'protobuf']}))")


def oracle_python(venv: Path = VENV, quiet: bool = False) -> Path:
    """The venv's python, after creating the venv and installing commonroad-io if missing or another version."""
    say = say_to("commonroad", quiet)
    python = venv_python(venv, "commonroad-io oracle", say)
    install_pins(python, PINS, say)
    found = import_check(python, ["-c", CHECK], "commonroad-io", venv)
    (venv / READY).write_text(found)
    say(f"imports fine: {found.strip()}")
    return python


def existing_python(venv: Path = VENV) -> Path | None:
    """The venv's python if it passed its import check before, else None; creates nothing (for skips)."""
    python = venv / "bin" / "python"
    return python if python.exists() and (venv / READY).exists() else None


def read_scenario(path: Path, goal_states: list[dict] | None = None, points: list[list[float]] | None = None,
                  python: Path | None = None, timeout: float = 600) -> dict:
    """What commonroad-io reads from ``path`` (read_scenario.py's JSON), with its goal check on ``goal_states``
    ({"planning_problem": id, "x", "y", "orientation", "velocity", "time_step"} each) and its lanelet
    lookup at ``points`` ([x, y] each)."""
    python = python or oracle_python(quiet=True)
    with tempfile.TemporaryDirectory() as tmp:
        states, at = Path(tmp) / "states.json", Path(tmp) / "points.json"
        states.write_text(json.dumps(goal_states or []))
        at.write_text(json.dumps(points or []))
        done = subprocess.run([str(python), str(READER), str(path), "--states", str(states), "--points", str(at)],
                              capture_output=True, text=True, timeout=timeout)
    if done.returncode != 0:
        raise RuntimeError(f"{READER.name} failed on {path}:\n{done.stderr[-4000:]}")
    return json.loads(done.stdout)


def _crime_ttc():
    spec = importlib.util.spec_from_file_location(
        "crime_ttc", Path(__file__).resolve().parents[1] / "nuplan_oracle" / "crime_ttc.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def checker_python(make: bool = False) -> Path | None:
    """The crime venv's python (commonroad-io 2024.3 with the drivability checker): made when ``make``,
    else the existing one or None (for skips)."""
    crime = _crime_ttc()
    return crime.make_venv() if make else crime.existing_python()


def check_trajectories(path: Path, problem_id: int, length: float, width: float, trajectories: list[dict],
                       python: Path | None = None, timeout: float = 1800) -> list[dict]:
    """check_trajectory.py's verdicts per time step on ``trajectories`` ({"name", "time_step", "x", "y",
    "orientation", "velocity"} lists each, x and y the box centre) of an ego box ``length`` x ``width``."""
    python = python or checker_python(make=True)
    request = {"scenario": str(path), "planning_problem": int(problem_id), "length": float(length),
               "width": float(width), "trajectories": trajectories}
    with tempfile.TemporaryDirectory() as tmp:
        file = Path(tmp) / "request.json"
        file.write_text(json.dumps(request))
        done = subprocess.run([str(python), str(CHECKER), str(file)], capture_output=True, text=True,
                              timeout=timeout)
    if done.returncode != 0:
        raise RuntimeError(f"{CHECKER.name} failed on {path}:\n{done.stderr[-4000:]}")
    return json.loads(done.stdout)["trajectories"]


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--venv", type=Path, default=VENV)
    args = parser.parse_args()
    print(oracle_python(args.venv))
