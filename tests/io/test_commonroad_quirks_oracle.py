"""The format's quirks against commonroad-io 2026.1 in its own venv (benchmarks/commonroad_oracle/oracle_venv.py
makes it; skipped where it is absent), on the shared files that hold them:

* an occupancy-set obstacle (test_reading_obstacles): an ego box collides with it at a step exactly where
  shapely says the box meets commonroad-io's ``occupancy_at_time`` shape (a circle's as the file gives it:
  2026.1's CircleOccupancy draws its shapely circle at half the radius);
* point-mass states (test_reading_pm_state): the obstacle's outline at every step is commonroad-io's
  (its heading from velocity and velocityY);
* the road's edge on every shared file with a planning problem: where we put a corner off the road,
  commonroad-io's ``find_lanelet_by_position`` finds no lanelet there (we are never the stricter one).
"""
from __future__ import annotations

import json
import subprocess

import numpy as np
import pytest

from conftest import REPO_ROOT, module_at
from pytest_driveeval.io.commonroad.commonroad import read_commonroad
from pytest_driveeval.io.commonroad.commonroad_geometry import obstacle_outline
from pytest_driveeval.sim.commonroad_road import corners_on_road
from pytest_driveeval.sim.commonroad_scene import commonroad_scene, read_cached
from pytest_driveeval.sim.episodes import reset

SCRIPT = """
import json, sys
import numpy as np
from commonroad.common.file_reader import CommonRoadFileReader
from shapely.geometry import Polygon
request = json.load(open(sys.argv[1]))
scenario, _ = CommonRoadFileReader(request["scenario"]).open()
out = {"hits": [], "lanelets": []}
for probe in request["boxes"]:
    box = Polygon(probe["corners"])
    found = []
    for obstacle in scenario.obstacles:
        occ = obstacle.occupancy_at_time(probe["t"])
        # 2026.1 answers an occupancy object with its own shapely_object; older ones an Occupancy with a shape.
        # 2026.1's CircleOccupancy.shapely_object buffers its centre by radius / 2 (its radius read as a
        # diameter): the circle the file gives, and the one its `radius` says, is centre.buffer(radius)
        if occ is not None and hasattr(occ, "circle_center"):
            shape = occ.circle_center.buffer(occ.radius, 64)
        else:
            shape = getattr(occ, "shapely_object", None) or (occ.shape.shapely_object if occ is not None else None)
        if shape is not None and box.intersects(shape):
            found.append(obstacle.obstacle_id)
    out["hits"].append(sorted(found))
if request["points"]:
    out["lanelets"] = scenario.lanelet_network.find_lanelet_by_position([np.array(p) for p in request["points"]])
print(json.dumps(out))
"""


ORACLE = module_at(REPO_ROOT / "benchmarks" / "commonroad_oracle" / "oracle_venv.py", "commonroad_oracle_venv_quirks")


@pytest.fixture(scope="module")
def oracle_python():
    python = ORACLE.existing_python()
    if python is None:
        pytest.skip(f"commonroad-io's venv absent: run python {ORACLE.__file__} to make {ORACLE.VENV}")
    return python


def ask(python, tmp_path, scenario, boxes=(), points=()) -> dict:
    request = tmp_path / "request.json"
    request.write_text(json.dumps({"scenario": str(scenario), "boxes": list(boxes), "points": list(points)}))
    script = tmp_path / "probe.py"
    script.write_text(SCRIPT)
    done = subprocess.run([str(python), str(script), str(request)], capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    return json.loads(done.stdout)


def corners(x, y, yaw, length, width) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    local = np.array([[0.5, 0.5], [-0.5, 0.5], [-0.5, -0.5], [0.5, -0.5]]) * (length, width)
    return local @ np.array([[c, s], [-s, c]]) + (x, y)


def test_occupancy_set_collisions_are_commonroad_ios(shared_data, oracle_python, tmp_path):
    # test_reading_obstacles has no planning problem: its obstacles in a scene of our own road
    source = (shared_data / "commonroad" / "test_reading_obstacles.xml").read_text()
    road = ('<lanelet id="77"><leftBound><point><x>-30</x><y>20</y></point><point><x>30</x><y>20</y></point>'
            '</leftBound><rightBound><point><x>-30</x><y>-20</y></point><point><x>30</x><y>-20</y></point>'
            "</rightBound></lanelet>")
    problem = ('<planningProblem id="500"><initialState><position><point><x>-20</x><y>0</y></point></position>'
               "<orientation><exact>0</exact></orientation><time><exact>0</exact></time><velocity><exact>0</exact>"
               "</velocity><yawRate><exact>0</exact></yawRate><slipAngle><exact>0</exact></slipAngle>"
               "</initialState><goalState><time><intervalStart>0</intervalStart><intervalEnd>5</intervalEnd>"
               "</time></goalState></planningProblem>")
    head_end = source.index(">", source.index("<commonRoad")) + 1
    path = tmp_path / "obstacles_with_road.xml"
    path.write_text(source[:head_end] + road + source[head_end:].replace("</commonRoad>", problem + "</commonRoad>"))
    scene = commonroad_scene(path, 500, vehicle_length=1.0, vehicle_width=0.6)
    assert read_commonroad(path).obstacles[1].set_based
    grid = np.linspace(-7.0, 7.0, 15)
    probes = [(float(x), float(y), 0.3 * (i % 5), t) for i, (x, y) in enumerate((x, y) for x in grid for y in grid)
              for t in range(5)]
    boxes = [{"t": t, "corners": corners(x, y, yaw, 1.0, 0.6).tolist()} for x, y, yaw, t in probes]
    theirs = ask(oracle_python, tmp_path, path, boxes=boxes)["hits"]
    episodes = reset(scene, np.zeros(len(probes), np.int64), 12)
    xy = np.array([p[:2] for p in probes])
    yaw = np.array([p[2] for p in probes])
    k = np.array([p[3] for p in probes])
    _, collision, _ = episodes.judge(xy, yaw, np.zeros(len(probes)), k)
    differ = [(p, h) for p, c, h in zip(probes, collision, theirs) if c != bool(h)]
    assert not differ, f"{len(differ)} of {len(probes)} differ, e.g. {differ[:4]}"
    assert 0 < collision.sum() < len(probes)
    # the occupancy-set obstacle itself is hit at every step 0..3 somewhere, and nowhere at step 4
    hit_steps = {p[3] for p, h in zip(probes, theirs) if 1 in h}
    assert hit_steps == {0, 1, 2, 3}


def test_point_mass_outlines_are_commonroad_ios(shared_data):
    path = shared_data / "commonroad" / "test_reading_pm_state.xml"
    theirs = ORACLE.existing_python()
    if theirs is None:
        pytest.skip("commonroad-io's venv absent")
    read = ORACLE.read_scenario(path, python=theirs)
    ours = read_commonroad(path)
    for ob in read["obstacles"]:
        mine = ours.obstacles[ob["id"]]
        for state, outline in zip(ob["states"], ob["outlines"]):
            got = obstacle_outline(mine, int(state["time_step"]))
            assert {tuple(np.round(p, 9)) for p in got} == {tuple(np.round(p, 9)) for p in outline}, state


def _road_edge_module():
    """tests/sim/test_commonroad_road_edge.py: its points on the road's edge and the offsets tried there."""
    return module_at(REPO_ROOT / "tests" / "sim" / "test_commonroad_road_edge.py", "commonroad_road_edge_tests")


def test_off_the_road_only_where_commonroad_io_finds_no_lanelet(shared_data, oracle_python, tmp_path):
    edge = _road_edge_module()
    OFFSETS, edge_points, union_of = edge.OFFSETS, edge.edge_points, edge.union_of

    checked = off = 0
    for path in sorted((shared_data / "commonroad").glob("*.xml")):
        s = read_cached(path)
        if not (s.planning_problems and s.lanelets):
            continue
        scene = commonroad_scene(path, min(s.planning_problems), max_steps=1)
        points, normals = edge_points(s, union_of(s), most=60)
        probes = np.concatenate([points + d * normals for d in OFFSETS])
        ours = corners_on_road(scene, probes[:, None, :])[:, 0]
        theirs = ask(oracle_python, tmp_path, path, points=probes.tolist())["lanelets"]
        stricter = [p.tolist() for p, on, found in zip(probes, ours, theirs) if not on and found]
        assert not stricter, f"{path.name}: off the road for us, on lanelets for commonroad-io: {stricter[:3]}"
        # and inside the road both agree
        inside = np.concatenate([np.full(len(points), d < 0) for d in OFFSETS])
        assert all(bool(found) for found, i in zip(theirs, inside) if i) and ours[inside].all(), path.name
        checked, off = checked + len(probes), off + int((~ours).sum())
    assert checked > 1000 and off > 0
