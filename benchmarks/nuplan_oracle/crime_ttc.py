"""A second check of time to collision: commonroad-crime's TTC on the following cases of cases.py.

Runs in its own venv (``--make-venv`` creates ``~/.cache/driveeval-bench/crime`` with
commonroad-crime from PyPI; it does not share nuplan-devkit's pins) and imports nothing from
pytest_driveeval. It takes score cases (CASE_FORMAT.md) with one straight lane and exactly one
vehicle agent, builds a CommonRoad scenario (the lane as a lanelet, ego and agent as dynamic
obstacles with constant-velocity states) and asks commonroad-crime's ``TTC`` measure for the
time to collision at every frame.

commonroad-crime's TTC is continuous (headway along the lane / closing speed, rounded to 0.01 s).
nuPlan's steps the boxes forward in 0.1 s steps from 0.1 to 2.9 s and answers the first step
at which they touch, so for a lead vehicle on a straight lane the two should agree as
``nuplan = ceil(crime / 0.1) * 0.1`` while that is below 3.0 s, and nuPlan answers none above.

    python crime_ttc.py --make-venv                              # create or check the venv, print versions
    ~/.cache/driveeval-bench/crime/bin/python crime_ttc.py cases.json [--out crime.jsonl]
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any, Dict, List, Optional

VENV = Path.home() / ".cache" / "driveeval-bench" / "crime"
PINS = {"commonroad-crime": "0.4.5"}  # brings commonroad-io, the drivability checker, clcs, numpy 2, ...


def make_venv(venv: Path = VENV) -> Path:
    """The crime venv's python, after creating it and installing commonroad-crime if missing (idempotent)."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmarks/: the venv helpers they share
    from reference_venvs import import_check, install_pins, say_to, venv_python

    say = say_to("crime", False)
    python = venv_python(venv, "commonroad-crime", say)
    install_pins(python, PINS, say)
    versions = ("import importlib.metadata as m, json;"
                "print(json.dumps({n: m.version(n) for n in ['commonroad-crime', 'commonroad-io', "
                "'commonroad-drivability-checker', 'commonroad-clcs', 'numpy', 'shapely']}))")
    found = import_check(python, ["-c", "import commonroad_crime.measure; " + versions], "commonroad-crime", venv)
    say(f"imports fine: {found.strip()}")
    return python


def existing_python(venv: Path = VENV) -> Optional[Path]:
    python = venv / "bin" / "python"
    return python if python.exists() and list(venv.glob("lib/python3.11/site-packages/commonroad_crime")) else None


# ---------------------------------------------------------------- inside the crime venv

def straight_lanelet(lane: Dict[str, Any]) -> Any:
    import numpy as np
    from commonroad.scenario.lanelet import Lanelet
    from shapely.geometry import LineString, Polygon

    baseline = LineString(lane["baseline"])
    if len(baseline.coords) != 2:
        raise ValueError(f"lane {lane['id']}: crime_ttc.py takes straight lanes only (a two-point baseline)")
    # the case's lane outline is a rectangle around the baseline: its area over the length is the width
    half_width = Polygon(lane["polygon"]).area / baseline.length / 2
    centre = np.asarray(baseline.coords, dtype=float)
    direction = (centre[1] - centre[0]) / baseline.length
    normal = np.array([-direction[1], direction[0]])
    return Lanelet(left_vertices=centre + half_width * normal, center_vertices=centre,
                   right_vertices=centre - half_width * normal, lanelet_id=100)


def obstacle(obstacle_id: int, length: float, width: float, centers: List[List[float]],
             speeds: List[float], first_step: int) -> Any:
    import numpy as np
    from commonroad.geometry.shape import Rectangle
    from commonroad.prediction.prediction import TrajectoryPrediction
    from commonroad.scenario.obstacle import DynamicObstacle, ObstacleType
    from commonroad.scenario.state import CustomState, InitialState
    from commonroad.scenario.trajectory import Trajectory

    def state(cls: Any, i: int) -> Any:
        x, y, heading = centers[i]
        made = cls(position=np.array([x, y]), orientation=heading, velocity=speeds[i], acceleration=0.0,
                   yaw_rate=0.0, slip_angle=0.0, time_step=first_step + i)
        # crime reads the lateral components too; InitialState has no such fields, so they are set after
        made.velocity_y = 0.0
        made.acceleration_y = 0.0
        return made

    states = [state(CustomState, i) for i in range(1, len(centers))]
    shape = Rectangle(length, width)
    return DynamicObstacle(obstacle_id, ObstacleType.CAR, shape, state(InitialState, 0),
                           TrajectoryPrediction(Trajectory(first_step + 1, states), shape))


def crime_ttc(case: Dict[str, Any]) -> Dict[str, Any]:
    import math as m

    import numpy as np
    from commonroad.scenario.lanelet import LaneletNetwork
    from commonroad.scenario.scenario import Scenario, ScenarioID
    from commonroad_crime.data_structure.configuration import CriMeConfiguration
    from commonroad_crime.measure.time.ttc import TTC

    vehicles = [a for a in case.get("agents", []) if a["type"] == "vehicle"]
    lanes = (case.get("map") or {}).get("lanes", [])
    if len(vehicles) != 1 or len(case.get("agents", [])) != 1 or len(lanes) != 1:
        raise ValueError("crime_ttc.py takes cases with one lane and exactly one vehicle agent")
    (lead,) = vehicles
    frames = lead["frames"]
    if frames != list(range(frames[0], frames[0] + len(frames))):
        raise ValueError("the agent's frames must be consecutive")
    dt = float(np.mean(np.diff(case["timestamps"])))
    scenario = Scenario(dt, ScenarioID())
    network = LaneletNetwork()
    network.add_lanelet(straight_lanelet(lanes[0]))
    scenario.add_objects(network)
    ego = case["ego"]
    # nuPlan's TTC moves the box centre with the rear axle's speed along the heading; crime reads
    # `velocity` as the (signed) speed along the lane: the same number on a straight lane.
    ego_speeds = [float(np.hypot(*v)) * (1 if v[0] >= 0 else -1) for v in ego["velocity"]]
    scenario.add_objects(obstacle(1, ego["length"], ego["width"], ego["center"], ego_speeds, 0))
    scenario.add_objects(obstacle(2, lead["length"], lead["width"], lead["center"],
                                  [float(np.hypot(*v)) for v in lead["velocity"]], frames[0]))
    scenario.assign_obstacles_to_lanelets()
    config = CriMeConfiguration()
    config.update(ego_id=1, sce=scenario)
    measure = TTC(config)
    values = []
    for step in range(len(case["timestamps"])):
        value = float(measure.compute(2, step, verbose=False)) if step in frames else m.inf
        values.append(None if not m.isfinite(value) else value)
    finite = [v for v in values if v is not None]
    return {"name": case["name"], "crime_ttc": values, "min_crime_ttc": min(finite) if finite else None,
            "nuplan_grid_min": nuplan_grid(min(finite)) if finite else None}


def nuplan_grid(ttc: float, step: float = 0.1, horizon: float = 3.0) -> Optional[float]:
    """What nuPlan's stepping should answer for a continuous TTC: the first step at or after it, below the horizon."""
    stepped = math.ceil(round(ttc / step, 6)) * step
    return round(stepped, 6) if stepped < horizon - 1e-9 else None


def agreement(crime: List[Optional[float]], nuplan: List[Optional[float]]) -> Dict[str, Any]:
    """Frames where nuPlan's stepped TTC is the first 0.1 s step at or after crime's (None = none below 3 s)."""
    expected = [None if c is None else nuplan_grid(c) for c in crime]
    differing = [i for i, (want, got) in enumerate(zip(expected, nuplan))
                 if not (want is None and got is None or want is not None and got is not None
                         and math.isclose(want, got, abs_tol=1e-6))]
    return {"frames": len(crime), "frames_agreeing": len(crime) - len(differing), "differing_frames": differing[:20]}


def main(argv: Optional[List[str]] = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("cases", type=Path, nargs="?", help="JSON file: one case or a list (CASE_FORMAT.md)")
    parser.add_argument("--out", type=Path)
    parser.add_argument("--only", nargs="*", help="case names (default: every case with one lane and one vehicle)")
    parser.add_argument("--make-venv", action="store_true", help="create or check the crime venv and exit")
    parser.add_argument("--nuplan", type=Path, help="the nuPlan oracle's answers (JSON lines) to compare frame by frame")
    args = parser.parse_args(argv)
    if args.make_venv:
        print(make_venv())
        return 0
    if args.cases is None:
        parser.error("give a case file, or --make-venv")
    data = json.loads(args.cases.read_text())
    cases = data if isinstance(data, list) else [data]
    if args.only:
        cases = [c for c in cases if c["name"] in set(args.only)]
    else:
        cases = [c for c in cases if len(c.get("agents", [])) == 1 and c["agents"][0]["type"] == "vehicle"
                 and c.get("map") and len(c["map"]["lanes"]) == 1]
    nuplan = {}
    if args.nuplan:
        nuplan = {r["name"]: r for r in map(json.loads, args.nuplan.read_text().splitlines()) if "error" not in r}
    lines = []
    for case in cases:
        try:
            out = crime_ttc(case)
        except Exception as error:
            out = {"name": case["name"], "error": f"{type(error).__name__}: {error}"}
        if case["name"] in nuplan and "error" not in out:
            out.update(agreement(out["crime_ttc"], nuplan[case["name"]]["time_to_collision"]))
        lines.append(json.dumps(out))
        if args.out is None:
            print(json.dumps({k: v for k, v in out.items() if k != "crime_ttc"}), flush=True)
    if args.out is not None:
        args.out.write_text("\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
