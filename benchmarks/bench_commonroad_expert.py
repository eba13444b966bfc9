"""``idm_expert`` on every planning problem of the shared CommonRoad files and the demo's fixtures: goal
rate, at-fault collisions (nuPlan's blame, sim.commonroad_fault), all collisions, off-road and
step-limit rates over seeds 0-63, the recorded obstacles replayed and, on a second line per problem,
reacting (``Traffic: reactive``).  The reference, in the same run on the same seeds: the ``constant``
baseline (keep speed and heading), which was the only competent CommonRoad policy before.

Problems whose goal no route reaches are listed with the reason (sim.commonroad_route's RouteError, or
the scene's own error when the file cannot be driven at all); they are not driven.  Files with the same
content (the demo's fixture is a copy of a shared file) count once.

Target (issue 36): on every reachable problem >= 90 % goals and no at-fault collision.

    python benchmarks/bench_commonroad_expert.py [--seeds 64] [--no-reactive] [--smoke]
"""
from __future__ import annotations

import argparse
import hashlib
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from pytest_driveeval.io.commonroad.commonroad import CommonRoadError  # noqa: E402
from pytest_driveeval.sim.commonroad_fault import FaultRecorder  # noqa: E402
from pytest_driveeval.metrics.episode_outcomes import COLLISION, GOAL, OFF_ROAD, STEP_LIMIT  # noqa: E402
from pytest_driveeval.policies.control_baselines import ConstantAction  # noqa: E402
from pytest_driveeval.policies.idm_expert import IDMExpert  # noqa: E402
from pytest_driveeval.sim.commonroad_route import RouteError, plan_route  # noqa: E402
from pytest_driveeval.sim.commonroad_scene import commonroad_scene, read_cached  # noqa: E402
from pytest_driveeval.usecases.policy_benchmark.evaluate import run_policy  # noqa: E402

SHARED = Path(os.environ.get("DRIVEEVAL_SHARED_DATA", ROOT.parent / "shared" / "data")) / "commonroad"
FIXTURES = ROOT / "fixtures" / "commonroad"


def files(smoke: bool) -> list[Path]:
    """Every CommonRoad file once by content; the smoke run: the demo's fixture only."""
    found = sorted(FIXTURES.glob("*.xml")) if smoke else sorted(SHARED.glob("*.xml")) + sorted(FIXTURES.glob("*.xml"))
    seen, out = set(), []
    for path in found:
        digest = hashlib.sha256(path.read_bytes()).hexdigest()
        if digest not in seen:
            seen.add(digest)
            out.append(path)
    return out


def drive(scene, seeds: np.ndarray, policy, name: str) -> dict:
    faults = FaultRecorder()
    run = run_policy(scene, seeds, policy, name, on_step=faults)
    rate = lambda code: 100.0 * float(np.mean(run.outcome == code))  # noqa: E731
    return {"goal": rate(GOAL), "at_fault": int(faults.faults(len(seeds)).sum()), "collision": rate(COLLISION),
            "off_road": rate(OFF_ROAD), "limit": rate(STEP_LIMIT)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, default=64, help="seeds 0 .. N-1 per problem (default 64)")
    parser.add_argument("--no-reactive", action="store_true", help="the recorded obstacles replayed only")
    parser.add_argument("--smoke", action="store_true", help="the fixture, 2 seeds, replay only: checks the script runs")
    args = parser.parse_args()
    if args.smoke:
        args.seeds, args.no_reactive = 2, True
        print("smoke run: tiny sizes; the figures mean nothing")
    seeds = np.arange(args.seeds)
    print(f"seeds 0-{args.seeds - 1}; files from {SHARED} and {FIXTURES}")
    print(f"{'file':46s} {'problem':>7s} {'traffic':8s} {'goal %':>7s} {'at-fault':>8s} {'coll %':>7s} "
          f"{'off-rd %':>8s} {'limit %':>7s} | constant goal %  (s)")
    worst, worst_constant, at_fault, reachable, unreachable = 100.0, 100.0, 0, 0, []
    start = time.perf_counter()
    for path in files(args.smoke):
        try:
            problems = sorted(read_cached(path).planning_problems)
        except (OSError, CommonRoadError) as exc:
            unreachable.append((path.name, "-", f"unreadable: {exc}"))
            continue
        if not problems:
            unreachable.append((path.name, "-", "no planning problem"))
        for problem in problems:
            scenario = read_cached(path)
            try:
                plan_route(scenario, scenario.planning_problems[problem])
                scenes = {"replay": commonroad_scene(path, problem)}
            except (RouteError, CommonRoadError) as exc:
                unreachable.append((path.name, problem, str(exc).split(": ", 2)[-1]))
                continue
            if not args.no_reactive:
                scenes["reactive"] = commonroad_scene(path, problem, traffic="reactive")
            reachable += 1
            for traffic, scene in scenes.items():
                t = time.perf_counter()
                mine = drive(scene, seeds, IDMExpert(), "idm_expert")
                ref = drive(scene, seeds, ConstantAction(), "constant")
                worst = min(worst, mine["goal"])
                worst_constant = min(worst_constant, ref["goal"]) if traffic == "replay" else worst_constant
                at_fault += mine["at_fault"]
                print(f"{path.name:46s} {problem:>7} {traffic:8s} {mine['goal']:7.1f} {mine['at_fault']:8d} "
                      f"{mine['collision']:7.1f} {mine['off_road']:8.1f} {mine['limit']:7.1f} | {ref['goal']:7.1f}"
                      f"  ({time.perf_counter() - t:.1f})", flush=True)
    print(f"\nnot reachable ({len(unreachable)} problem(s); not driven):")
    for name, problem, why in unreachable:
        print(f"  {name} {problem}: {why}")
    print(f"\nwall {time.perf_counter() - start:.1f} s")
    print(f"expert: lowest goal rate {worst:.1f} % over {reachable} reachable problem(s) (target 90), "
          f"{at_fault} at-fault collision(s) (target 0); constant baseline's lowest {worst_constant:.1f} %")


if __name__ == "__main__":
    main()
