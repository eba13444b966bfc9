"""ScenarioNet files as the datasets' converters write them: one test per quirk, each scene made in
ScenarioNet's layout (MetaDrive's scenario description, as scenarionet/converter/* writes it), written
to a file and read through the safe reader; and every real file in the shared data."""
import numpy as np
import pytest

from pytest_driveeval.io.l5.l5kit_zarr import label_index
from pytest_driveeval.io.scenarionet.scenarionet import ScenarioNetError, Skipped, read_scenario, scenario_files
from pytest_driveeval.io.scenarionet.scenarionet_l5 import ScenarioNetDataset, l5_scene
from pytest_driveeval.io.scenarionet.scenarionet_map import active_faces, scenario_map

from scenarionet_made import scenario, write


def read(tmp_path, data):
    return read_scenario(write(tmp_path, data))


def skipped_of(scene, fid):
    return [s for s in scene.skipped if s.id == fid]


def test_waymos_one_point_lanes_are_skipped_listed_and_the_scene_drives(tmp_path):
    # Waymo's map writes a lane's centre line as float32 (x, y, z); a real scene has five one-point ones
    data = scenario(steps=5)
    for fid in ("204", "205", "206", "207", "208"):
        data["map_features"][fid] = {"type": "LANE_SURFACE_STREET", "polyline": np.array([[3.0, 4.0, 0.1]], np.float32),
                                     "speed_limit_kmh": 40.2, "entry_lanes": [], "exit_lanes": []}
    scene = read(tmp_path, data)
    assert {f.id for f in scene.map_features} == {"lane_1", "stop", "walk"}
    assert skipped_of(scene, "204") == [Skipped("204", "LANE_SURFACE_STREET",
                                                "not read: its polyline has 1 point(s); a line needs 2")]
    assert str(scene.skipped[0]) == ("map feature 204 (LANE_SURFACE_STREET): not read: its polyline has 1 point(s); "
                                     "a line needs 2")
    assert len(scene.skipped) == 5
    assert l5_scene(scene).num_frames == 5 and list(scenario_map(scene).semantic.lane_ids) == ["lane_1"]


def test_a_zero_length_line_is_skipped(tmp_path):
    scene = read(tmp_path, scenario(map_features__line={"type": "ROAD_LINE_SOLID_SINGLE_WHITE",
                                                        "polyline": np.array([[1.0, 1.0], [1.0, 1.0], [1.0, 1.0]])}))
    assert "line" not in {f.id for f in scene.map_features}
    assert skipped_of(scene, "line")[0].reason == "not read: its polyline has zero length (its 3 points coincide)"


def test_argoverse_2s_last_one_point_piece_of_the_drivable_outline_is_skipped(tmp_path):
    # the Argoverse 2 converter cuts the drivable area's outline into pieces of 20 points
    outline = np.stack([np.arange(41.0), np.zeros(41)], axis=1)
    pieces = {f"boundary_0{i}": {"type": "ROAD_LINE_SOLID_SINGLE_WHITE", "polyline": outline[i:i + 20]}
              for i in range(0, 41, 20)}
    scene = read(tmp_path, scenario(map_features={**scenario()["map_features"], **pieces}))
    assert {f.id for f in scene.map_features} >= {"boundary_00", "boundary_020"}
    assert [s.id for s in scene.skipped] == ["boundary_040"]


@pytest.mark.parametrize("polygon, why", [
    (np.zeros((0, 3), np.float32), "its polygon is empty"),
    (np.array([[0.0, 0.0], [1.0, 1.0]]), "its polygon has 2 point(s); a surface needs 3"),
    (np.array([[2.0, 2.0], [2.0, 2.0], [2.0, 2.0]]), "its polygon is one point (its 3 points coincide)"),
    (np.array([[0.0, np.nan], [1, 1], [2, 0]]), "its polygon holds NaN or infinite coordinates"),
])
def test_an_empty_or_degenerate_polygon_is_skipped(tmp_path, polygon, why):
    scene = read(tmp_path, scenario(map_features__walk__polygon=polygon))
    assert "walk" not in {f.id for f in scene.map_features}
    assert skipped_of(scene, "walk") == [Skipped("walk", "CROSSWALK", f"not read: {why}")]


def test_a_lane_with_one_usable_outline_is_kept_from_it(tmp_path):
    # a polygon of two points: the lane stays, from its centre line, at the default width
    scene = read(tmp_path, scenario(map_features__lane_1__polygon=np.array([[0.0, 0], [5, 0]])))
    lane = next(f for f in scene.map_features if f.id == "lane_1")
    assert lane.polyline is not None and lane.polygon is None
    assert skipped_of(scene, "lane_1")[0].reason == ("polygon not read (its polygon has 2 point(s); a surface needs "
                                                     "3); kept from its polyline")
    assert scenario_map(scene).width_sources == ("default",)
    # a one-point centre line: the lane's surface is kept (for the drivable area), not a lane to follow
    scene = read(tmp_path, scenario(map_features__lane_1__polyline=np.array([[0.0, 0.0]])))
    lane = next(f for f in scene.map_features if f.id == "lane_1")
    assert lane.polyline is None and lane.polygon is not None
    assert "kept from its polygon" in skipped_of(scene, "lane_1")[0].reason
    assert len(scenario_map(scene).semantic.lane_ids) == 0


def test_a_feature_without_geometry_or_not_a_mapping_is_skipped(tmp_path):
    scene = read(tmp_path, scenario(map_features__lane_1={"type": "LANE_SURFACE_STREET"},
                                    map_features__stop={"type": "STOP_SIGN", "lane": [1]},
                                    map_features__odd=[1, 2]))
    assert {f.id for f in scene.map_features} == {"walk"}
    reasons = {s.id: s.reason for s in scene.skipped}
    assert reasons == {"lane_1": "not read: no polyline or polygon",
                       "stop": "not read: no position, polyline or polygon",
                       "odd": "not read: not a mapping with a text 'type' (found a list)"}


def test_a_speed_limit_that_is_not_a_speed_is_dropped_and_the_lane_kept(tmp_path):
    scene = read(tmp_path, scenario(map_features__lane_1__speed_limit_kmh=float("nan")))
    lane = next(f for f in scene.map_features if f.id == "lane_1")
    assert lane.speed_limit_kmh is None and lane.polyline is not None
    assert skipped_of(scene, "lane_1")[0].reason == "speed_limit_kmh 'nan' is not a speed in km/h: read without a " \
                                                    "speed limit"


def test_argoverse_2s_placeholder_speed_limit_is_not_read_as_a_limit(tmp_path):
    # the Argoverse 2 converter writes speed_limit_mph 85 and its km/h on every lane
    data = scenario(metadata__dataset="av2", map_features__lane_1__speed_limit_kmh=136.79,
                    map_features__lane_1__speed_limit_mph=85.0)
    scene = read(tmp_path, data)
    assert next(f for f in scene.map_features if f.id == "lane_1").speed_limit_kmh is None
    assert scene.notes == ["speed_limit_kmh of 1 lane(s) not read: ScenarioNet's Argoverse 2 converter writes 85 mph "
                           "on every lane, a placeholder (Argoverse 2's maps give no limits)"]
    waymo = read(tmp_path, scenario(metadata__dataset="waymo", map_features__lane_1__speed_limit_kmh=40.2))
    assert next(f for f in waymo.map_features if f.id == "lane_1").speed_limit_kmh == 40.2 and waymo.notes == []


#: what each converter writes (scenarionet/converter/*, metadriverse/scenarionet @ cebcbe6), as
#: (feature type, what it has) -> its group here
CONVERTED_FEATURES = {
    "waymo": {"LANE_FREEWAY": "lane", "LANE_SURFACE_STREET": "lane", "LANE_BIKE_LANE": "lane", "LANE_UNKNOWN": "lane",
              "UNKNOWN": "road_edge", "ROAD_LINE_BROKEN_SINGLE_WHITE": "road_line",
              "ROAD_LINE_SOLID_SINGLE_WHITE": "road_line", "ROAD_LINE_SOLID_DOUBLE_WHITE": "road_line",
              "ROAD_LINE_BROKEN_SINGLE_YELLOW": "road_line", "ROAD_LINE_BROKEN_DOUBLE_YELLOW": "road_line",
              "ROAD_LINE_SOLID_SINGLE_YELLOW": "road_line", "ROAD_LINE_SOLID_DOUBLE_YELLOW": "road_line",
              "ROAD_LINE_PASSING_DOUBLE_YELLOW": "road_line", "ROAD_EDGE_BOUNDARY": "road_edge",
              "ROAD_EDGE_MEDIAN": "road_edge", "STOP_SIGN": "point", "CROSSWALK": "area", "SPEED_BUMP": "area",
              "DRIVEWAY": "area"},
    "nuscenes": {"LANE_SURFACE_STREET": "lane", "LANE_SURFACE_UNSTRUCTURE": "lane",
                 "ROAD_LINE_SOLID_SINGLE_WHITE": "road_line", "ROAD_LINE_BROKEN_SINGLE_WHITE": "road_line",
                 "ROAD_LINE_SOLID_SINGLE_YELLOW": "road_line", "CROSSWALK": "area", "ROAD_EDGE_SIDEWALK": "road_edge"},
    "nuplan": {"LANE_SURFACE_STREET": "lane", "LANE_SURFACE_UNSTRUCTURE": "lane", "UNKNOWN_LINE": "road_line",
               "ROAD_LINE_BROKEN_SINGLE_WHITE": "road_line", "ROAD_LINE_SOLID_SINGLE_WHITE": "road_line",
               "ROAD_EDGE_SIDEWALK": "road_edge", "CROSSWALK": "area"},
    "av2": {"LANE_SURFACE_STREET": "lane", "LANE_BIKE_LANE": "lane", "UNKNOWN_LINE": "road_line",
            "ROAD_LINE_SOLID_DOUBLE_YELLOW": "road_line", "ROAD_LINE_SOLID_DOUBLE_WHITE": "road_line",
            "ROAD_LINE_SOLID_SINGLE_YELLOW": "road_line", "ROAD_LINE_SOLID_SINGLE_WHITE": "road_line",
            "ROAD_LINE_BROKEN_SINGLE_WHITE": "road_line", "ROAD_LINE_BROKEN_SINGLE_YELLOW": "road_line",
            "CROSSWALK": "area"},
}
CONVERTED_TRACKS = {"waymo": ("UNSET", "VEHICLE", "PEDESTRIAN", "CYCLIST", "OTHER"),
                    "nuscenes": ("VEHICLE", "PEDESTRIAN", "CYCLIST", "TRAFFIC_BARRIER", "TRAFFIC_CONE"),
                    "nuplan": ("VEHICLE", "PEDESTRIAN", "CYCLIST", "TRAFFIC_BARRIER", "TRAFFIC_CONE"),
                    "av2": ("VEHICLE", "PEDESTRIAN", "CYCLIST", "OTHER")}
LABEL_OF_TRACK = {"VEHICLE": "CAR", "PEDESTRIAN": "PEDESTRIAN", "CYCLIST": "CYCLIST"}
#: light states: Waymo's nine (a None where it lists none), nuPlan's four; the face each lights
LIGHT_FACES = {"LANE_STATE_UNKNOWN": None, "LANE_STATE_ARROW_STOP": "r", "LANE_STATE_ARROW_CAUTION": "y",
               "LANE_STATE_ARROW_GO": "g", "LANE_STATE_STOP": "r", "LANE_STATE_CAUTION": "y", "LANE_STATE_GO": "g",
               "LANE_STATE_FLASHING_STOP": None, "LANE_STATE_FLASHING_CAUTION": "y", None: None,
               "TRAFFIC_LIGHT_GREEN": "g", "TRAFFIC_LIGHT_RED": "r", "TRAFFIC_LIGHT_YELLOW": "y",
               "TRAFFIC_LIGHT_UNKNOWN": None}


def _shape_of(group):
    """A feature of ``group`` as the converters write it: lanes and lines as polylines, areas and
    sidewalks as polygons, a stop sign as a position."""
    if group == "point":
        return {"position": np.array([1.0, 2.0, 0.0], np.float32), "lane": [7]}
    square = np.array([[0.0, 0], [4, 0], [4, 4], [0, 4]], np.float32)
    return {"polygon": square} if group == "area" else {"polyline": np.array([[0.0, 0, 0], [5, 0, 0]], np.float32)}


@pytest.mark.parametrize("dataset", sorted(CONVERTED_FEATURES))
def test_every_type_a_converter_writes_is_read_into_what_it_means(tmp_path, dataset):
    features = {f"f{n}": {"type": kind, **_shape_of(group)}
                for n, (kind, group) in enumerate(CONVERTED_FEATURES[dataset].items())}
    features["side"] = {"type": "ROAD_EDGE_SIDEWALK", "polygon": np.array([[0.0, 5], [9, 5], [9, 7], [0, 7]])}
    data = scenario(steps=len(LIGHT_FACES), map_features=features, dynamic_map_states={})
    kinds = CONVERTED_TRACKS[dataset]
    for n, kind in enumerate(kinds):
        data["tracks"][f"t{n}"] = {**data["tracks"]["car"], "type": kind}
    data["dynamic_map_states"]["5"] = {"type": "TRAFFIC_LIGHT", "lane": 5, "stop_point": np.zeros(3, np.float32),
                                       "state": {"object_state": list(LIGHT_FACES)}}
    scene = read(tmp_path, data)
    assert scene.skipped == []  # nothing a converter writes is refused or skipped
    assert {f.id: f.group for f in scene.map_features if f.id != "side"} == \
        {fid: CONVERTED_FEATURES[dataset][f["type"]] for fid, f in features.items() if fid != "side"}
    l5 = l5_scene(scene)
    for n, kind in enumerate(kinds):
        row = scene.tracks.ids.index(f"t{n}")
        agent = l5.agents[l5.agents["track_id"] == row + 1][0]
        assert np.argmax(agent["label_probabilities"]) == label_index(LABEL_OF_TRACK.get(kind, "UNKNOWN")), kind
    lit = [active_faces(scene, t) for t in range(scene.steps)]
    assert [faces[0][-1] if faces else None for faces in lit] == list(LIGHT_FACES.values())


def test_a_type_no_converter_writes_is_skipped_or_kept_and_listed_never_refused(tmp_path):
    data = scenario(map_features__hill={"type": "BUILDING", "polygon": np.array([[0.0, 0], [1, 0], [1, 1]])},
                    tracks__car__type="SCOOTER", tracks__cone__type=None,
                    dynamic_map_states__tl__state__object_state=["LANE_STATE_GO", "BLINKING", "BLINKING", None])
    scene = read(tmp_path, data)
    assert "hill" not in {f.id for f in scene.map_features}
    assert scene.tracks.types == ["VEHICLE", "SCOOTER", "UNSET"]
    listed = {(s.what, s.id): s.reason for s in scene.skipped}
    assert listed[("map feature", "hill")].startswith("not read: not a map-feature type ScenarioNet's converters")
    assert "read as an object of unknown kind" in listed[("track", "car")]
    assert listed[("track", "cone")] == "no type: read as UNSET, an object of unknown kind"
    assert listed[("traffic light", "tl")].startswith("state(s) BLINKING not among those")
    l5 = l5_scene(scene)
    car = l5.agents[l5.agents["track_id"] == 2][0]
    assert np.argmax(car["label_probabilities"]) == label_index("UNKNOWN")  # still a box one can hit
    assert [active_faces(scene, t) for t in range(4)] == [["0:0:g"], [], [], []]


def waymo_times(steps, jitter_s=6e-5, seed=0):
    """Timestamps as Waymo's converter writes them (float32 seconds, no sample_rate): a median step of
    0.0999889 s, as a real Waymo scene has, each step jittered by up to ``jitter_s``."""
    rng = np.random.default_rng(seed)
    steps_s = 0.0999889 + rng.uniform(-jitter_s, jitter_s, steps - 1)
    return np.concatenate([[0.0], np.cumsum(steps_s)]).astype(np.float32)


def waymo_like(steps=91, times=None):
    data = scenario(steps=steps, metadata__ts=waymo_times(steps) if times is None else times)
    del data["metadata"]["sample_rate"]
    return data


def test_timestamps_that_jitter_within_the_tolerance_are_treated_as_the_step_and_said(tmp_path):
    scene = read(tmp_path, waymo_like())
    assert scene.notes == []  # the reader does not judge a rate; the closed loop's step does
    assert l5_scene(scene).num_frames == 91
    (note,) = scene.notes
    assert note.startswith("timestamps jitter up to 0.0") and "ms around 0.1 s" in note
    assert "median 99.99 ms" in note and "treated as 0.1 s (accepted: a median step within 1% and each step " \
                                        "within 5% of 0.1 s)" in note
    exact = read(tmp_path, scenario(steps=91))  # nuScenes: arange(0, T) * 0.1 and sample_rate 0.1
    l5_scene(exact)
    assert exact.notes == []


def test_a_gap_in_the_timestamps_is_refused_at_its_step(tmp_path):
    times = np.arange(20) * 0.1
    times[7:] += 0.1  # a frame missing after step 6
    with pytest.raises(ScenarioNetError, match=r"sd_test.pkl \(scenario s1\): metadata.ts steps 0.2 s from step 6 to 7 "
                                               r"\(0.6 s to 0.8 s\): a gap, a frame missing there; the closed loop "
                                               r"steps every 0.1 s and accepts a median step within 1% and each step "
                                               r"within 5% of it; cut the scenario there"):
        l5_scene(read(tmp_path, waymo_like(20, times)))


@pytest.mark.parametrize("times, declared, message", [
    (np.arange(20) * 0.103, None, r"sampled every 0.103 s \(the median step of metadata.ts\); the closed loop steps "
                                  r"every 0.1 s and accepts a median step within 1%"),
    (np.arange(20) * 0.5, 0.5, r"sampled every 0.5 s \(metadata.sample_rate\)"),
])
def test_another_rate_is_refused_with_the_tolerance_it_missed(tmp_path, times, declared, message):
    data = waymo_like(20, times)
    if declared is not None:
        data["metadata"]["sample_rate"] = declared
    with pytest.raises(ScenarioNetError, match=message):
        l5_scene(read(tmp_path, data))


def test_nuplans_interval_within_its_converters_bound_is_accepted(tmp_path):
    # the nuPlan converter writes ts = i * database_interval and accepts an interval within 1e-3 s of 0.1 s
    data = scenario(steps=40, metadata__ts=np.arange(40) * 0.1008, metadata__sample_rate=0.1008)
    scene = read(tmp_path, data)
    l5_scene(scene)
    assert "jitter up to 0.8 ms around 0.1 s" in scene.notes[0] and "drift up to 31.2 ms" in scene.notes[0]


def test_the_dataset_gives_what_was_skipped_as_data_and_as_lines(tmp_path):
    data = waymo_like(30)
    data["map_features"]["204"] = {"type": "LANE_SURFACE_STREET", "polyline": np.array([[3.0, 4.0, 0.1]])}
    write(tmp_path, data, "sd_a.pkl")
    write(tmp_path, scenario(steps=30), "sd_b.pkl")
    dataset = ScenarioNetDataset.open(tmp_path)
    notes = dataset.read_notes(0)
    assert notes["skipped"] == ["map feature 204 (LANE_SURFACE_STREET): not read: its polyline has 1 point(s); a "
                                "line needs 2"]
    assert notes["notes"][0].startswith("timestamps jitter up to")
    assert dataset.source(0).skipped[0].id == "204"
    assert dataset.read_notes(1) is None


def test_every_real_scenarionet_file_in_the_shared_data_reads_and_drives(shared_data):
    files = scenario_files(shared_data / "scenarionet")
    assert files
    for path in files:
        scene = read_scenario(path)
        assert l5_scene(scene).num_frames > 1, path.name
        assert len(scenario_map(scene).semantic.lane_ids) > 0, path.name
        # every type these files hold is one the table knows
        assert not [s for s in scene.skipped if "converters write" in s.reason], (path.name, scene.skipped)
