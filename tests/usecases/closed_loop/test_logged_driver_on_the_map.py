"""The sanity gate of the drivable area built from the map itself: on every real scene in the shared
data, the logged driver (log replay, each whole scene) keeps to the drivable area and drives with its
lanes.  The exceptions, and why the data makes them, are listed here:

- the L5 sample (l5kit/single_scene.zarr) ships without its semantic map (l5kit's tests carry the zarr
  alone, no semantic_map.pb or meta.json): it has no map, so both terms are not available, said as such.
"""
from conftest import REPO_ROOT
from pytest_driveeval.closed_loop import score_unroll, unroll_scenes
from pytest_driveeval.io.l5.l5kit_zarr import L5Dataset
from pytest_driveeval.io.scenarionet.scenarionet_drivable import STAND_IN
from pytest_driveeval.usecases.closed_loop.baselines import baseline
from pytest_driveeval.usecases.closed_loop.config import ClosedLoopConfig
from pytest_driveeval.usecases.closed_loop.datasets import open_dataset
from pytest_driveeval.usecases.closed_loop.raster_inputs import load_semantic_map

TERMS = ("drivable_area_compliance", "driving_direction_compliance")


def logged(dataset, semantic_map=None):
    """Every scene of ``dataset`` replayed from its log, start to end."""
    return unroll_scenes(dataset, baseline("log_replay", ClosedLoopConfig(Model="log_replay")),
                         list(range(dataset.num_scenes)), semantic_map=semantic_map)


def test_the_logged_nuscenes_drivers_stay_on_the_maps_own_drivable_area(shared_data):
    dataset = open_dataset(shared_data / "scenarionet" / "nuscenes", None)
    unroll = logged(dataset)
    scores = score_unroll(unroll)
    assert sorted(scores) == list(range(6))
    for scene, score in scores.items():
        name = dataset.source(scene).path.name
        area = score.terms["drivable_area_compliance"]
        assert area.value == 1.0, (name, area.message)
        assert score.terms["driving_direction_compliance"].value == 1.0, (name, score.terms[TERMS[1]].message)
        # judged on nuScenes' own drivable_area outline, not on the lanes widened
        assert "drivable-area outline" in area.reason and f"{STAND_IN} (" not in area.reason, name
        assert unroll.result.valid[scene].sum() == dataset.scene(scene).frames.shape[0], name  # the whole scene


def test_the_l5_sample_has_no_map_and_says_so(shared_data):
    zarr = shared_data / "l5kit" / "single_scene.zarr"
    # the exception: l5kit ships this zarr without the semantic map that would give it a drivable area
    assert not (zarr.parent / "semantic_map.pb").exists()
    score = score_unroll(logged(L5Dataset.open(zarr)))[0]
    for name in TERMS:
        assert score.terms[name].value is None and score.terms[name].reason == "the scene has no map", name


def test_an_l5_zarr_scores_on_its_semantic_maps_lanes():
    zarr = REPO_ROOT / "fixtures" / "l5kit" / "generated.zarr"  # generated scenes with their semantic map
    dataset = L5Dataset.open(zarr)
    unroll = logged(dataset, load_semantic_map(zarr))
    scores = score_unroll(unroll)
    assert len(scores) == dataset.num_scenes
    for scene, score in scores.items():
        area = score.terms["drivable_area_compliance"]
        assert area.value == 1.0 and "L5 semantic map's lanes" in area.reason, scene
        assert score.terms["driving_direction_compliance"].value == 1.0, scene
    # and a drive off the lanes is seen: the first scene's log moved 30 m sideways
    unroll.result.driven_xy[0, :, 1] += 30.0
    unroll.ego_states = None  # made again from the moved poses
    score = score_unroll(unroll)[0]
    assert score.terms["drivable_area_compliance"].value == 0.0
    assert "off the drivable area" in score.terms["drivable_area_compliance"].message


def test_without_a_semantic_map_an_l5_scene_has_no_map_terms():
    dataset = L5Dataset.open(REPO_ROOT / "fixtures" / "l5kit" / "generated.zarr")
    score = score_unroll(logged(dataset))[0]
    assert {n for n in TERMS if score.terms[n].value is None} == set(TERMS)
