"""Planners that are code in closed-loop items: ``Model: pkg.mod:factory`` under the opt-in (refused
without it, at the file's line), a robustness search and the regression gate driving one; and
``Model: pdm_closed``, the package's own, with no opt-in."""
from __future__ import annotations

import json
import shutil

import pytest

pytest.importorskip("torch")

from conftest import REPO_ROOT  # noqa: E402

NUSCENES = REPO_ROOT / "fixtures" / "scenarionet" / "nuscenes"

# A planner written against the API alone: straight on at its speed, along its heading.  It leaves
# what it was told in a file, so the test sees that initialize ran with the map, route and goal.
PLANNER = """\
import json
from pathlib import Path

import numpy as np


class Straight:
    def initialize(self, context):
        told = [dict(route=len(s.route.lanes), roadblocks=len(s.route.roadblocks), lanes=s.map.num_lanes,
                     near=len(s.map.lanes_near(s.goal.xy, 5.0)), goal=s.goal.frame) for s in context.scenes]
        with Path("told.jsonl").open("a") as out:
            out.write(json.dumps(told) + "\\n")
        self.future = context.future_frames
        self.dt = context.step_time

    def plan(self, obs):
        k = np.arange(1, self.future + 1) * self.dt
        positions = np.zeros((len(obs.rows), self.future, 2))
        positions[..., 0] = obs.ego_speed[:, None] * k
        return {"positions": positions, "yaws": np.zeros((len(obs.rows), self.future))}


def make():
    return Straight()
"""

SCENARIO = """\
ScenarioFormatVersion: 3.0.0
ScenarioName: {name}
Evaluation:
  UseCaseName: closed_loop
  UseCaseFormatVersion: 0.1.0
  Datasets:
    - nuscenes:
        Path: nuscenes
  Model: {model}
  Unroll:
    StartFrame: 10
    Steps: {steps}
    Scenes: [0]
    DriftThreshold: null
  Conditions:
    Collisions: {{Front: 0, Side: 0, Rear: 0, AtFaultOnly: true}}
{extra}"""


@pytest.fixture
def cl(pytester):
    shutil.copytree(NUSCENES, pytester.path / "nuscenes")
    pytester.path.joinpath("myplanner.py").write_text(PLANNER)
    pytester.syspathinsert()
    return pytester


def told(pytester) -> list:
    return [json.loads(line) for line in (pytester.path / "told.jsonl").read_text().splitlines()]


def test_a_planner_factory_is_refused_at_its_line_without_the_opt_in_and_runs_with_it(cl):
    cl.makefile(".scenario.yaml", mine=SCENARIO.format(name="mine", model="myplanner:make", steps=10, extra=""))
    result = cl.runpytest("-q", "-p", "no:randomly")
    result.assert_outcomes(errors=1)
    result.stdout.fnmatch_lines(["*ModelError: mine.scenario.yaml:9: Model 'myplanner:make' would run Python code*"])
    assert not (cl.path / "told.jsonl").exists()
    result = cl.runpytest("-q", "-p", "no:randomly", "--driveeval-allow-scenario-code")
    result.assert_outcomes(passed=1)
    (scenes,) = told(cl)
    assert scenes[0]["route"] >= 1 and scenes[0]["lanes"] > scenes[0]["route"] and scenes[0]["near"] >= 1
    assert scenes[0]["goal"] > 10


def test_a_robustness_search_and_the_regression_gate_drive_a_planner(cl):
    search = "  Perturbation:\n    Lateral: [-1.0, 1.0]\n    Examples: 4\n    Batch: 4\n"
    cl.makefile(".scenario.yaml", search=SCENARIO.format(name="search", model="myplanner:make", steps=8, extra=search),
                gated=SCENARIO.format(name="gated", model="myplanner:make", steps=8,
                                      extra="    Score: {MeanAtLeast: 0.0}\n"))
    args = ("-q", "-p", "no:randomly", "--driveeval-allow-scenario-code", "--driveeval-baseline", "baselines")
    result = cl.runpytest(*args, "--driveeval-baseline-update")
    result.assert_outcomes(passed=2)
    result.stdout.fnmatch_lines(["*no perturbation within the ranges broke it: * examples over 1 scene(s)*"])
    # each unroll initializes the planner with its rows: the gated item's, and each of the search's generations
    assert len(told(cl)) >= 2
    assert any((cl.path / "baselines").rglob("*gated*"))
    cl.runpytest(*args).assert_outcomes(passed=2)  # the same planner meets its own baseline


def test_pdm_closed_needs_no_opt_in(cl):
    cl.makefile(".scenario.yaml", pdm=SCENARIO.format(name="pdm", model="pdm_closed", steps=10, extra=""))
    cl.runpytest("-q", "-p", "no:randomly").assert_outcomes(passed=1)
