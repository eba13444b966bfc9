"""idm_expert on the shared CommonRoad files: on every problem whose goal a route reaches, the goal in
at least 90 % of episodes and no collision that is its fault (a few seeds here, seeds 0-63 in
benchmarks/bench_commonroad_expert.py); the problems no route reaches, and why, read from the file."""
from __future__ import annotations

import numpy as np
import pytest

from pytest_driveeval.io.commonroad.commonroad_geometry import lanelets_at, shape_outline
from pytest_driveeval.metrics.episode_outcomes import GOAL
from pytest_driveeval.policies.idm_expert import IDMExpert
from pytest_driveeval.sim.commonroad_fault import FaultRecorder
from pytest_driveeval.sim.commonroad_route import RouteError, plan_route
from pytest_driveeval.sim.commonroad_scene import commonroad_scene, read_cached

pytest.importorskip("torch")  # run_policy's no-grad context

SEEDS = np.arange(6)
REACHABLE = [("FRA_Anglet-1_1_T-1", 1, "replay"), ("USA_Lanker-1_1_T-1", 1215, "reactive"),
             ("USA_US101-3_3_T-1", 396, "replay"), ("ZAM_Tutorial-1_2_T-1", 100, "replay"),
             ("test_reading_complex_tl", 1995, "replay"), ("test_reading_ks_state", 29, "replay")]


@pytest.mark.parametrize("name, problem, traffic", REACHABLE, ids=[f"{n}-{p}" for n, p, _ in REACHABLE])
def test_the_expert_reaches_the_goal_without_fault(shared_data, name, problem, traffic):
    from pytest_driveeval.usecases.policy_benchmark.evaluate import run_policy

    scene = commonroad_scene(shared_data / "commonroad" / f"{name}.xml", problem, traffic=traffic)
    faults = FaultRecorder()
    run = run_policy(scene, SEEDS, IDMExpert(), "idm_expert", on_step=faults)
    assert np.mean(run.outcome == GOAL) >= 0.9, dict(zip(SEEDS.tolist(), run.outcome_names()))
    assert not faults.faults(len(SEEDS)).any(), faults.kind


def _goal_points(problem) -> np.ndarray:
    outlines = [shape_outline(s, circle_vertices=16) for g in problem.goals for s in g.shapes]
    return np.concatenate([np.concatenate([o.mean(axis=0, keepdims=True), o]) for o in outlines])


@pytest.mark.parametrize("name, problems", [("ZAM_Loading_Bay-1_1_T", range(100, 112)),
                                             ("test_reading_all", [1000])])
def test_goals_off_every_lanelet_cannot_be_reached(shared_data, name, problems):
    scenario = read_cached(shared_data / "commonroad" / f"{name}.xml")
    for problem_id in problems:
        problem = scenario.planning_problems[problem_id]
        # From the file: no lanelet holds any point of any goal shape (its centre and outline); the ego,
        # judged on its box centre, would have to leave the road (a loading bay's docks, a test's shapes).
        points = _goal_points(problem)
        assert not any(lanelets_at(scenario, points[:, 0], points[:, 1]))
        with pytest.raises(RouteError, match=rf"planning problem {problem_id}: the goal .* lies off every lanelet"):
            plan_route(scenario, problem)


@pytest.mark.parametrize("name, problem", [("test_reading_intersection_traffic_sign", 4000),
                                           ("test_reading_planning_problem", 1000)])
def test_starts_off_every_lanelet_cannot_be_routed(shared_data, name, problem):
    scenario = read_cached(shared_data / "commonroad" / f"{name}.xml")
    init = scenario.planning_problems[problem].initial
    assert lanelets_at(scenario, init.x, init.y) == [[]]  # from the file: no lanelet holds the start
    with pytest.raises(RouteError, match=rf"planning problem {problem}: no lanelet .* holds its initial position"):
        plan_route(scenario, scenario.planning_problems[problem])
