"""The nuPlan score's compiled kernels (metrics.nuplan_score.kernels) give the numpy paths' numbers bit for
bit: on a random map of overlapping, irregular lanes with an ego weaving across and off them among agents
in all directions, every term, its frames, places and series agree exactly."""
from __future__ import annotations

import numpy as np
import pytest

from pytest_driveeval.metrics.nuplan_score import kernels, score_scene
from pytest_driveeval.metrics.nuplan_score.case import inputs_from_case
from pytest_driveeval.metrics.nuplan_score.lanes import ScoreMap

from nuplan_cases import DT, FRAMES, case

pytestmark = pytest.mark.skipif(not kernels.AVAILABLE, reason="numba is not installed: only the numpy paths run")


def _lane(rng, x0, y0, heading, length=40.0, width=3.5):
    s = np.linspace(0.0, length, 9)
    bend = rng.normal(0.0, 0.02)
    angle = heading + bend * s
    centre = np.stack([x0 + np.cumsum(np.cos(angle)) * length / 9, y0 + np.cumsum(np.sin(angle)) * length / 9], 1)
    normal = np.stack([-np.sin(angle), np.cos(angle)], 1) * width / 2
    polygon = np.concatenate([centre + normal, (centre - normal)[::-1]])
    return polygon.tolist(), centre.tolist()


def random_case(seed: int) -> dict:
    rng = np.random.default_rng(seed)
    lanes = []
    for n in range(30):
        polygon, baseline = _lane(rng, rng.uniform(-20, 140), rng.uniform(-15, 15), rng.uniform(-np.pi, np.pi))
        lanes.append({"id": f"l{n}", "polygon": polygon, "baseline": baseline, "speed_limit": float(rng.uniform(5, 15)),
                      "roadblock": f"rb{n}", "connector": bool(n % 3 == 0), "incoming": [],
                      "outgoing": [f"l{(n + 1) % 30}"]})
    t = np.arange(FRAMES) * DT
    x = 10.0 * t
    y = 6.0 * np.sin(t / 1.5)
    heading = np.arctan2(np.gradient(y), np.gradient(x))
    agents = []
    for k in range(12):
        start = rng.uniform(0, 140)
        angle = rng.uniform(-np.pi, np.pi)
        v = rng.uniform(0, 12)
        ax, ay = start + v * np.cos(angle) * t, rng.uniform(-8, 8) + v * np.sin(angle) * t
        agents.append({"token": f"a{k}", "type": ("vehicle", "pedestrian", "generic_object")[k % 3],
                       "length": 4.5, "width": 2.0, "frames": list(range(FRAMES)),
                       "center": np.stack([ax, ay, np.full(FRAMES, angle)], 1).tolist(),
                       "velocity": np.tile([v * np.cos(angle), v * np.sin(angle)], (FRAMES, 1)).tolist()})
    spec = case(f"random-{seed}", x, y=y, heading=heading, speed=np.full(FRAMES, 10.0))
    spec["agents"] = agents
    spec["map"] = {"lanes": lanes, "roadblocks": [{"id": f"rb{n}", "polygon": lanes[n]["polygon"],
                                                    "connector": lanes[n]["connector"]} for n in range(30)],
                   "drivable_area": [lanes[0]["polygon"]], "intersections": [lanes[5]["polygon"]]}
    return spec


def _plain(result) -> dict:
    out = {"score": result.score}
    for name, term in result.terms.items():
        fields = dict(vars(term))
        fields["series"] = {k: np.asarray(v).tolist() for k, v in term.series.items()}
        out[name] = fields
    return out


@pytest.mark.parametrize("seed", range(4))
def test_the_compiled_paths_score_as_the_numpy_paths_do(seed, monkeypatch):
    spec = random_case(seed)
    monkeypatch.setattr(kernels, "wanted", lambda: False)
    numpy_result = score_scene(inputs_from_case(spec))
    monkeypatch.setattr(kernels, "wanted", lambda: True)
    compiled = score_scene(inputs_from_case(spec))
    assert _plain(compiled) == _plain(numpy_result)
    # the case reaches the kernels' work: lanes held, corners off, and agents close enough to step
    assert any(numpy_result.terms[n].frames for n in ("drivable_area_compliance", "time_to_collision_within_bound"))


def test_each_kernel_agrees_with_its_numpy_path(monkeypatch):
    rng = np.random.default_rng(7)
    inputs = inputs_from_case(random_case(9))
    score_map: ScoreMap = inputs.map
    points = rng.uniform([-30, -25], [160, 25], size=(2000, 2))
    lane_of = rng.integers(0, score_map.num_lanes, size=len(points))
    routes = [rng.choice(score_map.num_lanes, size=rng.integers(0, 3), replace=False).tolist() for _ in points]
    answers = []
    for compiled in (False, True):
        monkeypatch.setattr(kernels, "wanted", lambda compiled=compiled: compiled)
        answers.append((score_map.lanes_at(points), score_map.in_drivable(points),
                        score_map.distance_to_drivable(points, 3.0), score_map.distance_to_lanes(points, routes, 3.0),
                        score_map.along(points, lane_of), score_map.directions(points, lane_of)))
    for numpy_answer, compiled_answer in zip(*answers):
        np.testing.assert_array_equal(compiled_answer, numpy_answer)
    assert answers[0][0].any() and np.isfinite(answers[0][2]).any()


def test_the_process_takes_the_compiled_paths_once_the_numpy_paths_cost_numbas_start(monkeypatch):
    monkeypatch.setattr(kernels, "_forgone", 0.0)
    monkeypatch.setitem(__import__("sys").modules, "numba", None)  # not loaded by anyone
    monkeypatch.setattr(kernels, "AVAILABLE", True)
    assert not kernels.wanted()
    kernels.spent_without(kernels.START_SECONDS / kernels.SAVED_SHARE * 1.01)
    assert kernels.wanted()


def test_the_cells_dropped_as_unable_to_meet_could_not_have_met():
    from pytest_driveeval.metrics.nuplan_score import ttc

    inputs = inputs_from_case(random_case(3))
    ego, agents = inputs.ego, inputs.agents
    moving = ego.speed > ttc.STOPPED_SPEED
    usable = agents.available & moving[:, None]
    kept = np.zeros_like(usable)
    kept[ttc._candidates(ego, agents, moving, [])] = True
    dropped = np.nonzero(usable & ~kept)
    assert len(dropped[0]) and kept.sum() < usable.sum()
    assert (ttc._first_meetings(ego, agents, *dropped) == -1).all()
    assert (ttc._first_meetings(ego, agents, *np.nonzero(kept)) >= 0).any()
