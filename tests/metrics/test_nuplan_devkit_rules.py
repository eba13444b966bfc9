"""nuplan-devkit's own rules inside the score, one small synthetic case per rule; each expected value is
worked out from the devkit's source (docs/nuplan_score.md §1, §3.1, §3.3, §3.4, §3.7): its collision
types and blame, its route extractor (connectors in the map's order, the 5 m rule, the backward cut),
and its progress along the roadblocks of the expert's route."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from pytest_driveeval.geometry.boxes import segment_meets_box
from pytest_driveeval.metrics.nuplan_score import score_scene
from pytest_driveeval.metrics.nuplan_score.case import inputs_from_case, map_from_case
from pytest_driveeval.metrics.nuplan_score.collisions import nuplan_collisions
from pytest_driveeval.metrics.nuplan_score.progress import _Progress, expert_progress
from pytest_driveeval.metrics.nuplan_score.route import centre_route, corners_in_one_lane, lanes_lists

from nuplan_cases import DT, FRAMES, agent, case, cruising

T = np.arange(FRAMES) * DT


def strip(lane_id, x0, x1, y0=-2.0, y1=2.0, *, backwards=False, connector=True, outgoing=(), speed_limit=None):
    """A rectangular lane x0..x1, y0..y1, its baseline along the middle (against +x if ``backwards``)."""
    ym = (y0 + y1) / 2
    baseline = [[x1, ym], [x0, ym]] if backwards else [[x0, ym], [x1, ym]]
    return {"id": lane_id, "polygon": [[x0, y0], [x1, y0], [x1, y1], [x0, y1]], "baseline": baseline,
            "speed_limit": speed_limit, "roadblock": f"rb-{lane_id}", "connector": connector,
            "incoming": [], "outgoing": list(outgoing)}


def on_map(spec: dict, lanes: list[dict]) -> dict:
    """The case on these lanes, each in a roadblock of its own (its polygon the lane's), as compare_scenes
    exports ScenarioNet's lanes; incoming edges from the outgoing ones."""
    for lane in lanes:
        lane["incoming"] = [other["id"] for other in lanes if lane["id"] in other["outgoing"]]
    spec["map"] = {"lanes": lanes, "drivable_area": [lane["polygon"] for lane in lanes], "intersections": [],
                   "roadblocks": [{"id": lane["roadblock"], "polygon": lane["polygon"], "connector": lane["connector"]}
                                  for lane in lanes]}
    return spec


def collisions_term(spec: dict):
    return score_scene(inputs_from_case(spec)).terms["no_ego_at_fault_collisions"]


# ---------------------------------------------------------------- collisions (§3.1)

def test_a_static_object_hit_is_a_stopped_track_collision_counted_once_with_its_later_contacts_said():
    """The cone spans x 59.75..60.25 and the ego's box its centre +-2.588 m: they overlap while the centre is in
    57.162..62.838, frames at x = 58..62 (1 m a frame).  nuPlan counts the first (an object: 1 - 1/2 = 0.5); the
    term says the other 4 are not counted."""
    spec = case("cone", cruising(), agents=[agent("c", "traffic_cone", (60.0, 0.0))])
    term = collisions_term(spec)
    assert term.value == 0.5
    assert term.detail["at_fault_object"] == 1
    assert "stopped track" in term.message and "counted once per agent, as nuPlan counts" in term.message
    assert "4 later contact frame(s) with agent 0 not counted" in term.message


def test_running_into_a_slower_vehicle_is_an_active_front_collision_at_fault():
    spec = case("front", cruising(), agents=[agent("v", "vehicle", (40.0, 0.0), speed=5.0, length=4.0, width=2.0)])
    inputs = inputs_from_case(spec)
    found, _ = nuplan_collisions(inputs, np.ones(FRAMES, bool))
    assert [(c.kind, c.at_fault, c.group) for c in found] == [("active front", True, "vehicle")]
    assert score_scene(inputs).terms["no_ego_at_fault_collisions"].value == 0.0


def test_a_vehicle_closing_from_behind_is_an_active_rear_collision_not_at_fault():
    spec = case("rear", cruising(), agents=[agent("v", "vehicle", (-10.0, 0.0), speed=20.0, length=4.0, width=2.0)])
    term = collisions_term(spec)
    assert term.value == 1.0 and "active rear" in term.message and "not at fault" in term.message


def test_a_stopped_ego_hit_is_never_at_fault():
    spec = case("stopped", np.full(FRAMES, 10.0), speed=np.zeros(FRAMES), expert_speed=0.0,
                agents=[agent("v", "vehicle", (30.0, 0.0), heading=np.pi, speed=5.0, length=4.0, width=2.0)])
    term = collisions_term(spec)
    assert term.value == 1.0 and "stopped ego" in term.message


@pytest.mark.parametrize("ego_y, at_fault", [(0.0, False), (1.5, True)])
def test_a_side_swipe_is_at_fault_only_where_the_ego_is_not_inside_one_lane(ego_y, at_fault):
    """A vehicle alongside drifts into the ego's side (never ahead of its front bumper): ACTIVE_LATERAL, at
    fault only on frames where the corners are not all in one lane (at y = 1.5 two corners are off the 4 m
    lane)."""
    drift = agent("v", "vehicle", (10.0, ego_y + 3.5), heading=-0.05, speed=10.0, length=4.0, width=2.0)
    spec = case("side", cruising(), y=np.full(FRAMES, ego_y), agents=[drift])
    inputs = inputs_from_case(spec)
    result = score_scene(inputs)
    assert "active lateral" in result.terms["no_ego_at_fault_collisions"].message
    assert result.terms["no_ego_at_fault_collisions"].value == (0.0 if at_fault else 1.0)


def test_the_engines_blame_stays_available_by_name():
    spec = case("cone", cruising(), agents=[agent("c", "traffic_cone", (60.0, 0.0))])
    inputs = inputs_from_case(spec)
    engine = dataclasses.replace(inputs, blame="engine", collisions=[])
    assert score_scene(inputs).terms["no_ego_at_fault_collisions"].value == 0.5
    assert score_scene(engine).terms["no_ego_at_fault_collisions"].value == 1.0
    with pytest.raises(ValueError, match="blame 'mine': one of nuplan, engine"):
        dataclasses.replace(inputs, blame="mine")


def test_the_front_bumper_touching_a_box_counts_as_meeting_it():
    box = (np.array([0.0, 0.0]), 0.0, np.array([2.0, 2.0]))
    assert segment_meets_box(np.array([1.0, -3.0]), np.array([1.0, 3.0]), *box)  # along an edge
    assert segment_meets_box(np.array([2.0, 0.0]), np.array([1.0, 1.0]), *box)   # through a corner only
    assert not segment_meets_box(np.array([1.01, -3.0]), np.array([1.01, 3.0]), *box)


# ---------------------------------------------------------------- the route (§1)

def test_overlapping_connectors_are_taken_in_the_maps_order():
    """Both connectors hold the ego all along; nuPlan keeps both, in the map's order, and the terms read the
    first: listed first, the one whose baseline runs against the ego makes it drive 11 m backwards within
    1.1 s (driving direction 0); listed second, it changes nothing."""
    forward, backward = strip("fwd", 0, 500), strip("bwd", 0, 500, backwards=True)
    first_backward = on_map(case("dir", cruising()), [backward, forward])
    first_forward = on_map(case("dir", cruising()), [forward, backward])
    assert score_scene(inputs_from_case(first_backward)).terms["driving_direction_compliance"].value == 0.0
    assert score_scene(inputs_from_case(first_forward)).terms["driving_direction_compliance"].value == 1.0


def test_a_connector_left_is_kept_while_the_ego_is_within_5_m_of_it():
    """The ego leaves connector a (x <= 50) into b, which a does not lead into: nuPlan keeps a while the
    ego's centre is less than 5 m from a's polygon."""
    score_map = map_from_case({"lanes": [strip("a", 0, 50), strip("b", 50, 100)]})
    x = np.arange(40.0, 60.0, 0.5) + 0.25
    route = centre_route(score_map, np.stack([x, np.zeros_like(x)], 1))
    assert [r[0] for r in route] == [0 if xi < 55 else 1 for xi in x]


def test_connectors_in_doubt_are_cut_back_to_the_one_the_ego_ends_up_in():
    """a and b overlap at the start, then only b goes on: going backwards, nuPlan replaces each frame's
    [a, b] by its successor's [b], so the whole route is b (both baselines point along the ego)."""
    score_map = map_from_case({"lanes": [strip("a", 0, 20), strip("b", 0, 100)]})
    x = np.arange(10.0, 40.0, 1.0)
    route = centre_route(score_map, np.stack([x, np.zeros_like(x)], 1))
    assert all(r == [1] for r in route)


def test_a_lane_leading_into_the_next_keeps_the_corners_in_one_lane():
    """Rear corners on a, front corners on b, a leads into b: nuPlan's "connected" objects, so the frame is
    in one lane; without the link the ego straddles."""
    linked = map_from_case({"lanes": [strip("a", 0, 50, outgoing=["b"]), strip("b", 50, 100)]})
    unlinked = map_from_case({"lanes": [strip("a", 0, 50), strip("b", 50, 100)]})
    corners = np.array([[[52.0, 1.0], [52.0, -1.0], [48.0, -1.0], [48.0, 1.0]]])  # FL, FR, RR, RL
    assert corners_in_one_lane(linked, corners).tolist() == [True]
    assert corners_in_one_lane(unlinked, corners).tolist() == [False]


def test_a_connector_without_edges_keeps_its_own_speed_limit():
    speed = np.full(FRAMES, 10.0)
    speed[40:70] = 15.0 + 2.23
    spec = on_map(case("speeding", cruising(), speed=speed), [strip("c", 0, 500, speed_limit=15.0)])
    assert score_scene(inputs_from_case(spec)).terms["speed_limit_compliance"].value == pytest.approx(0.8)


# ---------------------------------------------------------------- progress (§3.4)

def two_roadblocks():
    return [strip("l1", 0, 80, outgoing=["l2"]), strip("l2", 80, 200), strip("side", 0, 200, 2.0, 6.0)]


def test_progress_is_measured_along_the_roadblocks_of_the_experts_route():
    """The expert drives 150 m through l1 into l2; an ego at half its speed makes 75 m along them."""
    spec = on_map(case("half", cruising(5.0)), two_roadblocks())
    term = score_scene(inputs_from_case(spec)).terms["ego_progress_along_expert_route"]
    assert term.detail["expert_progress"] == pytest.approx(150.0)
    assert term.value == pytest.approx(0.5)


def test_an_ego_outside_the_experts_roadblocks_makes_no_progress():
    """The ego drives as far as the expert, but in the neighbouring lane, in none of the route's
    roadblocks: nuPlan counts 0 m, so the ratio is 2 / 150 (the path-projection stand-in said 1)."""
    spec = on_map(case("beside", cruising(), y=np.full(FRAMES, 4.0)), two_roadblocks())
    term = score_scene(inputs_from_case(spec)).terms["ego_progress_along_expert_route"]
    assert term.detail["ego_progress"] == 0.0
    assert term.value == pytest.approx(2.0 / 150.0)


def test_a_roadblock_the_ego_jumps_over_still_counts_its_stretch():
    """l2 (x 60.5..61.9) lies between two frames of an ego moving 2 m a frame: nuPlan adds the rest of l1,
    the stretch of the skipped l2 and the way into l3; along collinear baselines that is the distance."""
    score_map = map_from_case({"lanes": [strip("l1", 0, 60.5), strip("l2", 60.5, 61.9), strip("l3", 61.9, 400)]})
    x = np.arange(50.0, 80.0, 2.0)
    points = np.stack([x, np.zeros_like(x)], 1)
    steps = _Progress(score_map, [(0, 0), (1, 1), (2, 2)], points, lanes_lists(score_map.lanes_at(points)))()
    assert steps[6] == pytest.approx(2.0)  # from x = 60 (l1) to x = 62 (l3)
    assert sum(steps) == pytest.approx(x[-1] - x[0])


def test_an_expert_never_on_a_lane_gives_one():
    spec = on_map(case("parking", cruising(1.0)), [strip("far", 0, 500, 50.0, 54.0)])
    term = expert_progress(inputs_from_case(spec))
    assert term.value == 1.0 and "never on a lane" in term.reason


# ---------------------------------------------------------------- the same cases in nuplan-devkit

def own_edges(spec: dict) -> dict:
    """nuPlan's speed limit takes max() over a connector's edges, which raises on a connector without any:
    such a connector gets itself as its edge, as compare_scenes exports it (the harness reads it the same)."""
    for lane in (spec["map"] or {}).get("lanes", []):
        if lane["connector"] and not lane["incoming"] and not lane["outgoing"]:
            lane["incoming"], lane["outgoing"] = [lane["id"]], [lane["id"]]
    return spec


def devkit_cases() -> list[dict]:
    drift = agent("v", "vehicle", (10.0, 5.0), heading=-0.05, speed=10.0, length=4.0, width=2.0)
    speed = np.full(FRAMES, 10.0)
    speed[40:70] = 15.0 + 2.23
    named = {
        "cone": case("", cruising(), agents=[agent("c", "traffic_cone", (60.0, 0.0))]),
        "front": case("", cruising(), agents=[agent("v", "vehicle", (40.0, 0.0), speed=5.0, length=4.0, width=2.0)]),
        "rear": case("", cruising(), agents=[agent("v", "vehicle", (-10.0, 0.0), speed=20.0, length=4.0, width=2.0)]),
        "side straddling": case("", cruising(), y=np.full(FRAMES, 1.5), agents=[drift]),
        "backward connector first": on_map(case("", cruising()), [strip("bwd", 0, 500, backwards=True),
                                                                  strip("fwd", 0, 500)]),
        "edgeless connector": on_map(case("", cruising(), speed=speed), [strip("c", 0, 500, speed_limit=15.0)]),
        "half progress": on_map(case("", cruising(5.0)), two_roadblocks()),
        "beside the route": on_map(case("", cruising(), y=np.full(FRAMES, 4.0)), two_roadblocks()),
    }
    return [{**own_edges(spec), "name": name} for name, spec in named.items()]


def test_nuplan_devkit_scores_these_cases_as_the_harness_does():
    from conftest import REPO_ROOT, module_at
    from pytest_driveeval.metrics.nuplan_score.case import answer

    venv = module_at(REPO_ROOT / "benchmarks" / "nuplan_oracle" / "oracle_venv.py", "nuplan_oracle_venv")
    python = venv.existing_python()
    if python is None:
        pytest.skip("nuplan-devkit oracle venv absent (python benchmarks/nuplan_oracle/oracle_venv.py builds it)")
    cases = devkit_cases()
    differences = []
    for case_, theirs in zip(cases, venv.run_metrics(cases, python)):
        assert "error" not in theirs, theirs
        ours = answer(case_)
        for name, value in theirs["metrics"].items():
            if name in ours["metrics"] and abs(ours["metrics"][name] - value) > 1e-6:
                differences.append(f"{case_['name']}: {name} ours {ours['metrics'][name]} nuplan {value}")
    assert not differences, "\n".join(differences)
