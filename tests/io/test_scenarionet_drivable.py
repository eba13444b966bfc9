"""The drivable area of a ScenarioNet scene from its map's own surfaces and edges, as each converter
writes them (metadriverse/scenarionet @ cebcbe6, scenarionet/converter/*/utils.py): nuScenes' and nuPlan's
outline rings (boundary_<n>), Argoverse 2's rings cut into 20-point pieces, Waymo's road edges, driveways
and measured lane widths; the lane-width stand-in only where the map has none of them."""
import sys
from pathlib import Path

import numpy as np
import pytest
import shapely
from shapely.geometry import Polygon

from pytest_driveeval.io.scenarionet.scenarionet import read_scenario
from pytest_driveeval.metrics.nuplan_score import score_scene
from pytest_driveeval.metrics.nuplan_score.case import inputs_from_case
from pytest_driveeval.io.scenarionet.scenarionet_drivable import STAND_IN, outline_rings
from pytest_driveeval.io.scenarionet.scenarionet_map import scenario_map
from pytest_driveeval.metrics.nuplan_score.road_edges import RoadEdges
from pytest_driveeval.usecases.closed_loop.score import score_map_of

from scenarionet_made import scenario, write

sys.path.insert(0, str(Path(__file__).parents[1] / "metrics"))  # the score's hand-checkable set-up
from nuplan_cases import FRAMES, case  # noqa: E402


def _ring(x0, y0, x1, y1, step=1.0, clockwise=False):
    """A closed rectangle outline with a point every ``step`` metres (first point repeated last)."""
    xs, ys = np.arange(x0, x1, step), np.arange(y0, y1, step)
    ring = np.concatenate([np.stack([xs, np.full_like(xs, y0)], 1), np.stack([np.full_like(ys, x1), ys], 1),
                           np.stack([xs[::-1] + step, np.full_like(xs, y1)], 1),
                           np.stack([np.full_like(ys, x0), ys[::-1] + step], 1)])
    ring = ring[::-1] if clockwise else ring
    return np.concatenate([ring, ring[:1]])


def _scene(tmp_path, features, name="sd_test.pkl"):
    return read_scenario(write(tmp_path, scenario(map_features=features), name))


def _lane(x0=0.0, x1=40.0, y=0.0, **extra):
    return {"type": "LANE_SURFACE_STREET", "polyline": np.stack([np.linspace(x0, x1, 9), np.full(9, y)], 1), **extra}


def test_the_nuscenes_outline_rings_are_the_area_holes_and_all(tmp_path):
    # nuScenes / nuPlan: the union's boundary, each ring one closed boundary_<n> line; ring 1 is a hole
    outer, hole = _ring(-10, -10, 50, 10), _ring(10, 3, 20, 8, clockwise=True)
    features = {"boundary_0": {"type": "ROAD_LINE_SOLID_SINGLE_WHITE", "polyline": outer},
                "boundary_1": {"type": "ROAD_LINE_SOLID_SINGLE_WHITE", "polyline": hole},
                "lane": _lane(), "divider": {"type": "ROAD_LINE_BROKEN_SINGLE_WHITE",
                                             "polyline": np.array([[0.0, 2], [40, 2]])}}
    source = _scene(tmp_path, features)
    made = scenario_map(source)
    assert len(made.drivable.outlines) == 2 and not made.drivable.stand_in
    assert "outline (2 ring(s)" in made.drivable.reason and STAND_IN not in made.drivable.reason
    score_map = score_map_of(source, made)
    inside = score_map.in_drivable(np.array([[0.0, 0], [15, 5], [45, -9], [60, 0], [0, 12]]))
    assert inside.tolist() == [True, False, True, False, False]  # (15, 5) lies in the hole
    # the lane's stand-in surface (no polygon of its own) does not count where the outline is given
    assert score_map.lane_drivable is not None and not score_map.lane_drivable.any()


def test_a_stand_in_lane_leaving_the_outline_counts_and_the_reason_says_so(tmp_path):
    # a lane connector running out of the drivable area (a way into a car park, which ScenarioNet leaves out)
    features = {"boundary_0": {"type": "ROAD_LINE_SOLID_SINGLE_WHITE", "polyline": _ring(-10, -10, 50, 10)},
                "inside": _lane(), "out": _lane(0, 40, 20)}
    source = _scene(tmp_path, features)
    score_map = score_map_of(source, scenario_map(source))
    assert score_map.lane_drivable.tolist() == [False, True]
    assert "1 lane(s) leaving it" in score_map.drivable_reason
    assert score_map.in_drivable(np.array([[20.0, 20.5]])).tolist() == [True]


def test_argoverse2_outline_pieces_join_into_their_ring(tmp_path):
    # Argoverse 2 cuts each ring into 20-point pieces, one after another, the segment between two pieces unwritten
    ring = _ring(0, 0, 30, 12, step=0.5)
    pieces = {f"boundary_0{i}": {"type": "ROAD_LINE_SOLID_SINGLE_WHITE", "polyline": ring[i:i + 20]}
              for i in range(0, len(ring), 20)}
    source = _scene(tmp_path, pieces | {"lane": _lane(2, 28, 6)})
    rings, skipped = outline_rings(source)
    assert skipped is None and len(rings) == 1 and np.array_equal(rings[0], ring)
    # a ring whose last piece is lost (ids such as boundary_1 + 20 and boundary_12 + 0 are written alike, and
    # the later piece replaces the earlier) stays open: an open ring would turn the area inside out, not used
    del pieces[list(pieces)[-1]]
    source = _scene(tmp_path, pieces | {"lane": _lane(2, 28, 6)}, "sd_open.pkl")
    made = scenario_map(source)
    assert made.drivable.outlines == [] and made.drivable.stand_in
    assert "do not close into a ring" in made.drivable.reason and STAND_IN in made.drivable.reason


def test_waymo_road_edges_driveways_and_measured_lane_widths(tmp_path):
    # a road from y = -6 to y = 6 between two edges, the road on each edge's left; a driveway north of it
    south = np.array([[-50.0, -6], [50, -6]])
    north = np.array([[50.0, 6], [-50, 6]])
    width = np.tile([[1.5, 2.0]], (9, 1)).astype(np.float32)  # 1.5 m to the left line, 2 m to the right
    features = {"1": _lane(-40, 40, 0, width=width), "2": _lane(-40, 40, -4),  # lane 2: no boundary measured
                "3": {"type": "ROAD_EDGE_BOUNDARY", "polyline": south},
                "4": {"type": "ROAD_EDGE_MEDIAN", "polyline": north},
                "5": {"type": "DRIVEWAY", "polygon": np.array([[0.0, 6], [4, 6], [4, 12], [0, 12]])}}
    source = _scene(tmp_path, features)
    made = scenario_map(source)
    assert made.width_sources == ("boundaries", "default")
    assert made.lane_widths[0] == pytest.approx(3.5)
    np.testing.assert_allclose(made.semantic.lanes_left[0][:, 1], 1.5, atol=1e-6)
    np.testing.assert_allclose(made.semantic.lanes_right[0][:, 1], -2.0, atol=1e-6)
    score_map = score_map_of(source, made)
    assert "2 road edge(s)" in score_map.drivable_reason and "1 driveway(s)" in score_map.drivable_reason
    np.testing.assert_allclose(score_map.baselines[0][:, 1], 0.0)  # the centre line, not the uneven midline
    points = np.array([[0.0, -5.9], [0, 5.5], [2, 9], [-1, 6.2], [0, -6.5], [10, 9]])
    assert score_map.in_drivable(points).tolist() == [True, True, True, False, False, False]
    distance = score_map.distance_to_drivable(points[3:5], 1.0)
    np.testing.assert_allclose(distance, [0.2, 0.5], atol=1e-9)


def test_only_centre_lines_fall_back_to_the_stand_in_and_say_so(tmp_path):
    source = _scene(tmp_path, {"lane": _lane()})
    score_map = score_map_of(source, scenario_map(source))
    assert score_map.drivable_stand_in and score_map.lane_drivable is None
    assert score_map.drivable_reason == (f"drivable area: {STAND_IN} (the scene's map has no drivable-area outline "
                                         "or road edges)")
    assert score_map.in_drivable(np.array([[5.0, 0.0]])).tolist() == [False]  # asked of points off every lane


def test_road_edges_signed_distance_is_waymos_rule():
    square = np.array([[0.0, 0], [10, 0], [10, 10], [0, 10], [0, 0]])  # anticlockwise: inside on the left
    edges = RoadEdges([square])
    d = edges.signed_distances(np.array([[5.0, 5], [5, -1], [11, 11], [5, 9.5], [-0.5, 5]]))
    np.testing.assert_allclose(d, [-5, 1, np.sqrt(2), -0.5, 0.5])
    # beyond the end of an open edge, its last segment's side decides
    open_edge = RoadEdges([np.array([[0.0, 0], [10, 0]])])
    np.testing.assert_allclose(open_edge.signed_distances(np.array([[12.0, 1], [12, -1]])),
                               [-np.sqrt(5), np.sqrt(5)])
    # a repeated point is dropped; a one-point edge bounds nothing
    assert len(RoadEdges([np.array([[0.0, 0], [0, 0], [1, 0]]), np.array([[3.0, 3]])])) == 1
    assert np.isinf(RoadEdges([]).signed_distances(np.zeros((2, 2)))).all()


def test_the_real_nuscenes_outlines_match_shapely(shared_data):
    for path in sorted((shared_data / "scenarionet" / "nuscenes").glob("*.pkl")):
        source = read_scenario(path)
        made = scenario_map(source)
        boundaries = [f for f in source.map_features if f.id.startswith("boundary_")]
        assert len(made.drivable.outlines) == len(boundaries) > 0, path.name
        score_map = score_map_of(source, made)
        area = Polygon(made.drivable.outlines[0])
        for ring in made.drivable.outlines[1:]:
            area = area.symmetric_difference(Polygon(ring))  # even-odd, as the score takes them
        lo, hi = area.bounds[:2], area.bounds[2:]
        points = np.random.default_rng(0).uniform(lo, hi, (5000, 2))
        np.testing.assert_array_equal(score_map.in_outlines(points),
                                      shapely.contains_xy(area, points[:, 0], points[:, 1]), err_msg=path.name)


def _drive(score_map, y):
    """The score of the hand-checkable set-up (tests/metrics/nuplan_cases.py) on ``score_map``, the ego at
    lateral offset ``y`` throughout."""
    inputs = inputs_from_case(case("drive", 10.0 + np.arange(FRAMES) * 1.0, y=np.full(FRAMES, y)))
    inputs.map = score_map
    return score_scene(inputs).terms["drivable_area_compliance"]


def test_the_terms_reason_names_the_stand_in_and_a_failure_repeats_it(tmp_path):
    source = _scene(tmp_path, {"lane": _lane(0, 300, 0)})
    score_map = score_map_of(source, scenario_map(source))
    on, off = _drive(score_map, 0.0), _drive(score_map, 2.5)  # the stand-in lane is 3.7 m wide
    assert on.value == 1.0 and STAND_IN in on.reason
    assert off.value == 0.0 and off.message.endswith(score_map.drivable_reason)


def test_a_lane_surface_that_is_a_stand_in_does_not_hold_a_corner_the_outline_does_not(tmp_path):
    # the outline is 1.5 m either side of y = 0; the lane's stand-in surface (no polygon) 1.85 m
    outline = _ring(-10, -1.5, 310, 1.5, step=0.5)
    source = _scene(tmp_path, {"boundary_0": {"type": "ROAD_LINE_SOLID_SINGLE_WHITE", "polyline": outline},
                               "lane": _lane(0, 300, 0)})
    score_map = score_map_of(source, scenario_map(source))
    # a 2.297 m wide ego 0.7 m off the middle: a corner 0.35 m past the outline, inside the stand-in
    term = _drive(score_map, 0.7)
    assert term.value == 0.0 and "outline" in term.reason and STAND_IN not in term.reason
    assert term.detail["max_corner_off_drivable_area"] == pytest.approx(0.3485, abs=1e-3)
    assert _drive(score_map, 0.5).value == 1.0  # 0.15 m past it: within nuPlan's 0.3 m
