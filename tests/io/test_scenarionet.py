"""ScenarioNet scenario files: the six real nuScenes-mini scenes, and each kind of bad input named
with the file, the scenario id and the object or feature."""
import pickle

import numpy as np
import pytest

from pytest_driveeval.io.scenarionet.safe_pickle import UnsafePickleError
from pytest_driveeval.io.scenarionet.scenarionet import (ScenarioNetError, feature_group, read_scenario, scenario_files)

from scenarionet_made import scenario, write


@pytest.fixture
def nuscenes(shared_data):
    return shared_data / "scenarionet" / "nuscenes"


def test_the_real_nuscenes_scenes_read_into_aligned_arrays(nuscenes):
    files = scenario_files(nuscenes)
    assert len(files) == 6
    for path in files:
        scene = read_scenario(path)
        raw = pickle.loads(path.read_bytes())  # trusted here: the test compares the two readings
        tracks = scene.tracks
        assert scene.id == raw["id"] and scene.steps == raw["length"] and scene.sample_rate == pytest.approx(0.1)
        assert tracks.position.shape == (len(raw["tracks"]), scene.steps, 3)
        assert tracks.ids[scene.sdc] == raw["metadata"]["sdc_id"] and tracks.types[scene.sdc] == "VEHICLE"
        some = tracks.ids[len(tracks.ids) // 2]
        state = raw["tracks"][some]["state"]
        row = tracks.ids.index(some)
        assert np.array_equal(tracks.position[row], state["position"])
        assert np.array_equal(tracks.valid[row], state["valid"] > 0)
        assert np.array_equal(tracks.size[row, :, 0], state["length"].reshape(-1))
        lanes = [f for f in scene.map_features if f.group == "lane"]
        assert lanes and all(f.polyline is not None for f in lanes) and any(f.polygon is not None for f in lanes)
        # nuScenes gives most lanes no speed limit: kept as None ("not available"), never a made-up number
        assert [f.speed_limit_kmh for f in lanes] == [raw["map_features"][f.id].get("speed_limit_kmh") for f in lanes]
        assert len(scene.map_features) == len(raw["map_features"])


def test_every_documented_feature_type_has_its_group():
    assert feature_group("LANE_FREEWAY") == "lane" and feature_group("ROAD_LINE_PASSING_DOUBLE_YELLOW") == "road_line"
    assert feature_group("ROAD_EDGE_SIDEWALK") == "road_edge" and feature_group("CROSSWALK") == "area"
    assert feature_group("STOP_SIGN") == "point" and feature_group("SOMETHING_NEW") == "other"


def test_a_made_scenario_reads_with_its_lights_and_point_features(tmp_path):
    scene = read_scenario(write(tmp_path, scenario()))
    assert scene.tracks.types == ["VEHICLE", "VEHICLE", "TRAFFIC_CONE"] and scene.sdc == 0
    stop = next(f for f in scene.map_features if f.id == "stop")
    assert stop.group == "point" and stop.position.tolist() == [5.0, 2.0, 0.0]
    assert scene.lights[0].lane == "lane_1" and scene.lights[0].states == ["LANE_STATE_GO"] * 4


@pytest.mark.parametrize("change, message", [
    ({"metadata__sdc_id": "nobody"}, r"scenario s1\): the self-driving car's track \(metadata.sdc_id 'nobody'\)"),
    ({"tracks__car__state__heading": np.zeros(3)}, r"scenario s1\), track car: the scenario has 4 steps, but heading 3"),
    ({"map_features__lane_1__polyline": np.array([[0.0, 0.0]])}, r"map feature lane_1: its polyline has 1 point"),
    ({"map_features__walk__polygon": np.array([[0.0, np.nan], [1, 1], [2, 2]])},
     r"map feature walk: its polygon holds NaN"),
    ({"tracks__car__state__position": np.full((4, 3), np.nan)}, r"track car: NaN or infinite .* at a valid step"),
    ({"dynamic_map_states__tl__state": {"object_state": ["LANE_STATE_GO"]}}, r"traffic light tl: 1 states for 4 steps"),
    ({"map_features__lane_1": {"type": "LANE_SURFACE_STREET"}}, r"map feature lane_1: a LANE_SURFACE_STREET without"),
])
def test_bad_input_names_the_file_the_scenario_and_the_object(tmp_path, change, message):
    with pytest.raises(ScenarioNetError, match=r"sd_test.pkl \(scenario s1.*" if "sdc" in message else message):
        read_scenario(write(tmp_path, scenario(**change)))
    with pytest.raises(ScenarioNetError, match=message):
        read_scenario(write(tmp_path, scenario(**change)))


def test_a_pickle_of_something_else_or_with_code_is_refused(tmp_path):
    with pytest.raises(ScenarioNetError, match="not a ScenarioNet scenario"):
        read_scenario(write(tmp_path, [1, 2, 3]))
    evil = tmp_path / "sd_evil.pkl"
    evil.write_bytes(pickle.dumps({"tracks": {}, "x": print}, protocol=4))
    with pytest.raises(UnsafePickleError, match="sd_evil.pkl asks for builtins.print"):
        read_scenario(evil)


def test_a_folder_lists_its_scenarios_without_the_summaries(tmp_path):
    write(tmp_path, scenario(), "sd_b.pkl")
    write(tmp_path, scenario(), "sd_a.pkl")
    write(tmp_path, {"sd_a.pkl": {}}, "dataset_summary.pkl")
    assert [p.name for p in scenario_files(tmp_path)] == ["sd_a.pkl", "sd_b.pkl"]
    (tmp_path / "empty").mkdir()
    with pytest.raises(ScenarioNetError, match="a folder without scenario files"):
        scenario_files(tmp_path / "empty")
