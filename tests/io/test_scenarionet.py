"""ScenarioNet scenario files: the six real nuScenes-mini scenes, and each kind of bad input named
with the file, the scenario id and the object or feature."""
import pickle

import numpy as np
import pytest

from pytest_driveeval.core.errors import DataError
from pytest_driveeval.io.scenarionet.safe_pickle import UnsafePickleError
from pytest_driveeval.io.scenarionet.scenarionet import (ScenarioNetError, feature_group, read_scenario, scenario_files)

from scenarionet_made import SPLICE, deep_list, scenario, write, write_crafted

# a fast reader / score / report check: CI runs these at the lowest declared versions (-m smoke)
pytestmark = pytest.mark.smoke


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
    # Waymo writes UNKNOWN for a road line or a road edge of unknown type; MetaDrive takes it as an edge
    assert feature_group("UNKNOWN") == "road_edge" and feature_group("UNKNOWN_LINE") == "road_line"


def test_a_made_scenario_reads_with_its_lights_and_point_features(tmp_path):
    scene = read_scenario(write(tmp_path, scenario()))
    assert scene.tracks.types == ["VEHICLE", "VEHICLE", "TRAFFIC_CONE"] and scene.sdc == 0
    stop = next(f for f in scene.map_features if f.id == "stop")
    assert stop.group == "point" and stop.position.tolist() == [5.0, 2.0, 0.0]
    assert scene.lights[0].lane == "lane_1" and scene.lights[0].states == ["LANE_STATE_GO"] * 4


@pytest.mark.parametrize("change, message", [
    ({"metadata__sdc_id": "nobody"}, r"scenario s1\): the self-driving car's track \(metadata.sdc_id 'nobody'\)"),
    ({"tracks__car__state__heading": np.zeros(3)}, r"scenario s1\), track car: the scenario has 4 steps, but heading 3"),
    ({"tracks__car__state__position": np.full((4, 3), np.nan)}, r"track car: NaN or infinite .* at a valid step"),
    ({"dynamic_map_states__tl__state": {"object_state": ["LANE_STATE_GO"]}}, r"traffic light tl: 1 states for 4 steps"),
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


@pytest.mark.parametrize("change, message", [
    ({"id": ["s1"]}, r"sd_test.pkl: id is a list of 1 item\(s\), not text"),
    ({"metadata__sdc_id": ["ego"]}, r"\(scenario s1\): metadata.sdc_id is a list of 1 item\(s\), not text"),
    ({"tracks__car__type": ["VEHICLE"]}, r"track car: type is a list of 1 item\(s\), not text"),
    ({"dynamic_map_states__tl__state__object_state": [["GO"]] * 4},
     r"traffic light tl: its state at step 0 is a list of 1 item\(s\), not text"),
    ({"map_features": []}, r"\(scenario s1\): map_features is a list of 0 item\(s\); ScenarioNet gives a mapping "
                           r"of id -> map feature"),
    ({"dynamic_map_states": [{"lane": "lane_1"}]}, r"dynamic_map_states is a list of 1 item\(s\); ScenarioNet gives a "
                                                   r"mapping"),
    ({"length": "4"}, r"\(scenario s1\): length is str '4', not a whole number of steps"),
    ({"metadata__ts": np.array([0.0, 0.1, np.nan, 0.3])}, r"metadata.ts is NaN or infinite at step 2: each step"),
    ({"metadata__ts": np.array([0.0, 0.1, 0.1, 0.3])}, r"metadata.ts does not increase at step 2"),
    ({"tracks__car__state__length": np.array([4.5, np.nan, 4.5, 4.5])},
     r"track car: state.length is nan at valid step 1; a size in metres >= 0 is needed"),
])
def test_a_value_of_the_wrong_kind_is_named_with_its_key(tmp_path, change, message):
    with pytest.raises(ScenarioNetError, match=message):
        read_scenario(write(tmp_path, scenario(**change)))


def test_a_scenario_of_0_steps_or_of_30_million_is_refused_before_anything_per_step_is_made(tmp_path):
    with pytest.raises(ScenarioNetError, match=r"\(scenario s1\): length is 0 steps: a scenario has at least one"):
        read_scenario(write(tmp_path, scenario(steps=0)))
    # 2 KB declaring 3e7 steps: refused from the number, before the 4.7 GB its tracks would take
    data = scenario(length=30_000_000)
    with pytest.raises(ScenarioNetError, match=r"length is 30000000 steps, more than the 36000 a scenario may have "
                                               r"\(an hour at 10 Hz\): cut the log"):
        read_scenario(write(tmp_path, data))
    # ... or from numpy.ndarray((3e7,)) called in the file, which would allocate what it asks
    ndarray = (pickle.BINUNICODE + b"\x05\0\0\0numpy" + pickle.BINUNICODE + b"\x07\0\0\0ndarray" + pickle.STACK_GLOBAL
               + pickle.BININT + (30_000_000).to_bytes(4, "little") + pickle.TUPLE1 + pickle.TUPLE1 + pickle.REDUCE)
    with pytest.raises(UnsafePickleError, match=r"numpy.ndarray\(...\) called directly: it would allocate what the "
                                                "file asks"):
        read_scenario(write_crafted(tmp_path, scenario(metadata__ts=SPLICE), ndarray))
    data = scenario(metadata__ts=np.zeros(40_000))
    data.pop("length")
    with pytest.raises(ScenarioNetError, match=r"metadata.ts's length is 40000 steps, more than the 36000"):
        read_scenario(write(tmp_path, data))


@pytest.mark.parametrize("key", ["id", "metadata__sdc_id", "tracks__car__type",
                                 "dynamic_map_states__tl__state__object_state"])
def test_a_100000_deep_list_anywhere_is_refused_with_its_key_not_a_recursion_error(tmp_path, key):
    path = write_crafted(tmp_path, scenario(**{key: SPLICE}), deep_list(100_000))
    where = key.replace("__", ".")
    with pytest.raises(UnsafePickleError, match=rf"sd_test.pkl is refused: at {where}(\[0\])+\.\.\. \(33 levels\) it "
                                                "nests more than 32 levels deep"):
        read_scenario(path)


def test_an_ordered_dict_whose_get_the_file_sets_is_refused(tmp_path):
    get = (pickle.SHORT_BINUNICODE + b"\x0bcollections" + pickle.SHORT_BINUNICODE + b"\x0bOrderedDict"
           + pickle.STACK_GLOBAL + pickle.EMPTY_TUPLE + pickle.REDUCE + pickle.EMPTY_DICT + pickle.SHORT_BINUNICODE
           + b"\x03get" + pickle.SHORT_BINUNICODE + b"\x08builtins" + pickle.SHORT_BINUNICODE + b"\x04dict"
           + pickle.STACK_GLOBAL + pickle.SETITEM + pickle.BUILD)
    path = write_crafted(tmp_path, scenario(metadata=SPLICE), get)
    with pytest.raises(UnsafePickleError, match=r"BUILD \(setting attributes\) on a OrderedDict"):
        read_scenario(path)


def test_a_scenario_with_only_the_ego_or_without_a_map_reads(tmp_path):
    alone = scenario()
    del alone["tracks"]["car"], alone["tracks"]["cone"]
    assert read_scenario(write(tmp_path, alone)).tracks.ids == ["ego"]
    bare = scenario(dynamic_map_states={})
    del bare["map_features"]
    assert read_scenario(write(tmp_path, bare)).map_features == []


def test_a_pkl_that_is_no_regular_file_is_listed_and_its_read_says_what_it_is(tmp_path):
    write(tmp_path, scenario(), "sd_a.pkl")
    (tmp_path / "sd_b.pkl").symlink_to("/dev/zero")
    files = scenario_files(tmp_path)
    assert [p.name for p in files] == ["sd_a.pkl", "sd_b.pkl"]
    with pytest.raises(DataError, match=r"sd_b.pkl \(a link to /dev/zero\) is a character device, not a regular file"):
        read_scenario(files[1])
    assert scenario_files(tmp_path / "sd_b.pkl") == [tmp_path / "sd_b.pkl"]
