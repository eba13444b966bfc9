"""nuPlan's score in the closed loop: per scene and per item, on the real nuScenes scenes' maps, from
Python (score_unroll and the assertion helpers) and from a scenario's Conditions.Score."""
import json

import pytest

from conftest import REPO_ROOT
import pytest_driveeval as de
from pytest_driveeval.closed_loop import score_unroll, unroll_scenes
from pytest_driveeval.usecases.closed_loop.baselines import baseline
from pytest_driveeval.usecases.closed_loop.config import ClosedLoopConfig
from pytest_driveeval.usecases.closed_loop.datasets import open_dataset


@pytest.fixture(scope="module")
def nuscenes(shared_data):
    return open_dataset(shared_data / "scenarionet" / "nuscenes", None)


def unrolled(dataset, policy, scenes):
    return unroll_scenes(dataset, baseline(policy, ClosedLoopConfig(Model=policy)), scenes, start_frame=10, steps=80)


def test_the_logged_drive_stays_on_the_map_and_in_the_lane_direction(nuscenes):
    scores = score_unroll(unrolled(nuscenes, "log_replay", list(range(6))))
    assert sorted(scores) == list(range(6))
    for scene, score in scores.items():
        assert score.terms["drivable_area_compliance"].value == 1.0, scene
        assert score.terms["driving_direction_compliance"].value == 1.0, scene
        assert score.terms["no_ego_at_fault_collisions"].value == 1.0, scene
        assert score.terms["ego_progress_along_expert_route"].value == pytest.approx(1.0), scene
        # nuScenes lanes carry no speed limit: said, not silently 1
        limit = score.terms["speed_limit_compliance"]
        assert limit.value is None and limit.used == 1.0 and "no speed limit" in limit.reason
        assert 0.0 <= score.score <= 1.0


def test_constant_velocity_leaves_the_road_and_the_helpers_say_where(nuscenes):
    unroll = unrolled(nuscenes, "constant_velocity", [0])
    score = score_unroll(unroll)[0]
    area = score.terms["drivable_area_compliance"]
    assert area.value == 0.0 and score.score == 0.0
    first = int(unroll.result.valid[0].nonzero()[0][area.frames[0]])
    with pytest.raises(AssertionError, match=rf"drivable_area_compliance below 1 in 1 scene\(s\):\n  scene 0 \(scenario scene-0061, [^)]*\): 0.000 "
                                             rf"\(a corner .* m off the drivable area at frame {first} "):
        de.assert_drivable_area_compliant(unroll)
    with pytest.raises(AssertionError, match="(?s)nuPlan score below 0.5 in 1 scene.*scene 0 \\(scenario scene-0061, [^)]*\\): score 0.000: .*"
                                             "drivable_area_compliance 0"):
        de.assert_score_at_least(unroll, 0.5)
    with pytest.raises(AssertionError, match="(?s)speed_limit_compliance below 1 .* not available .*no speed limit"):
        de.assert_speed_limit_compliant(unroll)
    de.assert_making_progress(unroll)  # it does drive on


def _plain(score) -> dict:
    return {"score": score.score} | {name: {**vars(term), "series": {k: list(v) for k, v in term.series.items()}}
                                     for name, term in score.terms.items()}


def test_a_scene_scores_the_same_alone_as_among_the_unrolls_other_scenes(nuscenes):
    from pytest_driveeval.usecases.closed_loop.score import scene_score

    unroll = unrolled(nuscenes, "constant_velocity", list(range(6)))
    together = score_unroll(unroll)  # the ego states and comfort signals of all six made at once
    assert unroll.ego_states is not None and len(unroll.ego_states) == 6
    for row, scene in enumerate(unroll.scene_ids):
        unroll.ego_states = {}  # none made for the batch: the scene's own, alone
        assert _plain(scene_score(unroll, row)) == _plain(together[scene]), scene


def test_a_scene_without_a_map_scores_without_the_map_terms():
    from pytest_driveeval.io.l5.l5kit_zarr import L5Dataset

    dataset = L5Dataset.open(REPO_ROOT / "fixtures" / "l5kit" / "generated.zarr")
    score = score_unroll(unrolled(dataset, "log_replay", [0]))[0]
    assert set(score.not_available()) == {"drivable_area_compliance", "driving_direction_compliance",
                                          "speed_limit_compliance"}
    assert score.terms["ego_progress_along_expert_route"].value == pytest.approx(1.0)


SCENARIO = """\
ScenarioFormatVersion: 3.0.0
ScenarioName: {name}
Evaluation:
  UseCaseName: closed_loop
  UseCaseFormatVersion: 0.1.0
  Datasets:
    - nuscenes_mini: {{Path: {data}}}
  Model: {model}
  Unroll: {{Scenes: [0, 4], StartFrame: 10, Steps: 80}}
  Conditions:
    Score: {score}
"""


def test_conditions_score_fails_the_scenes_below_it_and_reports_every_term(pytester, shared_data):
    data = shared_data / "scenarionet" / "nuscenes"
    pytester.makefile(".scenario.yaml",
                      logged=SCENARIO.format(name="logged", data=data, model="log_replay",
                                             score="{AtLeast: 0.5, Terms: {drivable_area_compliance: 1}}"),
                      straight=SCENARIO.format(name="straight", data=data, model="constant_velocity",
                                               score="{MeanAtLeast: 0.5, Terms: {drivable_area_compliance: 1}}"))
    pytester.runpytest("-p", "no:randomly")
    results = json.loads((pytester.path / "driveeval-results" / "summary.json").read_text())["results"]
    logged, straight = sorted(results, key=lambda r: r["scenario"])
    assert logged["verdict"] == "passed" and logged["figures"]["drivable_area_compliance"] == 1.0
    assert "nuPlan score" in logged["summary"]
    assert straight["verdict"] == "failed"
    scenes = {s["scene"]: s for s in straight["details"]["scenes"]}
    assert straight["figures"]["score"] == pytest.approx((scenes[0]["score"] + scenes[4]["score"]) / 2)
    for scene, record in scenes.items():
        terms = record["score_terms"]
        assert terms["speed_limit_compliance"]["value"] is None and "no speed limit" in terms["speed_limit_compliance"]["reason"]
        area = terms["drivable_area_compliance"]
        if area["value"] == 0.0:
            finding = next(f for f in straight["findings"] if f.get("figure") == "drivable_area_compliance"
                           and f.get("scene") == scene)
            assert finding["frame"] == area["frames"][0]  # the finding's frame is the reports' frame
            assert f"at frame {area['frames'][0]}" in finding["message"]
    mean = next(f for f in straight["findings"] if f.get("figure") == "score")
    assert mean["limit"] == 0.5 and mean["keypath"][-1] == "MeanAtLeast"
    markdown = (pytester.path / "driveeval-results" / "summary.md").read_text()
    section = markdown.split(f"#### nuPlan score per scene: `{straight['nodeid']}`")[1]
    # each row names its scene by index and file (the scene's identity)
    assert "| 0 (scenario scene-0061, " in section and "| 4 (scenario " in section and "n/a" in section
    assert "speed limit: no speed limit in the map (ScenarioNet's nuScenes lanes carry a placeholder" in section


def test_a_misspelt_term_is_an_error_at_its_line(pytester, shared_data):
    data = shared_data / "scenarionet" / "nuscenes"
    pytester.makefile(".scenario.yaml", typo=SCENARIO.format(name="typo", data=data, model="log_replay",
                                                             score="{Terms: {drivable_area_complience: 1}}"))
    result = pytester.runpytest("-p", "no:randomly")
    result.stdout.fnmatch_lines(["*did you mean drivable_area_compliance*"])
    assert result.ret != 0


def test_the_gif_markers_start_each_run_of_failing_frames(nuscenes):
    from pytest_driveeval.closed_loop import judge_scene
    from pytest_driveeval.usecases.closed_loop.config import ClosedLoopConditions

    unroll = unrolled(nuscenes, "constant_velocity", [0])
    verdict = judge_scene(unroll, 0, ClosedLoopConditions())
    area = verdict.score_terms["drivable_area_compliance"]["frames"]
    marked = [frame for frame, _, _, kind in verdict.markers if kind == "off_drivable_area"]
    starts = [f for i, f in enumerate(area) if i == 0 or area[i - 1] != f - 1]
    assert marked == starts and marked[0] == area[0]


def test_the_collision_term_follows_nuplans_blame_unless_the_engines_is_asked_for(nuscenes):
    """Constant velocity grazes an agent in scene 1 with its front bumper: nuPlan's rules blame the ego
    (ACTIVE_FRONT), the engine's excuse it (the agent closed faster).  Score.Blame: engine keeps the engine's."""
    from pytest_driveeval.closed_loop import judge_scene
    from pytest_driveeval.usecases.closed_loop.config import ClosedLoopConditions

    unroll = unrolled(nuscenes, "constant_velocity", [1])
    nuplan = judge_scene(unroll, 0, ClosedLoopConditions.model_validate({"Score": {}}))
    engine = judge_scene(unroll, 0, ClosedLoopConditions.model_validate({"Score": {"Blame": "engine"}}))
    assert nuplan.score_terms["no_ego_at_fault_collisions"]["value"] == 0.0
    assert "by nuPlan's rules" in nuplan.score_terms["no_ego_at_fault_collisions"]["message"]
    assert "active front" in nuplan.score_terms["no_ego_at_fault_collisions"]["message"]
    assert engine.score_terms["no_ego_at_fault_collisions"]["value"] == 1.0
    assert "by the engine's rules" in engine.score_terms["no_ego_at_fault_collisions"]["message"]
    with pytest.raises(ValueError, match="Blame"):
        ClosedLoopConditions.model_validate({"Score": {"Blame": "mine"}})
