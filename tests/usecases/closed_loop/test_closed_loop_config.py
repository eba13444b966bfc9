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
