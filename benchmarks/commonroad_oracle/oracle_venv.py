"""Create or check the venv that holds commonroad-io, the oracle for pytest_driveeval.io.commonroad.commonroad.

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
    return _run(python or oracle_python(quiet=True), READER, path, timeout,
                lambda put: [str(path), "--states", put("states", goal_states or []),
                             "--points", put("points", points or [])])


def _run(python: Path, script: Path, path: Path, timeout: float, arguments) -> dict:
    """``script``'s JSON answer, run by ``python`` with ``arguments(put)``, where ``put(name, value)``
    writes ``value`` as a JSON file for it and gives its path; an error with its stderr if it fails."""
    with tempfile.TemporaryDirectory() as tmp:
        def put(name: str, value) -> str:
            file = Path(tmp) / f"{name}.json"
            file.write_text(json.dumps(value))
            return str(file)

        done = subprocess.run([str(python), str(script), *arguments(put)], capture_output=True, text=True,
                              timeout=timeout)
    if done.returncode != 0:
        raise RuntimeError(f"{script.name} failed on {path}:\n{done.stderr[-4000:]}")
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
    request = {"scenario": str(path), "planning_problem": int(problem_id), "length": float(length),
               "width": float(width), "trajectories": trajectories}
    return _run(python or checker_python(make=True), CHECKER, path, timeout,
                lambda put: [put("request", request)])["trajectories"]


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--venv", type=Path, default=VENV)
    args = parser.parse_args()
    print(oracle_python(args.venv))
