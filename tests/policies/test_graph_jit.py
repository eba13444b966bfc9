"""The compiled flat graph observation (policies.graph_jit) against encode(graph_observation): the same bits."""
from __future__ import annotations

import numpy as np
import pytest
torch = pytest.importorskip("torch")  # a Python without torch skips the file

from pytest_driveeval.policies import graph_jit  # noqa: E402
from pytest_driveeval.policies.graph import GraphObservationError, ObservationRanges, encode, graph_observation  # noqa: E402
from pytest_driveeval.sim import episodes_jit  # noqa: E402
from pytest_driveeval.sim.blueprints import make_blueprint  # noqa: E402
from pytest_driveeval.sim.episodes import reset  # noqa: E402

pytestmark = pytest.mark.skipif(not episodes_jit.AVAILABLE, reason="numba is not installed: only torch runs")

FILL = {"highway": {}, "merging": {"main_span": (0.0, 95.0), "merge_span": (0.0, 60.0)},
        "intersection": {"traffic_span": (-95.0, 40.0)}}


def states(name, episodes_n, agents, steps=40):
    """The episodes' arrays after each of some steps of a jittery drive: agents near and far, leaving the map."""
    episodes = reset(make_blueprint(name, **FILL[name]), np.arange(episodes_n), agents)
    rng = np.random.default_rng(episodes_n)
    for _ in range(steps):
        yield episodes
        episodes.step(rng.uniform([-2.0, -0.1], [3.0, 0.1], (episodes_n, 2)))


@pytest.mark.parametrize("name", ["highway", "merging", "intersection"])
@pytest.mark.parametrize("episodes_n,agents,limit,radius,self_loops", [
    (16, 12, 12, 50.0, True), (5, 12, 4, 50.0, True), (7, 6, 12, 10.0, False), (1, 12, 12, 20.0, True),
    (3, 1, 12, 50.0, True), (4, 12, 1, 50.0, False)])
def test_compiled_observation_is_torchs_bit_for_bit(name, episodes_n, agents, limit, radius, self_loops):
    episodes_jit.start()
    ranges = observe = None
    for now in states(name, episodes_n, agents):
        ranges = ranges or ObservationRanges.from_bounding_box(*now.map_bounds)
        observe = observe or graph_jit.observer(ranges, limit, radius, self_loops)  # its buffers reused
        got = observe(now.xy, now.yaw, now.speed, now.valid, now.goal_centre, now.goal_speed)
        expected = encode(graph_observation(now.xy, now.yaw, now.speed, now.valid, now.goal_centre,
                                            now.goal_speed, ranges, agent_limit=limit, radius=radius,
                                            self_loops=self_loops))
        assert got.dtype == expected.dtype == torch.float32 and got.shape == expected.shape
        assert got.numpy().tobytes() == expected.numpy().tobytes()


def test_the_kernels_build_it_and_a_bad_value_is_named_as_torch_names_it(monkeypatch):
    episodes = reset("highway", np.arange(3), 12)
    ranges = ObservationRanges.from_bounding_box(*episodes.map_bounds)
    calls = []
    original = graph_jit.flat_observation
    monkeypatch.setattr(graph_jit, "flat_observation", lambda *a, **k: calls.append(1) or original(*a, **k))
    observe = graph_jit.observer(ranges, 12)
    episodes_jit.start()
    xy, valid = episodes.xy.copy(), episodes.valid.copy()
    valid[1, 5], xy[1, 5] = False, np.nan  # an agent off the map: ignored whatever its values
    got = observe(xy, episodes.yaw, episodes.speed, valid, episodes.goal_centre, episodes.goal_speed)
    assert calls and torch.equal(got, encode(graph_observation(xy, episodes.yaw, episodes.speed, valid,
                                                               episodes.goal_centre, episodes.goal_speed, ranges)))
    xy[1, 3] = np.nan
    with pytest.raises(GraphObservationError, match="episode 1, agent 3"):
        observe(xy, episodes.yaw, episodes.speed, valid, episodes.goal_centre, episodes.goal_speed)


def test_torch_builds_it_where_numba_is_not_wanted(monkeypatch):
    monkeypatch.setattr(episodes_jit, "AVAILABLE", False)
    monkeypatch.setattr(graph_jit, "flat_observation", lambda *a, **k: pytest.fail("the kernels ran"))
    episodes = reset("merging", np.arange(2), 12)
    observe = graph_jit.observer(ObservationRanges.from_bounding_box(*episodes.map_bounds), 12)
    flat = observe(episodes.xy, episodes.yaw, episodes.speed, episodes.valid, episodes.goal_centre,
                   episodes.goal_speed)
    assert flat.shape == (2, 3 + 12 * 11 + 144)
