"""Our CommonRoad reader and goal test against commonroad-io 2026.1, in its own venv
(benchmarks/commonroad_oracle/oracle_venv.py makes it; skipped where it is absent), on the four real files.

commonroad-io fills fields a file leaves out (acceleration, yaw rate, slip angle) with 0.0 where we keep
nan, so a field is compared where the file gives it, and checked to be 0.0 on its side where not.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from conftest import REPO_ROOT, module_at
from pytest_driveeval.io.commonroad.commonroad import read_commonroad
from pytest_driveeval.io.commonroad.commonroad_geometry import goal_reached, lanelets_at, obstacle_outline
from pytest_driveeval.io.commonroad.commonroad_types import Circle, Polygon, Rectangle

FILES = ["FRA_Anglet-1_1_T-1", "USA_Lanker-1_1_T-1", "USA_US101-3_3_T-1", "ZAM_Tutorial-1_2_T-1"]


ORACLE = module_at(REPO_ROOT / "benchmarks" / "commonroad_oracle" / "oracle_venv.py", "commonroad_oracle_venv")


@pytest.fixture(scope="module")
def oracle_python():
    python = ORACLE.existing_python()
    if python is None:
        pytest.skip(f"commonroad-io's venv absent: run python {ORACLE.__file__} to make {ORACLE.VENV}")
    return python


def goal_grid(problem) -> list[dict]:
    """States around each goal state: a 9 x 9 position grid over the goal's positions (or the ego's start)
    widened by 2 m, times at and beside the time interval's ends, speeds at and beside the velocity
    interval's ends, headings just inside and outside the orientation interval and once round the circle."""
    states = []
    for g in problem.goals:
        outlines = [*g.lanelet_polygons]
        for s in g.shapes:
            if isinstance(s, Polygon):
                outlines.append(s.vertices)
            elif isinstance(s, Circle):
                outlines.append(s.center + s.radius * np.array([[-1, -1], [1, 1]]))
            else:
                half = 0.5 * math.hypot(s.length, s.width)
                outlines.append(s.center + half * np.array([[-1, -1], [1, 1]]))
        pts = np.concatenate(outlines) if outlines else np.array([[problem.initial.x, problem.initial.y]])
        lo, hi = pts.min(axis=0) - 2.0, pts.max(axis=0) + 2.0
        t = g.time or type("T", (), {"start": 0, "end": 0})
        times = sorted({int(t.start) - 1, int(t.start), int(t.end), int(t.end) + 1})
        speeds = [g.velocity.start - 0.5, g.velocity.start, g.velocity.end, g.velocity.end + 0.5] if g.velocity \
            else [problem.initial.velocity]
        o = g.orientation
        headings = ([o.start - 0.05, o.start + 0.01, 0.5 * (o.start + o.end), o.end - 0.01, o.end + 0.05,
                     0.5 * (o.start + o.end) + 2 * math.pi] if o else [problem.initial.orientation])
        for x in np.linspace(lo[0], hi[0], 9):
            for y in np.linspace(lo[1], hi[1], 9):
                for ts in times:
                    for v in speeds:
                        for h in headings:
                            states.append({"planning_problem": problem.id, "x": float(x), "y": float(y),
                                           "orientation": float(h), "velocity": float(v), "time_step": ts})
    return states


def road_points(scenario) -> np.ndarray:
    """A 60 x 60 grid over the lanelets' extent and every bound vertex (on an outline: the edge case)."""
    vertices = np.concatenate([ll.polygon for ll in scenario.lanelets.values()])
    lo, hi = vertices.min(axis=0) - 1.0, vertices.max(axis=0) + 1.0
    gx, gy = np.meshgrid(np.linspace(lo[0], hi[0], 60), np.linspace(lo[1], hi[1], 60))
    return np.concatenate([np.stack([gx.ravel(), gy.ravel()], axis=1), vertices])


@pytest.fixture(scope="module")
def compared(shared_data, oracle_python):
    out = {}
    for name in FILES:
        path = shared_data / "commonroad" / f"{name}.xml"
        ours = read_commonroad(path)
        grid = [s for p in ours.planning_problems.values() for s in goal_grid(p)]
        points = road_points(ours)
        theirs = ORACLE.read_scenario(path, grid, points.tolist(), python=oracle_python)
        out[name] = (ours, grid, points, theirs)
    return out


def close(a, b) -> bool:
    return np.allclose(np.asarray(a, dtype=float), np.asarray(b, dtype=float), rtol=0, atol=1e-9)


@pytest.mark.parametrize("name", FILES)
def test_lanelets_equal(compared, name):
    ours, _, _, theirs = compared[name]
    assert sorted(ours.lanelets) == sorted(ll["id"] for ll in theirs["lanelets"])
    assert ours.dt == theirs["dt"]
    for ll in theirs["lanelets"]:
        mine = ours.lanelets[ll["id"]]
        assert close(mine.left, ll["left"]) and close(mine.right, ll["right"]), ll["id"]
        assert sorted(mine.predecessors) == ll["predecessors"] and sorted(mine.successors) == ll["successors"]
        for side, theirs_side in ((mine.adjacent_left, ll["adjacent_left"]), (mine.adjacent_right, ll["adjacent_right"])):
            assert (None if side is None else [side.id, side.same_direction]) == theirs_side, ll["id"]
        assert mine.speed_limit == ll["speed_limit"], ll["id"]


def state_matches(mine, theirs: dict) -> None:
    assert mine.time_step == theirs["time_step"]
    assert (mine.x, mine.y) == (theirs["x"], theirs["y"])
    for name in ("orientation", "velocity", "acceleration", "yaw_rate", "slip_angle"):
        value = getattr(mine, name)
        if math.isnan(value):
            assert theirs.get(name) in (None, 0.0), name  # commonroad-io's default for an absent field
        else:
            assert value == theirs[name], name


@pytest.mark.parametrize("name", FILES)
def test_obstacles_equal(compared, name):
    ours, _, _, theirs = compared[name]
    assert sorted(ours.obstacles) == sorted(o["id"] for o in theirs["obstacles"])
    states = 0
    for ob in theirs["obstacles"]:
        mine = ours.obstacles[ob["id"]]
        assert (mine.role, mine.type) == (ob["role"], ob["type"])
        shape = ob["shape"]
        assert isinstance(mine.shape, Rectangle) and shape["kind"] == "RectObstacleShape"
        assert (mine.shape.length, mine.shape.width) == (shape["length"], shape["width"])
        assert shape["origin_x_shift"] == 0.0 and mine.shape.center.tolist() == [0.0, 0.0]
        assert len(mine.trajectory) == len(ob["states"])
        for i, st in enumerate(ob["states"]):
            state_matches(mine.trajectory.at(st["time_step"]), {**st, "yaw_rate": None, "slip_angle": None})
            states += 1
        state_matches(mine.initial, ob["states"][0])
    assert states == sum(len(o.trajectory) for o in ours.obstacles.values())


@pytest.mark.parametrize("name", FILES)
def test_planning_problems_equal(compared, name):
    ours, _, _, theirs = compared[name]
    assert sorted(ours.planning_problems) == sorted(p["id"] for p in theirs["planning_problems"])
    for pp in theirs["planning_problems"]:
        mine = ours.planning_problems[pp["id"]]
        theirs_initial = dict(pp["initial"])
        if math.isnan(mine.initial.acceleration):
            # commonroad-io 2026.1 fills an initial state's fields in order and stops at the first one the
            # file leaves out (acceleration, in all four files), so it never reads yawRate and slipAngle and
            # answers its default 0.0 for them; we keep the file's (USA_Lanker: -0.005041 and 0.00004).
            assert (theirs_initial["yaw_rate"], theirs_initial["slip_angle"]) == (0.0, 0.0)
            theirs_initial["yaw_rate"], theirs_initial["slip_angle"] = mine.initial.yaw_rate, mine.initial.slip_angle
        state_matches(mine.initial, theirs_initial)
        assert len(mine.goals) == len(pp["goals"])
        for g, tg in zip(mine.goals, pp["goals"]):
            for field in ("time", "velocity", "orientation"):
                interval = getattr(g, field)
                want = tg.get("time_step" if field == "time" else field)
                assert (None if interval is None else [interval.start, interval.end]) == want, field
            position = tg.get("position")
            if not g.has_position:
                assert position is None
                continue
            shapes = position if isinstance(position, list) else [position]
            assert len(shapes) == len(g.shapes) + len(g.lanelet_polygons)
            for s, ts in zip(g.shapes, shapes):
                if isinstance(s, Rectangle):
                    assert ts["kind"] == "RectOccupancy"
                    assert (s.length, s.width, s.orientation, s.center.tolist()) == (
                        ts["length"], ts["width"], ts["orientation"], ts["rect_center"])
            for outline, ts in zip(g.lanelet_polygons, shapes[len(g.shapes):]):
                assert ts["kind"] == "PolygonOccupancy"
                assert {tuple(p) for p in outline.tolist()} == {tuple(p) for p in ts["polygon"]}


@pytest.mark.parametrize("name", FILES)
def test_goal_reached_equal(compared, name):
    ours, grid, _, theirs = compared[name]
    assert len(theirs["goal_reached"]) == len(grid) > 0
    mine = []
    for s in grid:
        problem = ours.planning_problems[s["planning_problem"]]
        mine.append(goal_reached(problem, s["x"], s["y"], s["orientation"], s["velocity"], s["time_step"]))
    differ = [s for s, a, b in zip(grid, mine, theirs["goal_reached"]) if a != b]
    assert not differ, f"{len(differ)} of {len(grid)} differ, e.g. {differ[:3]}"
    # the grid must meet the goal somewhere and miss it elsewhere, or it tests little
    assert any(mine) and not all(mine)


@pytest.mark.parametrize("name", FILES)
def test_obstacle_outlines_equal(compared, name):
    ours, _, _, theirs = compared[name]
    for ob in theirs["obstacles"]:
        mine = ours.obstacles[ob["id"]]
        for st, outline in zip(ob["states"], ob["outlines"]):
            corners = obstacle_outline(mine, int(st["time_step"]))
            assert len(corners) == len(outline)
            gap = np.linalg.norm(corners[:, None, :] - np.asarray(outline)[None, :, :], axis=2).min(axis=1)
            assert gap.max() < 1e-9, (ob["id"], st["time_step"])


@pytest.mark.parametrize("name", FILES)
def test_lanelets_at_points_equal(compared, name):
    ours, _, points, theirs = compared[name]
    mine = [sorted(ids) for ids in lanelets_at(ours, points[:, 0], points[:, 1])]
    differ = [(p.tolist(), a, b) for p, a, b in zip(points, mine, theirs["lanelets_at"]) if a != b]
    assert not differ, f"{len(differ)} of {len(points)} points differ, e.g. {differ[:3]}"
    assert any(mine) and not all(mine)
