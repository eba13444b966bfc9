"""The closed_loop YAML keys that set l5kit's options: what they accept, and where a mistake is."""
from __future__ import annotations

import pytest

from closed_loop_yaml import load, problems
from pytest_driveeval import load_scenario


def test_l5kit_setup_is_read(tmp_path):
    config = load(tmp_path, "  ConstantVelocity: {FirstStep: logged_next}\n"
                            "  Unroll:\n    Agents: {Labels: [CAR], WithinAtStart: 50.0}\n"
                            "  Conditions:\n    DistanceToReference: {Max: 4.0, Measure: l5kit}\n").config
    assert config.ConstantVelocity.FirstStep == "logged_next"
    assert (config.Unroll.Agents.Labels, config.Unroll.Agents.LabelThreshold,
            config.Unroll.Agents.WithinAtStart) == (["CAR"], 0.5, 50.0)
    assert config.Conditions.DistanceToReference.Measure == "l5kit"


def test_defaults_keep_todays_behaviour(tmp_path):
    config = load(tmp_path, "  Conditions:\n    DistanceToReference: {Max: 4.0}\n").config
    assert config.ConstantVelocity is None
    assert (config.Unroll.Agents.Labels, config.Unroll.Agents.WithinAtStart) == (None, None)
    assert config.Conditions.DistanceToReference.Measure == "polyline"


@pytest.mark.parametrize("extra, model, expected", [
    ("  Unroll:\n    Agents: {Labels: [LORRY]}\n", "constant_velocity",
     "k:8: Evaluation.Unroll.Agents.Labels: unknown perception label 'LORRY'; known: PERCEPTION_LABEL_NOT_SET"),
    ("  Unroll:\n    Agents: {LabelThreshold: 0.3}\n", "constant_velocity",
     "k:8: Evaluation.Unroll.Agents: LabelThreshold applies to Labels; give Labels too"),
    ("  Unroll:\n    Agents: {Labels: [CAR], LabelThreshold: 1.0}\n", "constant_velocity",
     "k:8: Evaluation.Unroll.Agents.LabelThreshold: expected less than 1; found 1.0"),
    ("  Unroll:\n    Agents: {WithinAtStart: -5}\n", "constant_velocity",
     "k:8: Evaluation.Unroll.Agents.WithinAtStart: expected greater than 0; found -5"),
    ("  Conditions:\n    DistanceToReference: {Max: 4.0, Measure: waypoints}\n", "constant_velocity",
     "k:8: Evaluation.Conditions.DistanceToReference.Measure: "),
    ("  ConstantVelocity: {FirstStep: logged}\n", "constant_velocity",
     "k:7: Evaluation.ConstantVelocity.FirstStep: "),
    ("  ConstantVelocity: {FirstStep: logged_next}\n", "log_replay",
     "k:7: Evaluation.ConstantVelocity: applies to Model: constant_velocity, not 'log_replay'"),
])
def test_mistakes_are_located(tmp_path, extra, model, expected):
    found = problems(tmp_path, extra, model)
    assert len(found) == 1 and found[0].startswith(expected), found


def test_the_demo_l5kit_scenario_uses_the_l5kit_setup():
    from conftest import REPO_ROOT

    config = load_scenario(REPO_ROOT / "scenario_tests" / "closed_loop" / "real_scene_l5kit.scenario.yaml").config
    assert (config.Model, config.ConstantVelocity.FirstStep) == ("constant_velocity", "logged_next")
    assert (config.Unroll.StartFrame, config.Unroll.DriftThreshold, config.Unroll.FreezeOnCollision) == (0, None, False)
    agents = config.Unroll.Agents
    assert (agents.Labels, agents.LabelThreshold, agents.WithinAtStart) == (["CAR"], 0.5, 50.0)
    assert config.Conditions.DistanceToReference.Measure == "l5kit"


@pytest.mark.parametrize("extra, expected", [
    ("  Perturbation:\n    Lateral: [-.inf, .inf]\n",
     "k:8: Evaluation.Perturbation.Lateral: a range of finite numbers is needed, got [-inf, inf]"),
    ("  Perturbation:\n    SpeedScale: [0.9, .nan]\n",
     "k:8: Evaluation.Perturbation.SpeedScale: a range of finite numbers is needed, got [0.9, nan]"),
    ("  Perturbation:\n    Lateral: [-1, 1]\n    Replay: {Scene: 0, Lateral: 1.5}\n",
     "k:9: Evaluation.Perturbation.Replay.Lateral: outside the scenario's range Lateral: [-1, 1]; got 1.5"),
    ("  Perturbation:\n    Lateral: [-1, 1]\n    Replay: {Scene: 0, SpeedScale: -1}\n",
     "k:9: Evaluation.Perturbation.Replay.SpeedScale: a speed scale must stay above 0; got -1.0"),
    ("  Perturbation:\n    Lateral: [-1, 1]\n    Replay: {Scene: .nan}\n",
     "k:9: Evaluation.Perturbation.Replay.Scene: expected a finite number; found nan (float)"),
    ("  Unroll:\n    DriftThreshold: .inf\n",
     "k:8: Evaluation.Unroll.DriftThreshold: expected a finite number; found inf (float)"),
    ("  Unroll:\n    Agents: {Mode: reactive, TimeHeadway: .nan}\n",
     "k:8: Evaluation.Unroll.Agents.TimeHeadway: expected a finite number; found nan (float)"),
    ("  Unroll:\n    Inputs: {Kind: raster, PixelSize: [.inf, 0.5]}\n",
     "k:8: Evaluation.Unroll.Inputs.PixelSize[0]: expected a finite number; found inf (float)"),
    ("  Conditions:\n    Displacement: {Max: .nan}\n",
     "k:8: Evaluation.Conditions.Displacement.Max: expected a finite number; found nan (float)"),
    ("  Conditions:\n    ScenePassRate: .nan\n",
     "k:8: Evaluation.Conditions.ScenePassRate: expected a finite number; found nan (float)"),
    ("  Executor: {Kind: ray, NumCpus: .inf}\n",
     "k:7: Evaluation.Executor.NumCpus: expected a finite number; found inf (float)"),
])
def test_a_number_that_is_not_finite_is_located_wherever_it_is_declared(tmp_path, extra, expected):
    """``.inf`` and ``.nan`` are valid YAML floats; taken, they surface deep in an unroll."""
    found = problems(tmp_path, extra)
    assert len(found) == 1 and found[0].startswith(expected), found


def test_the_demo_reactive_scenario_is_its_log_replay_twin():
    """The demo shows reactive agents beside log replay; the comparison means something only
    while the two files differ in ``Unroll.Agents.Mode`` alone."""
    from conftest import REPO_ROOT

    demo = REPO_ROOT / "scenario_tests" / "closed_loop"
    log, reactive = (load_scenario(demo / name) for name in ("real_scene.scenario.yaml",
                                                            "real_scene_reactive.scenario.yaml"))
    assert (log.config.Unroll.Agents.Mode, reactive.config.Unroll.Agents.Mode) == ("log", "reactive")
    apart_from_mode = {"Unroll": {"Agents": {"Mode"}}}
    assert reactive.config.model_dump(exclude=apart_from_mode) == log.config.model_dump(exclude=apart_from_mode)
    assert [(d.name, d.path) for d in reactive.datasets] == [(d.name, d.path) for d in log.datasets]
    assert (reactive.marks, reactive.xfail, reactive.skip) == (log.marks, log.xfail, log.skip)
