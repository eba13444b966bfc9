"""The CommonRoad format as its XSD (commonroad-io's XML_commonRoad_XSD.xsd) and commonroad-io's reader
allow it, one test per quirk: set-valued states (a shape, a lanelet as position; intervals as values),
occupancy-set obstacles, point-mass states, 3-D points, and the obstacle kinds the benchmark skips;
then every file of the shared data read, with its notes."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from pytest_driveeval.io.commonroad.commonroad import CommonRoadError, planning_problem, read_commonroad
from pytest_driveeval.io.commonroad.commonroad_types import Circle, Interval, Polygon, Rectangle

HEAD = '<?xml version="1.0"?>\n<commonRoad commonRoadVersion="{v}" timeStepSize="0.1" benchmarkID="Q">\n'
LANELET = """<lanelet id="1">
<leftBound><point><x>0</x><y>2</y></point><point><x>40</x><y>2</y></point></leftBound>
<rightBound><point><x>0</x><y>-2</y></point><point><x>40</x><y>-2</y></point></rightBound>
</lanelet>
"""
RECT = "<rectangle><length>4</length><width>2</width></rectangle>"


def exact(tag: str, value) -> str:
    return f"<{tag}><exact>{value}</exact></{tag}>"


def interval(tag: str, start, end) -> str:
    return f"<{tag}><intervalStart>{start}</intervalStart><intervalEnd>{end}</intervalEnd></{tag}>"


def point(x, y) -> str:
    return f"<position><point><x>{x}</x><y>{y}</y></point></position>"


def write(tmp_path: Path, body: str, version: str = "2020a") -> Path:
    path = tmp_path / "q.xml"
    path.write_text(HEAD.format(v=version) + LANELET + body + "</commonRoad>\n")
    return path


def line_of(path: Path, text: str) -> int:
    """The line (from 1) where ``text`` first appears in the file."""
    return next(i for i, line in enumerate(path.read_text().splitlines(), start=1) if text in line)


def obstacle_2018b(oid: int, initial: str, states: str = "") -> str:
    """A 2018b <obstacle> (BMW's A9 recording writes these) with the given initial state's content."""
    trajectory = f"<trajectory>{states}</trajectory>" if states else ""
    return (f'<obstacle id="{oid}"><role>dynamic</role><type>car</type><shape>{RECT}</shape>'
            f"<initialState>{initial}</initialState>{trajectory}</obstacle>\n")


def timed(t: int, extra: str) -> str:
    return exact("time", t) + extra


# ---------------------------------------------------------------- set-valued states

def test_a_rectangle_position_with_interval_orientation_and_velocity_reads_at_its_middle(tmp_path):
    # The A9 shape: the XSD's "position" is a point or rectangles/circles/polygons/lanelets; every other
    # value decimalExactOrInterval.  The file was refused with "needs a <position><point>".
    initial = ("<position><rectangle><length>2</length><width>1</width><orientation>0.3</orientation>"
               "<center><x>10</x><y>1</y></center></rectangle></position>"
               + interval("orientation", 0.1, 0.3) + exact("time", 0) + interval("velocity", 20, 24))
    states = (f"<state>{point(12.2, 1)}{exact('orientation', 0.2)}{exact('time', 1)}{exact('velocity', 22)}</state>")
    s = read_commonroad(write(tmp_path, obstacle_2018b(3536, initial, states), "2018b"))
    ob = s.obstacles[3536]
    st = ob.initial
    assert (st.x, st.y) == (10.0, 1.0)                       # the rectangle's centre
    assert st.orientation == pytest.approx(0.2) and st.velocity == 22.0  # the intervals' middles
    # the set stays for the conservative checks
    (shape,) = st.set.position
    assert isinstance(shape, Rectangle) and (shape.length, shape.width, shape.orientation) == (2.0, 1.0, 0.3)
    assert st.set.interval("orientation") == Interval(0.1, 0.3) and st.set.interval("velocity") == Interval(20, 24)
    assert st.set.interval("acceleration") is None
    assert ob.trajectory.at(0).set is st.set and ob.trajectory.at(1).set is None
    assert ob.trajectory.x.tolist() == [10.0, 12.2]
    notes = {n.what: n for n in s.notes}
    assert notes["states with position as shapes"].count == 1 and notes["states with position as shapes"].action == "assumed"
    assert notes["states with orientation as an interval"].count == 1
    assert notes["states with velocity as an interval"].line == line_of(s.path, "<initialState>")


def test_a_circle_position_is_its_centre_and_a_polygon_its_centroid(tmp_path):
    circle = "<position><circle><radius>3</radius><center><x>5</x><y>-1</y></center></circle></position>"
    # an L-shaped polygon: its centroid is not its vertices' mean
    poly = ("<position><polygon>" + "".join(f"<point><x>{x}</x><y>{y}</y></point>" for x, y in
                                            [(0, 0), (2, 0), (2, 1), (1, 1), (1, 2), (0, 2)]) + "</polygon></position>")
    body = (obstacle_2018b(1, circle + exact("orientation", 0) + exact("time", 0))
            + obstacle_2018b(2, poly + exact("orientation", 0) + exact("time", 0)))
    s = read_commonroad(write(tmp_path, body.replace("dynamic", "static"), "2018b"))
    assert (s.obstacles[1].initial.x, s.obstacles[1].initial.y) == (5.0, -1.0)
    assert isinstance(s.obstacles[1].initial.set.position[0], Circle)
    # centroid of the L (three unit squares at (0.5,0.5), (1.5,0.5), (0.5,1.5)): (5/6, 5/6)
    assert (s.obstacles[2].initial.x, s.obstacles[2].initial.y) == pytest.approx((5 / 6, 5 / 6))
    assert isinstance(s.obstacles[2].initial.set.position[0], Polygon)


def test_several_shapes_and_a_lanelet_as_position(tmp_path):
    two = ("<position><rectangle><length>2</length><width>2</width><center><x>0</x><y>0</y></center></rectangle>"
           "<rectangle><length>6</length><width>2</width><center><x>10</x><y>0</y></center></rectangle></position>")
    lanelet = '<position><lanelet ref="1"/></position>'
    body = (obstacle_2018b(1, two + exact("orientation", 0) + exact("time", 0))
            + obstacle_2018b(2, lanelet + exact("orientation", 0) + exact("time", 0)))
    s = read_commonroad(write(tmp_path, body.replace("dynamic", "static"), "2018b"))
    # area-weighted: (4 * 0 + 12 * 10) / 16
    assert s.obstacles[1].initial.x == pytest.approx(7.5) and len(s.obstacles[1].initial.set.position) == 2
    lane = s.obstacles[2].initial
    assert (lane.x, lane.y) == pytest.approx((20.0, 0.0))  # the lanelet's centroid
    np.testing.assert_array_equal(lane.set.position[0].vertices, s.lanelets[1].polygon)
    assert any(n.what == "states with position as lanelets" for n in s.notes)


def test_a_planning_problems_interval_initial_state_starts_at_the_middle(tmp_path):
    body = ('<planningProblem id="5"><initialState>' + point(5, 0) + exact("orientation", 0) + exact("time", 0)
            + interval("velocity", 8, 12) + exact("yawRate", 0) + exact("slipAngle", 0) + "</initialState>"
            + "<goalState>" + interval("time", 10, 20) + "</goalState></planningProblem>")
    pp = planning_problem(read_commonroad(write(tmp_path, body)), 5)
    assert pp.initial.velocity == 10.0 and pp.initial.set.interval("velocity") == Interval(8, 12)


@pytest.mark.parametrize("bad, message", [
    (interval("velocity", 1, "INF"), r"<velocity> at time step 0: the interval \[1, inf\] is open"),
    ('<foo/>', None),  # an unknown element is counted, not refused
])
def test_an_open_interval_in_a_state_is_refused_an_unknown_field_counted(tmp_path, bad, message):
    path = write(tmp_path, obstacle_2018b(7, point(0, 0) + exact("orientation", 0) + exact("time", 0) + bad).replace(
        "dynamic", "static"), "2018b")
    if message:
        with pytest.raises(CommonRoadError, match=r'q\.xml:\d+: <obstacle id="7">: ' + message):
            read_commonroad(path)
    else:
        notes = read_commonroad(path).notes
        assert any(n.action == "skipped" and n.what == "<foo> of states" for n in notes)


def test_a_position_with_nothing_in_it_names_the_state(tmp_path):
    path = write(tmp_path, obstacle_2018b(7, "<position></position>" + exact("orientation", 0) + exact("time", 0))
                 .replace("dynamic", "static"), "2018b")
    with pytest.raises(CommonRoadError, match=r'<obstacle id="7">: <initialState> at time step 0: <position> holds '
                                              r"no <point>, shape"):
        read_commonroad(path)


# ---------------------------------------------------------------- point-mass states

def test_a_point_mass_state_heads_along_its_velocity(tmp_path):
    # commonroad-io's PMState: velocity is the x component, velocityY the y; no orientation
    states = f"<state>{point(1, 1)}{exact('time', 1)}{exact('velocity', 3)}{exact('velocityY', 4)}</state>"
    s = read_commonroad(write(tmp_path, obstacle_2018b(1, point(0, 0) + exact("orientation", 0) + exact("time", 0)
                                                       + exact("velocity", 5), states), "2018b"))
    st = s.obstacles[1].trajectory.at(1)
    assert st.velocity == 5.0 and st.orientation == pytest.approx(math.atan2(4, 3))
    assert any(n.what.startswith("point-mass states") and n.count == 1 for n in s.notes)


def test_with_an_orientation_velocity_stays_the_speed_and_velocity_y_is_dropped(tmp_path):
    states = (f"<state>{point(1, 0)}{exact('orientation', 0.1)}{exact('time', 1)}{exact('velocity', 3)}"
              f"{exact('velocityY', 4)}</state>")
    s = read_commonroad(write(tmp_path, obstacle_2018b(1, point(0, 0) + exact("orientation", 0) + exact("time", 0),
                                                       states), "2018b"))
    st = s.obstacles[1].trajectory.at(1)
    assert (st.velocity, st.orientation) == (3.0, 0.1)


# ---------------------------------------------------------------- occupancy sets

def occupancy(shape: str, time: str) -> str:
    return f"<occupancy><shape>{shape}</shape>{time}</occupancy>"


def test_an_occupancy_set_obstacle_reads_its_shapes_per_step(tmp_path):
    circle = "<circle><radius>1</radius><center><x>20</x><y>0</y></center></circle>"
    body = ('<dynamicObstacle id="9"><type>unknown</type><shape>' + RECT + "</shape><initialState>" + point(0, 0)
            + exact("orientation", 0) + exact("time", 0) + "</initialState><occupancySet>"
            + occupancy(circle + RECT, interval("time", 3, 5))  # two shapes over steps 3..5
            + occupancy(RECT, exact("time", 1))                 # out of order in the file
            + "</occupancySet></dynamicObstacle>")
    s = read_commonroad(write(tmp_path, body))
    ob = s.obstacles[9]
    assert ob.set_based and len(ob.trajectory) == 1
    assert [(o.start, o.end, len(o.shapes)) for o in ob.occupancy] == [(1, 1, 1), (3, 5, 2)]
    assert isinstance(ob.occupancy[1].shapes[0], Circle)
    assert any(n.what == "obstacles given by <occupancySet>" and n.count == 1 for n in s.notes)


def test_an_empty_occupancy_is_refused_at_its_line(tmp_path):
    body = ('<dynamicObstacle id="9"><type>unknown</type><shape>' + RECT + "</shape><initialState>" + point(0, 0)
            + exact("orientation", 0) + exact("time", 0) + "</initialState><occupancySet>"
            + occupancy("", exact("time", 1)) + "</occupancySet></dynamicObstacle>")
    with pytest.raises(CommonRoadError, match=r'<dynamicObstacle id="9">: <occupancy> at line \d+ holds no shape'):
        read_commonroad(write(tmp_path, body))


def test_a_trajectory_state_over_a_time_interval_is_refused(tmp_path):
    states = f"<state>{point(1, 0)}{exact('orientation', 0)}{interval('time', 1, 3)}</state>"
    with pytest.raises(CommonRoadError, match=r"its <time> is the interval \[1, 3\]: a state of a trajectory needs "
                                              r"one time step \(a set over time is an <occupancySet>\)"):
        read_commonroad(write(tmp_path, obstacle_2018b(1, point(0, 0) + exact("orientation", 0) + exact("time", 0),
                                                       states), "2018b"))


# ---------------------------------------------------------------- skipped elements

def test_environment_and_phantom_obstacles_are_skipped_and_said(tmp_path):
    body = ('<environmentObstacle id="50"><type>building</type><shape>' + RECT + "</shape></environmentObstacle>"
            '<phantomObstacle id="51"><occupancySet>' + occupancy(RECT, exact("time", 1))
            + "</occupancySet></phantomObstacle>")
    s = read_commonroad(write(tmp_path, body))
    assert s.obstacles == {}
    skipped = {n.what: n for n in s.notes if n.action == "skipped"}
    assert skipped["<environmentObstacle>"].count == 1 and "neither replayed nor collided" in skipped["<environmentObstacle>"].why
    line = line_of(s.path, "<phantomObstacle")
    assert skipped["<phantomObstacle>"].line == line
    assert f"skipped 1 <phantomObstacle> (first at line {line}): " in skipped["<phantomObstacle>"].render()


def test_3d_points_read_as_planar_and_the_heights_are_counted(tmp_path):
    lanelet = LANELET.replace("<y>2</y></point>", "<y>2</y><z>7.5</z></point>")
    path = tmp_path / "z.xml"
    path.write_text(HEAD.format(v="2020a") + lanelet + "</commonRoad>\n")
    s = read_commonroad(path)
    assert s.lanelets[1].left.tolist() == [[0.0, 2.0], [40.0, 2.0]]
    (note,) = [n for n in s.notes if n.what == "<z> coordinates"]
    assert (note.action, note.count, note.line) == ("skipped", 2, line_of(path, "<z>"))


# ---------------------------------------------------------------- the shared files

def test_every_shared_file_reads_and_says_what_it_read(shared_data):
    files = sorted((shared_data / "commonroad").glob("*.xml"))
    assert len(files) >= 18
    for path in files:
        s = read_commonroad(path)
        actions = {n.action for n in s.notes}
        assert "read" in actions, path.name
        lanelets = [n for n in s.notes if n.what == "<lanelet>"]
        assert lanelets[0].count == len(s.lanelets), path.name
        for n in s.notes:
            assert n.why and n.count >= 0 and n.render().startswith(n.action), (path.name, n)


def test_the_format_coverage_files_read_what_commonroad_io_reads(shared_data):
    d = shared_data / "commonroad"
    # the two occupancy-set files that were refused
    for name, first in (("test_reading_obstacles.xml", ["Rectangle"]), ("test_reading_all.xml", [])):
        s = read_commonroad(d / name)
        ob = s.obstacles[1]
        steps = list(range(1 - len(first), 4))
        assert ob.set_based and [(o.start, o.end) for o in ob.occupancy] == [(t, t) for t in steps]
        assert [type(o.shapes[0]).__name__ for o in ob.occupancy] == first + ["Circle", "Polygon", "Circle"]
        assert s.obstacles[2].trajectory.t.tolist() == [0, 1] and not s.obstacles[2].set_based
    all_notes = {n.what for n in read_commonroad(d / "test_reading_all.xml").notes}
    assert {"<environmentObstacle>", "<phantomObstacle>", "signal states (indicators, brake lights)"} <= all_notes
    # every state type: ks/st/std/custom keep velocity and orientation; pm derives them
    ks = read_commonroad(d / "test_reading_ks_state.xml").obstacles
    pm = read_commonroad(d / "test_reading_pm_state.xml").obstacles
    (oid,) = ks
    for t in pm[oid].trajectory.t[1:]:
        assert math.isfinite(pm[oid].trajectory.at(int(t)).orientation)
    for name in ("test_reading_st_state.xml", "test_reading_std_state.xml", "test_reading_custom_state.xml"):
        other = read_commonroad(d / name).obstacles[oid].trajectory
        np.testing.assert_array_equal(other.orientation, ks[oid].trajectory.orientation)
    heights = [n for n in read_commonroad(d / "test_3d_points.xml").notes if n.what == "<z> coordinates"]
    assert heights and heights[0].count == 40
