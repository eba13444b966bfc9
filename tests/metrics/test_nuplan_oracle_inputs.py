"""The nuplan-devkit oracle's own reading of ScenarioNet files (benchmarks/nuplan_oracle/scenario_pickle.py and
scenario_map.py): they import neither pytest_driveeval nor the devkit, so they are tested here with the
project's python.  Each quirk of the converters' output that the oracle rebuilds from has a test.  The ego's
box and dynamic state (scenario_case.py) need the devkit: tested in its venv where it exists."""
import math
import os
import pickle
import sys

import numpy as np
import pytest
from shapely.geometry import Point, Polygon

from conftest import REPO_ROOT, module_at

ORACLE = REPO_ROOT / "benchmarks" / "nuplan_oracle"


def _load(name):
    sys.path.insert(0, str(ORACLE))  # scenario_map is imported by name inside the oracle's modules
    try:
        return module_at(ORACLE / f"{name}.py", f"nuplan_oracle_{name}")
    finally:
        sys.path.remove(str(ORACLE))


reader = _load("scenario_pickle")
mapping = _load("scenario_map")


class _Runs:
    def __reduce__(self):
        return (os.system, ("echo this must not run",))


def test_the_reader_refuses_a_pickle_that_names_any_other_callable(tmp_path):
    path = tmp_path / "evil.pkl"
    path.write_bytes(pickle.dumps({"tracks": _Runs(), "map_features": {}, "metadata": {}}))
    with pytest.raises(reader.RefusedPickle, match=r"evil.pkl: the pickle asks for posix.system"):
        reader.load_scenario(path)


def test_the_reader_refuses_what_is_not_a_regular_file_or_not_a_scenario(tmp_path):
    with pytest.raises(reader.RefusedPickle, match="not a regular file"):
        reader.load_scenario(tmp_path)
    (tmp_path / "list.pkl").write_bytes(pickle.dumps([1, 2]))
    with pytest.raises(reader.RefusedPickle, match="not a ScenarioNet scenario"):
        reader.load_scenario(tmp_path / "list.pkl")
    (tmp_path / "cut.pkl").write_bytes(pickle.dumps({"a": np.zeros(100)})[:40])
    with pytest.raises(reader.RefusedPickle, match="not a readable pickle"):
        reader.load_scenario(tmp_path / "cut.pkl")


def test_the_reader_rebuilds_numpy_arrays_and_builtin_containers(tmp_path):
    scenario = {"tracks": {"ego": {"state": {"position": np.arange(6.0).reshape(2, 3)}}}, "map_features": {},
                "metadata": {"ts": np.array([0.0, 0.1]), "ids": {"a", "b"}, "sample_rate": np.float64(0.1)}}
    path = tmp_path / "ok.pkl"
    path.write_bytes(pickle.dumps(scenario))
    read = reader.load_scenario(path)
    assert np.array_equal(read["tracks"]["ego"]["state"]["position"], scenario["tracks"]["ego"]["state"]["position"])
    assert read["metadata"]["ids"] == {"a", "b"} and read["metadata"]["sample_rate"] == 0.1


def _lane(x0, x1, y=0.0, width=4.0, polygon=True, **extra):
    line = np.array([[x, y, 0.0] for x in np.linspace(x0, x1, 5)])
    feature = {"type": "LANE_SURFACE_STREET", "polyline": line, **extra}
    if polygon:
        feature["polygon"] = np.array([[x0, y - width / 2], [x1, y - width / 2], [x1, y + width / 2],
                                       [x0, y + width / 2]])
    return feature


def _ring(x0, y0, x1, y1):
    return {"type": "ROAD_LINE_SOLID_SINGLE_WHITE",
            "polyline": np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1], [x0, y0]])}


def test_a_nuscenes_connector_without_outline_is_a_lane_connector_widened_from_the_lanes_it_joins():
    # ScenarioNet's nuScenes converter writes a lane_connector's centre line only (older versions with the
    # lanes' type and a 100 km/h placeholder), and no entry or exit lanes at all.
    features = {"a": _lane(0, 10, width=4.0), "c": _lane(10, 20, polygon=False, speed_limit_kmh=100),
                "b": _lane(20, 30, width=3.0)}
    built = mapping.scenario_map({"map_features": features})
    lanes = {lane["id"]: lane for lane in built["lanes"]}
    assert [lanes[k]["connector"] for k in "acb"] == [False, True, False]
    assert lanes["a"]["outgoing"] == ["c"] and lanes["c"]["incoming"] == ["a"] and lanes["c"]["outgoing"] == ["b"]
    connector = Polygon(lanes["c"]["polygon"]["shell"])
    assert connector.bounds == pytest.approx((10, -1.75, 20, 1.75))  # half the mean of 4 and 3 m, flat ends
    assert lanes["c"]["speed_limit"] == pytest.approx(100 / 3.6) and lanes["a"]["speed_limit"] is None
    assert any("lane graph joins centre lines" in n for n in built["notes"])


def test_lanes_join_only_where_one_ends_within_the_tolerance_of_anothers_start():
    features = {"a": _lane(0, 10), "b": _lane(10 + 2 * mapping.JOIN_TOLERANCE, 20)}
    lanes = {lane["id"]: lane for lane in mapping.scenario_map({"map_features": features})["lanes"]}
    assert lanes["a"]["outgoing"] == [] and lanes["b"]["incoming"] == []


def test_entry_and_exit_lanes_of_the_file_are_taken_as_given():
    features = {"a": _lane(0, 10, exit_lanes=["b"]), "b": _lane(50, 60, entry_lanes=["a"]), "c": _lane(10, 20)}
    lanes = {lane["id"]: lane for lane in mapping.scenario_map({"map_features": features})["lanes"]}
    assert lanes["a"]["outgoing"] == ["b"] and lanes["b"]["incoming"] == ["a"] and lanes["c"]["incoming"] == []


def test_neighbouring_lanes_form_one_roadblock_and_a_lone_lane_its_own():
    # nuPlan's converter lists the roadblock's other lanes as left / right neighbours
    features = {"l": _lane(0, 10, y=4.0, right_neighbor=["r"]), "r": _lane(0, 10, y=0.0, left_neighbor=["l"]),
                "x": _lane(40, 50)}
    built = mapping.scenario_map({"map_features": features})
    lanes = {lane["id"]: lane for lane in built["lanes"]}
    assert lanes["l"]["roadblock"] == lanes["r"]["roadblock"] != lanes["x"]["roadblock"]
    (both,) = [b for b in built["roadblocks"] if b["id"] == lanes["l"]["roadblock"]]
    assert Polygon(both["polygon"]["shell"]).area == pytest.approx(80.0)


def test_the_drivable_area_is_rebuilt_from_the_boundary_rings_hole_included():
    # The converters write the union's boundary, exploded: exterior and hole rings alike
    features = {"a": _lane(0, 10), "boundary_0": _ring(-50, -50, 50, 50), "boundary_1": _ring(-10, -10, 10, 10)}
    built = mapping.scenario_map({"map_features": features})
    (area,) = built["drivable_area"]
    polygon = Polygon(area["shell"], area["holes"])
    assert polygon.area == pytest.approx(100 * 100 - 20 * 20)
    assert polygon.contains(Point(30, 30)) and not polygon.contains(Point(0, 0))


def test_without_boundary_rings_the_drivable_area_is_the_lanes_and_it_says_so():
    built = mapping.scenario_map({"map_features": {"a": _lane(0, 10), "b": _lane(10, 20)}})
    assert sum(Polygon(a["shell"]).area for a in built["drivable_area"]) == pytest.approx(80.0)
    assert any("union of the lanes" in n for n in built["notes"])


def test_a_lane_whose_centre_line_is_one_point_is_left_out_and_named():
    features = {"a": _lane(0, 10), "dot": {"type": "LANE_SURFACE_STREET", "polyline": np.array([[1.0, 2.0, 0.0]])}}
    built = mapping.scenario_map({"map_features": features})
    assert [lane["id"] for lane in built["lanes"]] == ["a"]
    assert any(n.startswith("lane dot:") for n in built["notes"])


def test_on_the_real_nuscenes_files_no_two_lanes_overlap_and_every_connector_has_a_polygon(shared_data):
    # nuPlan's map asserts that one point lies in at most one LANE; connectors may overlap
    for path in sorted((shared_data / "scenarionet" / "nuscenes").glob("*.pkl")):
        built = mapping.scenario_map(reader.load_scenario(path))
        lanes = [Polygon(lane["polygon"]["shell"], lane["polygon"]["holes"])
                 for lane in built["lanes"] if not lane["connector"]]
        assert lanes and built["drivable_area"], path
        overlap = [(i, j) for i in range(len(lanes)) for j in range(i + 1, len(lanes))
                   if lanes[i].intersection(lanes[j]).area > 1e-6]
        assert overlap == [], path.name
        assert all(len(lane["polygon"]["shell"]) >= 3 for lane in built["lanes"])


EGO_CHECK = r"""
import json, math, sys
import numpy as np
sys.path.insert(0, sys.argv[1])
from scenario_case import ego_box, ego_dynamics

notes = []
scenario = {"metadata": {"sdc_id": "ego"},
            "tracks": {"ego": {"state": {"length": np.full((3, 1), 1.73), "width": np.full((3, 1), 4.08)}}}}
box = ego_box(scenario, 0, notes)
times = np.arange(40) * 0.1
straight = np.stack([10.0 * times, np.zeros(40), np.zeros(40)], axis=1)
# a left turn of radius 20 m at 5 m/s, the box centre on the circle, heading along it
omega = 5.0 / 20.0
turn = np.stack([20 * np.sin(omega * times), 20 - 20 * np.cos(omega * times), omega * times], axis=1)
print(json.dumps({"box": box, "notes": notes, "straight": ego_dynamics(straight, times, 5.0, 2.0),
                  "turn": ego_dynamics(turn, times, 5.0, 2.0)}))
"""


@pytest.fixture(scope="module")
def venv_ego():
    import json
    import subprocess

    venv = _load("oracle_venv").existing_python()
    if venv is None:
        pytest.skip("nuplan-devkit oracle venv absent (python benchmarks/nuplan_oracle/oracle_venv.py builds it)")
    done = subprocess.run([str(venv), "-c", EGO_CHECK, str(ORACLE)], capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    return json.loads(done.stdout.strip().splitlines()[-1])


def test_the_nuscenes_ego_box_written_wider_than_long_is_turned_and_said(venv_ego):
    # ScenarioNet's nuScenes converter writes [4.08, 1.73, 1.56] into the [width, length, height] slot
    assert venv_ego["box"] == [4.08, 1.73]
    assert "swaps them" in venv_ego["notes"][0]


def test_the_ego_state_is_nuplans_derivative_of_the_poses(venv_ego):
    straight = venv_ego["straight"]
    assert np.allclose(straight["velocity"], [[10.0, 0.0]] * 40)
    assert np.allclose(straight["acceleration"], 0.0, atol=1e-9)
    assert np.allclose(straight["angular_velocity"], 0.0) and np.allclose(straight["angular_acceleration"], 0.0)
    assert straight["rear_axle_to_center"] == pytest.approx(5.0 * 1.461 / 5.176)
    turn = venv_ego["turn"]
    assert np.allclose(turn["angular_velocity"], 0.25, atol=1e-6)
    inner = np.array(turn["acceleration"])[5:-5]
    # The rear axle runs on a circle of radius sqrt(20^2 + d^2) at 0.25 rad/s: 5.0x m/s^2 towards the centre, on
    # the left; nuPlan's projection (_project_from_global_to_ego_centric_ds) gives the lateral part its sign
    # flipped, and the oracle keeps nuPlan's sign.
    radius = math.hypot(20.0, 5.0 * 1.461 / 5.176)
    assert np.allclose(np.hypot(*inner.T), radius * 0.25 ** 2, rtol=1e-3)
    assert (inner[:, 1] < 0).all()
