"""A ScenarioNet map as the L5 semantic map model: lane boundaries from centre lines and measured
widths, lights as faces, and on the real nuScenes scenes the logged car drives on the surfaces."""
import numpy as np
import pytest

from pytest_driveeval.geometry.polygons import points_in_polygon
from pytest_driveeval.io.l5.l5_semantic_map import GREEN, RED
from pytest_driveeval.io.scenarionet.scenarionet import read_scenario, scenario_files
from pytest_driveeval.io.scenarionet.scenarionet_l5 import l5_scene
from pytest_driveeval.io.scenarionet.scenarionet_map import DEFAULT_LANE_WIDTH, active_faces, scenario_map

from scenarionet_made import scenario, write


def made(tmp_path):
    data = scenario(steps=3)
    data["map_features"]["lane_1"]["polygon"] = np.array([[0.0, -2], [10, -2], [10, 2], [0, 2]])  # 4 m wide
    data["map_features"]["lane_2"] = {"type": "LANE_FREEWAY", "polyline": np.array([[0.0, 10, 0.3], [0, 20, 0.3]])}
    data["dynamic_map_states"]["tl"]["state"]["object_state"] = ["LANE_STATE_GO", "LANE_STATE_STOP", None]
    return read_scenario(write(tmp_path, data))


def test_lane_boundaries_lie_half_the_measured_width_either_side_of_the_centre_line(tmp_path):
    smap = scenario_map(made(tmp_path))
    lanes = list(smap.semantic.lane_ids)
    one, two = lanes.index("lane_1"), lanes.index("lane_2")
    assert smap.lane_widths[one] == pytest.approx(4.0) and smap.width_sources[one] == "polygon"
    assert np.allclose(smap.semantic.lanes_left[one], [[0, 2], [10, 2]])    # left of +x is +y
    assert np.allclose(smap.semantic.lanes_right[one], [[0, -2], [10, -2]])
    # No polygon: the default width, and the third column (a heading) is not taken for a coordinate
    assert smap.lane_widths[two] == DEFAULT_LANE_WIDTH and smap.width_sources[two] == "default"
    assert np.allclose(smap.semantic.lanes_left[two][:, 0], -DEFAULT_LANE_WIDTH / 2)
    assert list(smap.semantic.crosswalk_ids) == ["walk"]


def test_a_light_is_three_faces_on_its_lane_and_its_state_lights_one(tmp_path):
    scene = made(tmp_path)
    smap = scenario_map(scene, index=7).semantic
    one = list(smap.lane_ids).index("lane_1")
    assert list(smap.lane_controls(one)) == ["7:0:r", "7:0:y", "7:0:g"]
    assert smap.face_colours[list(smap.face_ids).index("7:0:r")] == RED
    assert smap.face_colours[list(smap.face_ids).index("7:0:g")] == GREEN
    assert [active_faces(scene, t, 7) for t in range(3)] == [["7:0:g"], ["7:0:r"], []]
    # ... and the engine's scene lists the lit face at each frame, as an L5 scene does
    l5 = l5_scene(scene, 7)
    assert [list(l5.tl_faces_of_frame(t)["face_id"]) for t in range(3)] == [["7:0:g"], ["7:0:r"], []]


def test_on_the_real_nuscenes_scenes_the_logged_car_drives_on_the_lane_surfaces(shared_data):
    for path in scenario_files(shared_data / "scenarionet" / "nuscenes"):
        scene = read_scenario(path)
        smap = scenario_map(scene)
        assert len(smap.semantic.lane_ids) > 100
        assert np.all((smap.lane_widths >= 2.0) & (smap.lane_widths <= 8.0))
        ego = scene.tracks.position[scene.sdc, :, :2][scene.tracks.valid[scene.sdc]]
        on_road = np.zeros(len(ego), bool)
        for i in range(len(smap.surfaces)):
            on_road |= points_in_polygon(ego[:, 0], ego[:, 1], smap.surfaces[i])
        # A logged drive stays on its map: a wrong width or a swapped side would show here.
        assert on_road.mean() > 0.95, (scene.id, on_road.mean())
