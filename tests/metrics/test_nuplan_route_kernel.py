"""route.centre_route's compiled loop (metrics.nuplan_score.route_kernel) assigns every frame the lanes its
Python loop assigns, and its first lanes: on the real nuScenes maps of the fixtures (overlapping
connectors, lanes leading into several), with paths that follow the lanes, jump between them, leave
them and come back, and on edge cases (no frame, no lane anywhere, two plain lanes holding a point)."""
from __future__ import annotations

import numpy as np
import pytest

from pytest_driveeval.metrics.nuplan_score import kernels
from pytest_driveeval.metrics.nuplan_score.case import inputs_from_case
from pytest_driveeval.metrics.nuplan_score.route import centre_route, first_lanes

from conftest import REPO_ROOT
from test_nuplan_kernels import random_case

pytestmark = pytest.mark.skipif(not kernels.AVAILABLE, reason="numba is not installed: only the numpy paths run")

SCENES = REPO_ROOT / "fixtures" / "scenarionet" / "nuscenes"


def _both(monkeypatch, score_map, points, headings):
    holding = score_map.lanes_at(points)
    answers = []
    for compiled in (False, True):
        monkeypatch.setattr(kernels, "wanted", lambda compiled=compiled: compiled)
        route = centre_route(score_map, points, headings, holding)
        answers.append(([list(lanes) for lanes in route], first_lanes(route).tolist()))
    return answers


@pytest.fixture(scope="module")
def real_maps():
    from pytest_driveeval.usecases.closed_loop.datasets import open_dataset
    from pytest_driveeval.usecases.closed_loop.score import dataset_score_maps

    if not any(SCENES.glob("*.pkl")):
        pytest.skip(f"no ScenarioNet scenes in {SCENES}")
    dataset = open_dataset(SCENES, None)
    return [m for m in dataset_score_maps(dataset, range(len(list(SCENES.glob("*.pkl"))))).values() if m is not None]


def _paths(score_map, rng):
    """Along chains of lanes (each lane's baseline, then one it leads into), with sideways noise now and then
    off the lane; and the baselines' vertices in the map's order (a path that jumps)."""
    for start in rng.choice(score_map.num_lanes, size=min(6, score_map.num_lanes), replace=False).tolist():
        parts, lane = [], start
        for _ in range(5):
            parts.append(score_map.baselines[lane])
            ahead = score_map.outgoing[lane]
            if not ahead:
                break
            lane = ahead[int(rng.integers(len(ahead)))]
        path = np.concatenate(parts)
        path = path + rng.normal(0.0, 1.5, size=path.shape) * (rng.random((len(path), 1)) < 0.3)
        yield path
    yield np.concatenate(score_map.baselines)[::3]


def test_the_compiled_route_is_the_python_route_on_real_maps(real_maps, monkeypatch):
    rng = np.random.default_rng(5)
    frames = 0
    for score_map in real_maps:
        for path in _paths(score_map, rng):
            step = np.diff(path, axis=0, append=path[-1:] + path[-1:] - path[-2:-1])
            headings = np.arctan2(step[:, 1], step[:, 0])
            python, compiled = _both(monkeypatch, score_map, path, headings)
            assert compiled == python
            frames += len(path)
    assert frames > 1000


@pytest.mark.parametrize("seed", range(4))
def test_the_compiled_route_is_the_python_route_on_random_maps(seed, monkeypatch):
    inputs = inputs_from_case(random_case(seed))
    rng = np.random.default_rng(seed)
    points = rng.uniform([-30, -20], [160, 20], size=(300, 2))
    for path in (inputs.ego.center[:, :2], points, points[:0], points + 1e4):  # ..., no frame, no lane anywhere
        python, compiled = _both(monkeypatch, inputs.map, path, rng.uniform(-np.pi, np.pi, len(path)))
        assert compiled == python
