"""The graph observation: round trip, nearest agents, edges, invariances, normalisation, errors."""
from __future__ import annotations

import math

import numpy as np
import pytest

torch = pytest.importorskip("torch")

import itertools

from hypothesis import given
from hypothesis import strategies as st

from pytest_driveeval.policies.graph import (
    EDGE_FEATURES,
    NODE_FEATURES,
    GraphObservation,
    GraphObservationError,
    ObservationRanges,
    decode,
    encode,
    graph_observation,
    observation_size,
)

RANGES = ObservationRanges.from_bounding_box(-100.0, -50.0, 300.0, 150.0)
COL = {name: i for i, name in enumerate(NODE_FEATURES)}


@st.composite
def states(draw, max_agents: int = 16):
    """Episodes of traffic as the simulator gives them.  Speeds are distinct per
    agent (0.5, 1.5, ...) so a node's speed says which agent it is."""
    episodes = draw(st.integers(1, 3))
    agents = draw(st.integers(1, max_agents))
    coordinate = st.floats(-80.0, 80.0, allow_nan=False, width=32)
    xy = np.array(draw(st.lists(coordinate, min_size=episodes * agents * 2, max_size=episodes * agents * 2)),
                  dtype=np.float64).reshape(episodes, agents, 2)
    yaw = np.array(draw(st.lists(st.floats(-math.pi, 2 * math.pi), min_size=episodes * agents,
                                 max_size=episodes * agents))).reshape(episodes, agents)
    valid = np.array(draw(st.lists(st.booleans(), min_size=episodes * agents, max_size=episodes * agents)),
                     dtype=bool).reshape(episodes, agents)
    speed = np.broadcast_to(np.arange(agents) + 0.5, (episodes, agents)).copy()
    goal_xy = np.array(draw(st.lists(coordinate, min_size=episodes * 2, max_size=episodes * 2))).reshape(episodes, 2)
    goal_speed = np.full(episodes, 12.5)
    return {"xy": xy, "yaw": yaw, "speed": speed, "valid": valid, "goal_xy": goal_xy, "goal_speed": goal_speed}


limits = st.integers(1, 8)
radii = st.sampled_from([0.0, 10.0, 30.0, 50.0, 500.0])


def observe(state: dict, **kwargs) -> GraphObservation:
    return graph_observation(ranges=RANGES, **state, **kwargs)


def agent_of_each_node(graph: GraphObservation, episode: int) -> list[int]:
    velocity = RANGES.velocity
    speeds = graph.nodes[episode, : int(graph.count[episode]), COL["vel"]].double() * (velocity[1] - velocity[0])
    return [round(float(s) - 0.5) for s in speeds]


def distance(xy: np.ndarray, a: int, b: int) -> float:
    return float(torch.linalg.vector_norm(torch.as_tensor(xy[a] - xy[b])))


# Distances closer than this may round either way between two ways of computing them.
TIE = 1e-9


@given(states(), limits, radii, st.booleans(), st.sampled_from([torch.float32, torch.float64]))
def test_decode_inverts_encode_exactly(state, agent_limit, radius, self_loops, dtype):
    graph = observe(state, agent_limit=agent_limit, radius=radius, self_loops=self_loops, dtype=dtype)
    flat = encode(graph)
    assert flat.shape == (len(state["xy"]), observation_size(agent_limit)) and flat.dtype == dtype
    back = decode(flat)
    for name, ours, theirs in zip(GraphObservation._fields, graph, back):
        assert ours.dtype == theirs.dtype and torch.equal(ours, theirs), name
    assert torch.equal(encode(back), flat)
    assert flat[:, 0].eq(agent_limit).all() and flat[:, 2].eq(len(NODE_FEATURES)).all()


@given(states(), limits)
def test_nodes_are_the_ego_then_the_nearest_valid_others_in_order(state, agent_limit):
    graph = observe(state, agent_limit=agent_limit)
    for e, xy in enumerate(state["xy"]):
        others = [a for a in range(1, xy.shape[0]) if state["valid"][e, a]]
        assert int(graph.count[e]) == 1 + min(len(others), agent_limit - 1)
        nodes = agent_of_each_node(graph, e)
        assert nodes[0] == 0 and len(set(nodes)) == len(nodes) and set(nodes[1:]) <= set(others)
        near = [distance(xy, a, 0) for a in nodes[1:]]
        assert all(d <= e + TIE for d, e in itertools.pairwise(near))
        left_out = [distance(xy, a, 0) for a in set(others) - set(nodes)]
        assert not left_out or not near or max(near) <= min(left_out) + TIE
        assert graph.mask[e].tolist() == [i < len(nodes) for i in range(agent_limit)]
        assert not graph.nodes[e, len(nodes):].any() and not graph.adjacency[e, len(nodes):].any()


@given(states(), limits, radii, st.booleans())
def test_edges_are_exactly_the_pairs_within_the_radius(state, agent_limit, radius, self_loops):
    graph = observe(state, agent_limit=agent_limit, radius=radius, self_loops=self_loops)
    assert torch.equal(graph.adjacency, graph.adjacency.transpose(1, 2))
    for e, xy in enumerate(state["xy"]):
        nodes = agent_of_each_node(graph, e)
        for i, a in enumerate(nodes):
            for j, b in enumerate(nodes):
                if i != j and abs(distance(xy, a, b) - radius) < TIE:
                    continue
                expected = self_loops if i == j else distance(xy, a, b) <= radius
                assert graph.adjacency[e, i, j] == float(expected), (i, j)


@given(states(), limits, radii)
def test_edge_features_are_source_minus_target_of_the_normalised_nodes(state, agent_limit, radius):
    graph = observe(state, agent_limit=agent_limit, radius=radius)
    columns = [COL[name] for name in ("x", "y", "vel", "theta")]
    assert [f"d{name}" for name in ("x", "y", "vel", "theta")] == list(EDGE_FEATURES)
    difference = graph.nodes[:, :, None, columns] - graph.nodes[:, None, :, columns]
    expected = torch.where(graph.adjacency[..., None] > 0, difference, torch.zeros(()))
    assert torch.equal(graph.edge_features, expected)


@given(states(), limits, st.randoms(use_true_random=False))
def test_permuting_the_other_agents_keeps_the_ego_row_and_without_ties_everything(state, agent_limit, rnd):
    agents = state["xy"].shape[1]
    order = [0] + rnd.sample(range(1, agents), agents - 1)
    shuffled = {k: (v[:, order] if v.ndim >= 2 and k not in ("goal_xy",) else v) for k, v in state.items()}
    before, after = observe(state, agent_limit=agent_limit), observe(shuffled, agent_limit=agent_limit)
    assert torch.equal(before.nodes[:, 0], after.nodes[:, 0])
    assert torch.equal(before.count, after.count)
    # The speeds name the agents, so the shuffled state says the same about each of them; only
    # equal distances to the ego can leave the order to the input order.
    distances = [sorted(distance(xy, a, 0) for a in range(1, agents) if state["valid"][e, a])
                 for e, xy in enumerate(state["xy"])]
    if all(b - a > TIE for d in distances for a, b in itertools.pairwise(d)):
        assert torch.equal(encode(before), encode(after))


@given(states(max_agents=8), limits, st.integers(1, 6), st.data())
def test_invalid_agents_change_nothing_whatever_they_hold(state, agent_limit, extra, data):
    episodes, agents = state["valid"].shape
    where = data.draw(st.lists(st.integers(1, agents + extra - 1), min_size=extra, max_size=extra, unique=True))
    keep = [i for i in range(agents + extra) if i not in where]
    junk = data.draw(st.sampled_from([np.nan, np.inf, 0.0, 1e9]))
    padded = {}
    for key, value in state.items():
        if value.ndim >= 2 and key != "goal_xy":
            grown = np.full((episodes, agents + extra) + value.shape[2:], junk if value.dtype != bool else False,
                            dtype=value.dtype)
            grown[:, keep] = value
            padded[key] = grown
        else:
            padded[key] = value
    assert torch.equal(encode(observe(state, agent_limit=agent_limit)), encode(observe(padded, agent_limit=agent_limit)))


def test_normalisation_maps_the_ends_of_each_range_to_0_and_1():
    (x0, x1), (y0, y1) = RANGES.x, RANGES.y
    # Ego at the box's low corner, still, heading 0, its goal at the high corner; the other agent the opposite.
    state = {"xy": np.array([[[x0, y0], [x1, y1]]]), "yaw": np.array([[0.0, 2 * math.pi]]),
                 "speed": np.array([[0.0, 100.0]]), "valid": np.array([[True, True]]),
                 "goal_xy": np.array([[x1, y1]]), "goal_speed": np.array([100.0])}
    graph = observe(dict(state, agent_goal_xy=np.array([[[0, 0], [x0, y0]]]),
                         agent_goal_speed=np.array([[0.0, 0.0]])), radius=1e4, dtype=torch.float64)
    ego, other = graph.nodes[0, 0].tolist(), graph.nodes[0, 1].tolist()
    low, high = {"x", "y", "theta", "vel"}, {"goal_x", "goal_y", "goal_dx", "goal_dy", "goal_vel"}
    assert ego == [0.0 if n in low else 1.0 if n in high else ego[COL[n]] for n in NODE_FEATURES]
    assert other == [1.0 if n in low else 0.0 if n in high else other[COL[n]] for n in NODE_FEATURES]
    assert ego[COL["goal_d"]] == 1.0 == other[COL["goal_d"]]
    # The bearing to the goal (BARK-ML's goal_theta) over [0, 2pi]: up the y axis is a quarter.
    graph = observe(dict(state, goal_xy=np.array([[x0, y1]])), dtype=torch.float64)
    assert float(graph.nodes[0, 0, COL["goal_theta"]]) == 0.25
    assert float(graph.nodes[0, 0, COL["goal_d"]]) * RANGES.distance[1] == pytest.approx(y1 - y0)


def test_features_of_a_small_scene_by_hand():
    ranges = ObservationRanges.from_bounding_box(0.0, 0.0, 100.0, 50.0)
    state = {"xy": np.array([[[10.0, 20.0], [40.0, 20.0], [14.0, 23.0]]]), "yaw": np.array([[0.5, 1.0, 1.5]]),
                 "speed": np.array([[10.0, 20.0, 30.0]]), "valid": np.array([[True, True, True]]),
                 "goal_xy": np.array([[90.0, 20.0]]), "goal_speed": np.array([15.0])}
    graph = graph_observation(ranges=ranges, **state, agent_limit=3, radius=20.0, dtype=torch.float64)
    # Nearest first: agent 2 (5 m away) before agent 1 (30 m away); 1 is beyond 20 m of both.
    expected_rows = []
    for (x, y), yaw, speed in [((10, 20), 0.5, 10), ((14, 23), 1.5, 30), ((40, 20), 1.0, 20)]:
        dx, dy = 90 - x, 20 - y
        expected_rows.append([x / 100, y / 50, yaw / (2 * math.pi), speed / 100, 0.9, 0.4, (dx + 100) / 200,
                              (dy + 50) / 100, math.atan2(dy, dx) / (2 * math.pi), math.hypot(dx, dy) /
                              math.hypot(100, 50), 0.15])
    torch.testing.assert_close(graph.nodes[0], torch.tensor(expected_rows, dtype=torch.float64))
    assert graph.adjacency[0].tolist() == [[1, 1, 0], [1, 1, 0], [0, 0, 1]]
    torch.testing.assert_close(graph.edge_features[0, 0, 1],
                               torch.tensor([-0.04, -0.06, -0.2, -1.0 / (2 * math.pi)], dtype=torch.float64))


def test_an_agent_exactly_at_the_radius_is_linked_as_in_bark_ml():
    state = {"xy": np.array([[[10.0, 20.0], [30.0, 20.0], [10.0, 50.5]]]), "yaw": np.zeros((1, 3)),
                 "speed": np.zeros((1, 3)), "valid": np.ones((1, 3), bool), "goal_xy": np.zeros((1, 2)),
                 "goal_speed": np.zeros(1)}
    graph = observe(state, agent_limit=3, radius=20.0, self_loops=False)
    assert graph.adjacency[0].tolist() == [[0, 1, 0], [1, 0, 0], [0, 0, 0]]


def test_others_take_their_own_goals_when_given_and_the_ego_keeps_its_own():
    state = {"xy": np.array([[[0.0, 0.0], [5.0, 0.0]]]), "yaw": np.zeros((1, 2)), "speed": np.zeros((1, 2)),
                 "valid": np.ones((1, 2), bool), "goal_xy": np.array([[100.0, 0.0]]), "goal_speed": np.array([10.0])}
    shared = observe(state, dtype=torch.float64)
    own = observe(dict(state, agent_goal_xy=np.array([[[7.0, 7.0], [0.0, 100.0]]]),
                       agent_goal_speed=np.array([[1.0, 20.0]])), dtype=torch.float64)
    assert torch.equal(shared.nodes[0, 0], own.nodes[0, 0])
    assert float(shared.nodes[0, 1, COL["goal_x"]]) == pytest.approx((100 - RANGES.x[0]) / 400)
    assert float(own.nodes[0, 1, COL["goal_y"]]) == pytest.approx((100 - RANGES.y[0]) / 200)
    assert float(own.nodes[0, 1, COL["goal_vel"]]) == pytest.approx(0.2)


@pytest.mark.parametrize("limit", [0, -3, 2.0, True])
def test_an_agent_limit_below_one_or_not_an_integer_is_refused(limit):
    state = {"xy": np.zeros((1, 2, 2)), "yaw": np.zeros((1, 2)), "speed": np.zeros((1, 2)), "valid": np.ones((1, 2), bool),
                 "goal_xy": np.zeros((1, 2)), "goal_speed": np.zeros(1)}
    with pytest.raises(GraphObservationError, match=r"agent_limit must be an integer of at least 1 \(node 0 is the "
                                                    rf"ego\), got {limit!r}"):
        observe(state, agent_limit=limit)
    with pytest.raises(GraphObservationError, match="agent_limit must be"):
        observation_size(limit)


@pytest.mark.parametrize("key, value, message", [
    ("xy", np.zeros((2, 3)), r"xy: expected shape \(E, A, 2\) with A >= 1 \(agent 0 is the ego\), found \(2, 3\)"),
    ("yaw", np.zeros((2, 4)), r"yaw: expected shape \(E, A\) = \(2, 3\), found \(2, 4\)"),
    ("valid", np.ones((3, 2), bool), r"valid: expected shape \(E, A\) = \(2, 3\), found \(3, 2\)"),
    ("goal_xy", np.zeros(2), r"goal_xy: expected shape \(E, 2\) = \(2, 2\), found \(2,\)"),
    ("goal_speed", np.zeros((2, 1)), r"goal_speed: expected shape \(E,\) = \(2,\), found \(2, 1\)"),
    ("agent_goal_xy", np.zeros((2, 3)), r"agent_goal_xy: expected shape \(E, A, 2\) = \(2, 3, 2\), found \(2, 3\)"),
    ("speed", np.array([["a"] * 3] * 2), r"speed: expected an array of numbers"),
])
def test_a_wrong_input_is_named_with_the_shape_expected_and_found(key, value, message):
    state = {"xy": np.zeros((2, 3, 2)), "yaw": np.zeros((2, 3)), "speed": np.zeros((2, 3)), "valid": np.ones((2, 3), bool),
                 "goal_xy": np.zeros((2, 2)), "goal_speed": np.zeros(2)}
    with pytest.raises(GraphObservationError, match=message):
        observe({**state, key: value})


def test_a_valid_agent_that_is_not_finite_is_a_fault_an_invalid_one_is_not():
    state = {"xy": np.zeros((2, 3, 2)), "yaw": np.zeros((2, 3)), "speed": np.zeros((2, 3)),
                 "valid": np.array([[True, True, False], [True, True, True]]), "goal_xy": np.zeros((2, 2)),
                 "goal_speed": np.zeros(2)}
    state["yaw"][0, 2] = np.nan
    observe(state)
    state["yaw"][1, 1] = np.nan
    with pytest.raises(GraphObservationError, match=r"yaw: episode 1, agent 1 \(valid\) is not finite"):
        observe(state)
    with pytest.raises(GraphObservationError, match=r"goal_xy: episode 0 is not finite"):
        observe(dict(state, yaw=np.zeros((2, 3)), goal_xy=np.array([[np.inf, 0.0], [0.0, 0.0]])))


def test_decode_refuses_what_encode_cannot_have_made():
    graph = graph_observation(xy=np.zeros((2, 3, 2)), yaw=np.zeros((2, 3)), speed=np.zeros((2, 3)),
                              valid=np.ones((2, 3), bool), goal_xy=np.zeros((2, 2)), goal_speed=np.zeros(2),
                              ranges=RANGES, agent_limit=4)
    flat = encode(graph)
    with pytest.raises(GraphObservationError, match=r"header says K=4, F=11, so expected shape \(2, 63\), "
                                                    r"found \(2, 62\)"):
        decode(flat[:, :-1])
    with pytest.raises(GraphObservationError, match=r"expected shape \(B, 3 \+ K\*F \+ K\*K\), found \(63,\)"):
        decode(flat[0])
    bad = flat.clone()
    bad[1, 1] = 5
    with pytest.raises(GraphObservationError, match=r"agent count n must be in \[1, 4\], found \[5\]"):
        decode(bad)
    bad = flat.clone()
    bad[1, 0] = 3
    with pytest.raises(GraphObservationError, match="K and F differ between rows"):
        decode(bad)
    with pytest.raises(GraphObservationError, match="empty batch"):
        decode(flat[:0])


def test_ranges_derive_distances_from_the_box_and_refuse_an_empty_range():
    ranges = ObservationRanges.from_bounding_box(0, 0, 30, 40)
    assert (ranges.distance, ranges.dx, ranges.dy) == ((0.0, 50.0), (-30.0, 30.0), (-40.0, 40.0))
    assert ranges.theta == (0.0, 2 * math.pi) and ranges.velocity == (0.0, 100.0)
    with pytest.raises(GraphObservationError, match=r"ObservationRanges.x must be finite with low < high, "
                                                    r"got \(5.0, 5.0\)"):
        ObservationRanges.from_bounding_box(5, 0, 5, 1)
