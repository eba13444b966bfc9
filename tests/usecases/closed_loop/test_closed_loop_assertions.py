"""Closed-loop helpers and per-scene verdicts on a hand-made unroll: messages name scene, frame, agent."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

import pytest_driveeval.usecases.closed_loop.assertions as cl_assertions
from pytest_driveeval import assert_collision_free, assert_drift_within
from pytest_driveeval.usecases.closed_loop.artefacts import chart_counts
from pytest_driveeval.usecases.closed_loop.config import ClosedLoopConditions
from pytest_driveeval.usecases.closed_loop.evaluate import Unroll, judge_scene

FRAMES = 10


def hand_made_unroll() -> Unroll:
    """Scene 7: an at-fault front hit at frame 3, a not-at-fault front hit at 5 and
    side hit at 6; 3 m of drift at frames 4-5; drift resets at frames 4 and 8."""
    kind, track, fault = np.zeros((1, FRAMES), np.int8), np.full((1, FRAMES), -1), np.zeros((1, FRAMES), bool)
    for frame, k, agent, at_fault in ((3, 1, 42, True), (5, 1, 9, False), (6, 2, 5, False)):
        kind[0, frame], track[0, frame], fault[0, frame] = k, agent, at_fault
    drift = np.zeros((1, FRAMES))
    drift[0, 4:6] = 3.0
    reset = np.zeros((1, FRAMES), bool)
    reset[0, [4, 8]] = True
    result = SimpleNamespace(
        scene_ids=np.array([7]), valid=np.ones((1, FRAMES), bool), collision_kind=kind, collision_track_id=track,
        collision_at_fault=fault, displacement_error=drift, distance_to_reference=drift.copy(),
        speed_difference=np.zeros((1, FRAMES)), reset=reset, errors=[None],
        driven_xy=np.zeros((1, FRAMES, 2)), driven_yaw=np.zeros((1, FRAMES)))
    return Unroll(result, log=None, drift_threshold=10.0, step_time=0.1)


def test_collision_free_names_scene_frame_kind_and_agent():
    unroll = hand_made_unroll()
    with pytest.raises(AssertionError) as failed:
        assert_collision_free(unroll)
    assert str(failed.value) == ("front/side/rear collisions in 1 scene(s):\n"
                                 "  scene 7: 3 collision frame(s); first at frame 3: front with agent 42")
    with pytest.raises(AssertionError, match=r"^side collisions in 1 scene\(s\):\n  scene 7: 1 collision frame\(s\); "
                                             r"first at frame 6: side with agent 5 \(not at fault\)$"):
        assert_collision_free(unroll, kinds=("side",))
    assert_collision_free(unroll, kinds=("side", "rear"), at_fault_only=True)
    with pytest.raises(AssertionError, match=r"^at-fault front collisions"):
        assert_collision_free(unroll, kinds=("front",), at_fault_only=True)


def test_drift_within_names_the_frames_and_tolerates_short_excursions():
    unroll = hand_made_unroll()
    expected = (r"^scene 7: displacement should be <= 2 m but is not at 2 of 10 frame\(s\): "
                r"frame 4 \(3 m\), frame 5 \(3 m\); worst at frame 4: 3 m$")
    with pytest.raises(AssertionError, match=expected):
        assert_drift_within(unroll, meters=2.0)
    assert_drift_within(unroll, meters=2.0, seconds=0.2)
    assert_drift_within(unroll, meters=3.0)


def test_judge_scene_counts_collisions_and_resets_against_what_is_allowed():
    conditions = ClosedLoopConditions.model_validate(
        {"Collisions": {"Front": 1, "Side": 0, "Rear": 0}, "Displacement": {"Max": 2.0, "Duration": 0.2},
         "MaxResets": 1})
    verdict = judge_scene(hand_made_unroll(), 0, conditions)
    assert not verdict.passed
    assert [f.message for f in verdict.findings] == [
        "scene 7: 2 front collision frame(s), 1 allowed; first at frame 3 with agent 42",
        "scene 7: 1 side collision frame(s), 0 allowed; first at frame 6 with agent 5 (not at fault)",
        "scene 7: 2 reset(s) on drift, 1 allowed; first at frame 4",
    ]
    resets = verdict.findings[-1]
    assert (resets.figure, resets.value, resets.limit, resets.frame, resets.scene) == ("drift_resets", 2, 1, 4, 7)
    assert resets.keypath == ("Evaluation", "Conditions", "MaxResets")
    front = verdict.findings[0]
    assert (front.figure, front.value, front.limit, front.frame) == ("front", 2, 1, 3)
    assert front.keypath == ("Evaluation", "Conditions", "Collisions", "Front")
    assert verdict.figures["front"] == 2 and verdict.figures["at_fault"] == 1
    assert verdict.figures["drift_resets"] == 2 and "displacement_error" not in verdict.figures
    assert chart_counts(verdict.figures) == {"front": 2, "side": 1, "rear": 0, "drift resets": 2}


def test_judge_scene_passes_within_the_limits():
    conditions = ClosedLoopConditions.model_validate(
        {"Collisions": {"Front": 1, "AtFaultOnly": True}, "Displacement": {"Max": 3.0}, "MaxResets": 2})
    verdict = judge_scene(hand_made_unroll(), 0, conditions)
    assert verdict.passed and verdict.findings == []


def test_helpers_module_is_rewritten_by_pytest():
    assert type(cl_assertions.__loader__).__name__ == "AssertionRewritingHook"


def test_failure_traceback_stops_at_the_test_not_inside_the_helper(pytester):
    pytester.makepyfile(test_drift='''
        from types import SimpleNamespace

        import numpy as np

        from pytest_driveeval import assert_drift_within
        from pytest_driveeval.closed_loop import Unroll

        def test_drift():
            result = SimpleNamespace(scene_ids=[3], valid=np.ones((1, 3), bool),
                                     displacement_error=np.array([[0.1, 0.2, 4.0]]))
            assert_drift_within(Unroll(result, None, 10.0, 0.1), meters=2.0)
        ''')
    result = pytester.runpytest("-q")
    result.assert_outcomes(failed=1)
    result.stdout.fnmatch_lines(["*AssertionError: scene 3: displacement should be <= 2 m*frame 2 (4 m)*"])
    assert "assertions.py" not in result.stdout.str()


def test_a_collision_condition_on_one_agents_several_frames_says_the_score_counts_it_once():
    """The condition counts every frame in contact (the engine's blame); nuPlan's collision term counts an
    agent once: the finding says so, as the term's message says which later contacts it left out."""
    unroll = hand_made_unroll()
    unroll.result.collision_kind[0, 4], unroll.result.collision_track_id[0, 4] = 1, 42
    unroll.result.collision_at_fault[0, 4] = True
    conditions = ClosedLoopConditions.model_validate({"Collisions": {"Front": 0, "AtFaultOnly": True}})
    (finding,) = judge_scene(unroll, 0, conditions, score=False).findings
    assert finding.message == (
        "scene 7: 2 at-fault front collision frame(s), 0 allowed; first at frame 3 with agent 42; every frame in "
        "contact counts here, by the engine's blame (the score's no_ego_at_fault_collisions counts each agent "
        "once, by nuPlan's rules)")
