"""Our CommonRoad episodes' goal, collision and off-road verdicts at every step against CommonRoad's own
(commonroad-io 2024.3 and the drivability checker in the crime venv, benchmarks/commonroad_oracle/
check_trajectory.py), on the trajectories benchmarks/commonroad_oracle/compare_trajectories.py drives.

Goal and collision must agree at every step.  Off-road must agree exactly with the same rule as ours
(some box corner outside every lanelet, shapely on commonroad-io's lanelet polygons) except where a
corner lies within EDGE (0.15 m) of the road's edge, which our 0.1 m raster may put either side; with
the drivability checker's enclosure of the whole box every disagreement must have a cause measured
in the oracle's distances and areas (compare_trajectories.explain), none unexplained.
Skips without the crime venv (python benchmarks/nuplan_oracle/crime_ttc.py --make-venv), and the
shared files without the shared data; the fixture's tutorial runs whenever the venv is there.
"""
from __future__ import annotations

import importlib.util
import sys

import numpy as np
import pytest

from conftest import REPO_ROOT


def _module():
    path = REPO_ROOT / "benchmarks" / "commonroad_oracle" / "compare_trajectories.py"
    spec = importlib.util.spec_from_file_location("commonroad_compare_trajectories", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # its dataclass looks its module up there
    spec.loader.exec_module(module)
    return module


COMPARE = _module()
CASES = ["fixture", *COMPARE.SCENARIOS]


@pytest.fixture(scope="module")
def checker_python():
    python = COMPARE.ORACLE.checker_python()
    if python is None:
        pytest.skip("the crime venv (commonroad-io with the drivability checker) is absent: run "
                    "python benchmarks/nuplan_oracle/crime_ttc.py --make-venv")
    return python


@pytest.fixture(scope="module")
def episodes(checker_python, request):
    cache = {}

    def get(case: str):
        if case not in cache:
            if case == "fixture":
                path = COMPARE.FIXTURE
            else:
                path = request.getfixturevalue("shared_data") / "commonroad" / f"{case}.xml"
            cache[case] = COMPARE.scenario_episodes(path, checker_python)
        return cache[case]

    return get


@pytest.mark.parametrize("case", CASES)
def test_goal_and_collision_agree_at_every_step(episodes, case):
    eps = episodes(case)
    for ep in eps:
        for ours, theirs in ((ep.goal, "goal"), (ep.collision, "collision"), (ep.collision, "collision_shapely")):
            differ = np.flatnonzero(ours != ep.theirs[theirs])
            assert differ.size == 0, f"{ep.name}: {theirs} differs at steps {differ.tolist()}"
    # the trajectories reach goals, hit obstacles and leave the road, by the oracle's account
    assert any(ep.theirs["goal"].any() for ep in eps)
    assert any(ep.theirs["collision"].any() for ep in eps)
    assert any(ep.theirs["off_road"].any() for ep in eps)


@pytest.mark.parametrize("case", CASES)
def test_off_road_by_our_rule_agrees_except_within_a_cell_of_the_edge(episodes, case):
    for ep in episodes(case):
        differ = ep.off_road != ep.theirs["corner_off_road"]
        far = ep.theirs["corner_edge_distance"][differ]
        assert np.all(far <= COMPARE.EDGE), f"{ep.name}: corners {far} m from the edge disagree"


@pytest.mark.parametrize("case", CASES)
def test_off_road_against_the_drivability_checker_has_a_cause_wherever_it_differs(episodes, case):
    for ep in episodes(case):
        causes = COMPARE.explain(ep)
        unexplained = np.flatnonzero(causes["unexplained"])
        assert unexplained.size == 0, (f"{ep.name}: off-road differs at steps {unexplained.tolist()}, "
                                       f"corner distances {ep.theirs['corner_edge_distance'][unexplained]}, "
                                       f"areas off the road {ep.theirs['outside_area'][unexplained]}")
        # the causes only ever make us more lenient than the box's enclosure, never stricter, but at the edge
        lenient = causes["hairline"] | causes["between corners"]
        assert not np.any(ep.off_road[lenient])


@pytest.mark.parametrize("case", CASES)
def test_the_episode_outcome_is_the_oracles_verdict_at_the_last_step(episodes, case):
    for ep in episodes(case):
        last = {k: bool(v[-1]) for k, v in ep.theirs.items() if v.dtype == bool}
        if ep.outcome == "collision":
            assert last["collision"], ep.name
        elif ep.outcome == "off_road":
            assert last["off_road"] and not last["collision"], ep.name
        elif ep.outcome == "goal":
            assert last["goal"] and not last["collision"], ep.name
        # before the last step no outcome: the oracle sees no collision and no goal there
        assert not np.any(ep.theirs["collision"][:-1]), ep.name
        assert not np.any(ep.theirs["goal"][1:-1]), ep.name
