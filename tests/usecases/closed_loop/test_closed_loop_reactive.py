"""``Unroll.Agents: log | reactive`` in the closed_loop YAML: what it accepts, where a mistake is, what it does."""
from __future__ import annotations

import json
import shutil

import pytest

import closed_loop_yaml
from conftest import REPO_ROOT


def load(tmp_path, agents):
    return closed_loop_yaml.load(tmp_path, "  Unroll:\n" + agents).config.Unroll.Agents


def problems(tmp_path, agents) -> list[str]:
    return closed_loop_yaml.problems(tmp_path, "  Unroll:\n" + agents)


def test_the_default_and_log_replay_the_log(tmp_path):
    assert load(tmp_path, "    StartFrame: 0\n").reactive() is None
    assert load(tmp_path, "    Agents: log\n").reactive() is None
    assert load(tmp_path, "    Agents: {Mode: log, Labels: [CAR]}\n").reactive() is None


def test_reactive_shorthand_takes_the_policy_benchmarks_idm(tmp_path):
    pytest.importorskip("torch")
    from pytest_driveeval.sim.agents import TrafficModel

    spec = load(tmp_path, "    Agents: reactive\n")
    assert spec.Mode == "reactive" and spec.Labels is None
    assert spec.reactive().idm == TrafficModel()


def test_reactive_mapping_sets_the_idm(tmp_path):
    pytest.importorskip("torch")
    spec = load(tmp_path, "    Agents: {Mode: reactive, Labels: [CAR], TimeHeadway: 1.0, MinGap: 3.0, "
                          "ComfortAccel: 2.0, ComfortDecel: 4.0, MaxBrake: 9.0, Delta: 3.0, Corridor: 1.2}\n")
    reactive = spec.reactive()
    idm = reactive.idm
    assert (idm.time_headway, idm.min_gap, idm.max_accel, idm.comfort_decel, idm.max_brake, idm.delta) == \
        (1.0, 3.0, 2.0, 4.0, 9.0, 3.0)
    assert reactive.corridor == 1.2 and spec.Labels == ["CAR"]


@pytest.mark.parametrize("agents, expected", [
    ("    Agents: reactiv\n", "k:8: Evaluation.Unroll.Agents: expected log, reactive or a mapping; found 'reactiv'"),
    ("    Agents: {Mode: replay}\n", "k:8: Evaluation.Unroll.Agents.Mode: expected 'log' or 'reactive'; found 'replay'"),
    ("    Agents: {TimeHeadway: 2.0}\n",
     "k:8: Evaluation.Unroll.Agents: TimeHeadway applies to Mode: reactive; give Mode: reactive too"),
    ("    Agents:\n      Mode: reactive\n      MinGap: -1\n",
     "k:10: Evaluation.Unroll.Agents.MinGap: expected greater than 0; found -1"),
    ("    Agents: {Mode: reactive, ComfortDecel: 9.0}\n",
     "k:8: Evaluation.Unroll.Agents: MaxBrake (8) must be >= ComfortDecel (9)"),
])
def test_mistakes_are_located(tmp_path, agents, expected):
    found = problems(tmp_path, agents)
    assert len(found) == 1 and found[0].startswith(expected), found


SCENE = """\
ScenarioFormatVersion: 3.0.0
ScenarioName: {name}
Evaluation:
  UseCaseName: closed_loop
  UseCaseFormatVersion: 0.1.0
  Datasets:
    - logs: {{Path: gen.zarr}}
  Model: constant_velocity
  Unroll:
    Scenes: [1]
    StartFrame: 10
    Agents: {agents}
  Conditions:
    Collisions: {{Front: 1000, Side: 1000, Rear: 0}}
  Artefacts: {{Animations: all}}
"""


def test_a_scenario_with_reactive_agents(pytester):
    """Generated scene 1: constant velocity stops short, and the logged car behind drives into it;
    reactive, that car brakes and no rear collision is left."""
    pytest.importorskip("torch")
    shutil.copytree(REPO_ROOT / "fixtures" / "l5kit" / "generated.zarr", pytester.path / "gen.zarr")
    pytester.makefile(".scenario.yaml", replayed=SCENE.format(name="replayed", agents="log"),
                      reactive=SCENE.format(name="reactive", agents="reactive"))
    pytester.runpytest("-q").assert_outcomes(passed=1, failed=1)
    results = json.loads((pytester.path / "driveeval-results" / "summary.json").read_text())["results"]
    by_name = {("reactive" if "reactive" in r["nodeid"] else "replayed"): r for r in results}
    assert by_name["replayed"]["figures"]["rear"] > 0
    assert by_name["reactive"]["figures"]["rear"] == 0
    assert "scene_1_gif" in by_name["reactive"]["artefacts"]
