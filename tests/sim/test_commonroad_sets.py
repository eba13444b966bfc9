"""CommonRoad episodes on what the format allows beyond exact rectangles: collisions with occupancy-set
obstacles, circles, polygons and set-valued states decided by their shapes; every planning problem of
the shared files driven; the files that cannot be driven refused by name."""
from __future__ import annotations

import numpy as np
import pytest

from pytest_driveeval.io.commonroad.commonroad import CommonRoadError
from pytest_driveeval.sim.commonroad_scene import commonroad_scene, read_cached
from pytest_driveeval.sim.episodes import reset

HEAD = '<?xml version="1.0"?>\n<commonRoad commonRoadVersion="{v}" timeStepSize="0.1" benchmarkID="S">\n'
ROAD = """<lanelet id="1">
<leftBound><point><x>-50</x><y>6</y></point><point><x>50</x><y>6</y></point></leftBound>
<rightBound><point><x>-50</x><y>-6</y></point><point><x>50</x><y>-6</y></point></rightBound>
</lanelet>
"""
PROBLEM = ('<planningProblem id="5"><initialState><position><point><x>-40</x><y>0</y></point></position>'
           "<orientation><exact>0</exact></orientation><time><exact>0</exact></time><velocity><exact>0</exact>"
           "</velocity><yawRate><exact>0</exact></yawRate><slipAngle><exact>0</exact></slipAngle></initialState>"
           "<goalState><time><intervalStart>0</intervalStart><intervalEnd>10</intervalEnd></time>"
           "<position><circle><radius>1</radius><center><x>45</x><y>0</y></center></circle></position>"
           "</goalState></planningProblem>\n")
ZERO = dict(start_lateral=(0, 0), start_longitudinal=(0, 0), start_heading=(0, 0), start_speed=(0, 0),
            vehicle_length=2.0, vehicle_width=1.0)


def ex(tag, v):
    return f"<{tag}><exact>{v}</exact></{tag}>"


def scene_with(tmp_path, obstacles: str, version: str = "2020a", name: str = "s.xml"):
    path = tmp_path / name
    path.write_text(HEAD.format(v=version) + ROAD + obstacles + PROBLEM + "</commonRoad>\n")
    return commonroad_scene(path, 5, **ZERO)


def hits(scene, k: int, *egos) -> list[bool]:
    """Whether an ego box (2 m x 1 m) at each (x, y, yaw) collides at step ``k``."""
    episodes = reset(scene, np.zeros(len(egos), np.int64), 12)
    xy = np.array([e[:2] for e in egos], float)
    yaw = np.array([e[2] for e in egos], float)
    _, collision, _ = episodes.judge(xy, yaw, np.zeros(len(egos)), np.full(len(egos), k))
    return collision.tolist()


CIRCLE_OCCUPANCY = ('<dynamicObstacle id="9"><type>unknown</type><shape><rectangle><length>4</length><width>2'
                    "</width></rectangle></shape><initialState><position><point><x>0</x><y>0</y></point></position>"
                    + ex("orientation", 0) + ex("time", 0) + "</initialState><occupancySet>"
                    "<occupancy><shape><circle><radius>2</radius><center><x>10</x><y>0</y></center></circle></shape>"
                    "<time><intervalStart>2</intervalStart><intervalEnd>3</intervalEnd></time></occupancy>"
                    "<occupancy><shape><polygon><point><x>20</x><y>0</y></point><point><x>24</x><y>0</y></point>"
                    "<point><x>20</x><y>4</y></point></polygon><rectangle><length>1</length><width>1</width>"
                    "<center><x>30</x><y>0</y></center></rectangle></shape>" + ex("time", 4)
                    + "</occupancy></occupancySet></dynamicObstacle>\n")


def test_an_occupancy_set_obstacle_collides_where_its_step_shapes_are(tmp_path):
    scene = scene_with(tmp_path, CIRCLE_OCCUPANCY)
    # present at its initial state (step 0, as commonroad-io) and the steps its occupancies cover (2, 3: the
    # circle; 4: a triangle and a square)
    assert scene.valid[:, 0].tolist() == [True, False, True, True, True, False, False, False, False, False, False]
    circle_edge = (10 + 2 + 1 - 1e-6, 0, 0)   # the ego's rear edge just inside the circle's rim
    beside = (10 + 2 + 1 + 0.01, 0, 0)         # 1 cm clear of it
    in_box_corner = (10 + 2.6, 2.2, 0)         # in the circle's bounding square, clear of the circle
    assert hits(scene, 2, circle_edge, beside, in_box_corner) == [True, False, False]
    assert hits(scene, 3, circle_edge) == [True]
    assert hits(scene, 1, circle_edge) == [False] and hits(scene, 5, circle_edge) == [False]  # absent
    # step 0: the obstacle's own 4 m x 2 m rectangle at its initial state (0, 0), not the occupancies
    assert hits(scene, 0, (2.0 + 1.0 - 1e-6, 0, 0), circle_edge) == [True, False]
    # step 4: the union of a triangle (hypotenuse x + y = 24) and a unit square at (30, 0)
    assert hits(scene, 4, circle_edge, (30, 1.0, 0), (23.5, 2.5, 0), (21.5, 1.0, 0)) == [False, True, False, True]


def test_a_circle_obstacle_collides_with_its_circle_not_its_square(tmp_path):
    static = ('<staticObstacle id="3"><type>parkedVehicle</type><shape><circle><radius>1</radius></circle></shape>'
              "<initialState><position><point><x>0</x><y>0</y></point></position>" + ex("orientation", 0)
              + ex("time", 0) + "</initialState></staticObstacle>\n")
    scene = scene_with(tmp_path, static)
    diagonal = 1.0 / np.sqrt(2)  # the ego's corner on the circle's diagonal, just outside it, inside its square
    ego_x, ego_y = diagonal + 0.01 + 1.0, diagonal + 0.01 + 0.5
    assert hits(scene, 3, (ego_x, ego_y, 0.0), (ego_x - 0.02, ego_y - 0.02, 0.0)) == [False, True]


def test_a_set_valued_state_collides_anywhere_in_its_set(tmp_path):
    # 2018b, as BMW's A9: the position a rectangle 10 m long, the orientation an interval
    state = ("<state><position><rectangle><length>10</length><width>1</width><center><x>0</x><y>0</y></center>"
             "</rectangle></position><orientation><intervalStart>-0.1</intervalStart><intervalEnd>0.1"
             "</intervalEnd></orientation>" + ex("time", 1) + ex("velocity", 0) + "</state>")
    obstacle = ('<obstacle id="9"><role>dynamic</role><type>car</type><shape><rectangle><length>2</length>'
                "<width>1</width></rectangle></shape><initialState><position><point><x>0</x><y>0</y></point>"
                "</position>" + ex("orientation", 0) + ex("time", 0) + "</initialState><trajectory>" + state
                + "</trajectory></obstacle>\n")
    scene = scene_with(tmp_path, obstacle, "2018b")
    # replayed at the set's middle; the car could be at x = 5 (the set's end), so an ego there collides
    # at step 1, while at step 0 (an exact state) only the car's own box counts
    assert scene.xy[1, 0].tolist() == [0.0, 0.0]
    far_end = (5.0 + 1.0 + 0.5, 0.0, 0.0)
    assert hits(scene, 1, far_end) == [True] and hits(scene, 0, far_end) == [False]
    assert hits(scene, 1, (5.0 + 1.0 + 1.0 + 1.0 + 0.5, 0.0, 0.0)) == [False]  # beyond every placement


def test_reactive_traffic_keeps_the_occupancy_obstacles_in_place(tmp_path):
    path = tmp_path / "r.xml"
    path.write_text(HEAD.format(v="2020a") + ROAD + CIRCLE_OCCUPANCY + PROBLEM + "</commonRoad>\n")
    scene = commonroad_scene(path, 5, traffic="reactive", **ZERO)
    episodes = reset(scene, np.zeros(1, np.int64), 12)
    for _ in range(3):
        episodes.step(np.zeros((1, 2)))
    assert episodes.valid[0, 1] and episodes.xy[0, 1].tolist() == [10.0, 0.0]


# ---------------------------------------------------------------- the shared files

def driven(path, problem):
    scene = commonroad_scene(path, problem, max_steps=5)
    episodes = reset(scene, np.array([0, 1]), 12)
    for _ in range(5):
        if episodes.done.all():
            break
        episodes.step(np.zeros((2, 2)))
    return scene, episodes


def test_every_planning_problem_of_the_shared_files_runs(shared_data):
    ran, refused = [], []
    for path in sorted((shared_data / "commonroad").glob("*.xml")):
        problems = sorted(read_cached(path).planning_problems)
        for problem in problems:
            try:
                scene, episodes = driven(path, problem)
            except CommonRoadError as exc:
                refused.append((path.name, str(exc)))
                continue
            assert episodes.steps.max() >= 1 and np.isfinite(episodes.xy).all(), (path.name, problem)
            ran.append((path.name, problem))
    names = {n for n, _ in ran}
    # the occupancy-set file, each state type, the intersection and the traffic lights all run
    assert {"test_reading_all.xml", "test_reading_pm_state.xml", "test_reading_ks_state.xml",
            "test_reading_st_state.xml", "test_reading_std_state.xml", "test_reading_custom_state.xml",
            "test_reading_complex_tl.xml", "test_reading_intersection_traffic_sign.xml", "ZAM_Loading_Bay-1_1_T.xml",
            "USA_US101-3_3_T-1.xml"} <= names
    # the only planning problem that cannot run is one without a road, and its error says so by name
    assert [n for n, _ in refused] == ["test_reading_planning_problem.xml"]
    assert "test_reading_planning_problem.xml: planning problem 1000: the file has no <lanelet>" in refused[0][1]


@pytest.mark.parametrize("name", ["DEU_Starnberg-1_1_T-1.xml", "test_reading_lanelets.xml", "test_3d_points.xml",
                                  "test_reading_obstacles.xml"])
def test_a_shared_file_without_a_planning_problem_says_it_cannot_be_driven(shared_data, name):
    path = shared_data / "commonroad" / name
    with pytest.raises(CommonRoadError, match=rf"{name} has no <planningProblem> \(it holds \d+ lanelet\(s\) and \d+ "
                                              r"obstacle\(s\) only\): .*this file cannot be driven"):
        commonroad_scene(path, 1)
