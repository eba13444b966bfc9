"""The GNN actor and critic: the message passing they claim, invariances, padding, SAC sampling, loading."""
from __future__ import annotations

import copy
import functools
import math

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from pytest_driveeval.policies.gnn import (
    GNNActor,
    GNNCritic,
    GraphEncoder,
    make_actor,
    make_critic,
)
from pytest_driveeval.policies.graph import (
    GraphObservation,
    ObservationRanges,
    decode,
    edge_features,
    encode,
    graph_observation,
    observation_size,
)
from pytest_driveeval.policies.loading import load_model

from flat_examples import example_flat

F = 11


@pytest.fixture(autouse=True, scope="module")
def one_thread():
    # Graphs of a few nodes: a second thread only adds wake-ups, which cost milliseconds per
    # matmul when xdist workers already fill the cores.
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def spread(module: torch.nn.Module, seed: int = 0) -> torch.nn.Module:
    """Weights large enough that every unit is sometimes on and sometimes off: PyTorch's
    default initialisation leaves outputs so flat that a wrong mask could pass unnoticed."""
    generator = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for p in module.parameters():
            p.copy_(torch.randn(p.shape, generator=generator) * 0.6)
    return module


def pack(nodes: torch.Tensor, adjacency: torch.Tensor, count: torch.Tensor) -> torch.Tensor:
    mask = torch.arange(nodes.shape[1]).unsqueeze(0) < count.unsqueeze(1)
    return encode(GraphObservation(nodes, adjacency, edge_features(nodes, adjacency), count, mask))


@st.composite
def graphs(draw, agent_limit: int | None = None, batch: int | None = None):
    """Flat observations of random graphs: any node values, any symmetric adjacency, self-loops or not."""
    k = agent_limit or draw(st.integers(1, 8))
    b = batch or draw(st.integers(1, 3))
    nodes, adjacency = torch.zeros(b, k, F), torch.zeros(b, k, k)
    count = torch.tensor(draw(st.lists(st.integers(1, k), min_size=b, max_size=b)))
    for g, n in enumerate(count.tolist()):
        nodes[g, :n] = torch.from_numpy(draw(arrays(np.float32, (n, F), elements=st.floats(-0.5, 1.5, width=32))))
        upper = np.triu(draw(arrays(bool, (n, n))), 1)
        adjacency[g, :n, :n] = torch.from_numpy((upper | upper.T).astype(np.float32))
        if draw(st.booleans()):
            adjacency[g, range(n), range(n)] = 1.0
    return pack(nodes, adjacency, count)


def loop_ego_embedding(encoder: GraphEncoder, flat: torch.Tensor) -> torch.Tensor:
    """The message passing as the seed writes it, one graph, one node and one edge at a time:
    m_i = sum over edges i-j of MLP([h_j, e_ij]); h_i <- h_i + z (tanh(c / 2) - h_i)."""
    graph = decode(flat)
    out = []
    for b in range(flat.shape[0]):
        n = int(graph.count[b])
        h = torch.relu(encoder.embed(graph.nodes[b, :n]))
        for layer in [*encoder.inner, encoder.last]:
            updated = []
            for i in range(n):
                message = torch.zeros(encoder.hidden, dtype=h.dtype)
                for j in range(n):
                    if graph.adjacency[b, i, j] > 0:
                        hidden = torch.relu(layer.sender(h[j]) + layer.edge(graph.edge_features[b, i, j]))
                        message = message + layer.message(hidden)
                gate, candidate = layer.update(torch.cat([h[i], message])).chunk(2)
                updated.append(h[i] + torch.sigmoid(gate) * (torch.tanh(candidate / 2) - h[i]))
            h = torch.stack(updated)
        out.append(h[0])
    return torch.stack(out)


@given(graphs(), st.integers(1, 3))
def test_the_dense_encoder_is_the_per_edge_message_passing(flat, rounds):
    # float64, so the only difference left is the algebra: sender and receiver terms
    # instead of one layer over [h_j, e_ij], the second layer after the sum, the ego-only last round.
    encoder = spread(GraphEncoder(agent_limit=int(flat[0, 0]), rounds=rounds)).double()
    flat = flat.double()
    with torch.no_grad():
        torch.testing.assert_close(encoder(flat), loop_ego_embedding(encoder, flat), atol=1e-10, rtol=1e-10)


@functools.cache
def spread_actor(agent_limit: int) -> GNNActor:
    """The same weights whatever the agent limit: none of them depends on it."""
    return spread(make_actor(agent_limit=agent_limit))


ACTOR = spread_actor(12)
# Sums over neighbours in another order, in float32, of terms up to ~10.
REORDERED = {"rtol": 1e-4, "atol": 1e-4}


def outputs(actor: GNNActor, flat: torch.Tensor) -> torch.Tensor:
    """The action and the Gaussian's mean before tanh: spread weights can saturate the action, never the mean."""
    with torch.no_grad():
        return torch.cat([actor(flat), actor.distribution(flat)[0]], dim=-1)


ACTOR64 = copy.deepcopy(ACTOR).double()  # .double() converts in place: ACTOR stays float32
# In float64 a different order of summation moves the result by ~1e-15, so the bound can be tight
# (in float32, terms up to ~10 summed in another order drift past 1e-4 on some graphs).
REORDERED64 = {"rtol": 1e-9, "atol": 1e-9}


@given(graphs(agent_limit=12), st.data())
def test_relabelling_the_other_nodes_changes_nothing(flat, data):
    flat = flat.double()
    graph = decode(flat)
    before = outputs(ACTOR64, flat)
    for b, n in enumerate(graph.count.tolist()):
        order = [0] + data.draw(st.permutations(range(1, n))) + list(range(n, 12))
        graph.nodes[b] = graph.nodes[b, order]
        graph.adjacency[b] = graph.adjacency[b][order][:, order]
    torch.testing.assert_close(outputs(ACTOR64, pack(graph.nodes, graph.adjacency, graph.count)), before,
                               **REORDERED64)


@given(graphs(agent_limit=12), st.floats(-1e6, 1e6), st.data())
def test_what_padded_nodes_hold_never_reaches_the_action(flat, junk, data):
    graph = decode(flat)
    nodes, adjacency = graph.nodes.clone(), graph.adjacency.clone()
    padded = ~graph.mask
    nodes[padded] = junk
    links = torch.from_numpy(data.draw(arrays(bool, adjacency.shape))).float()
    either = padded.unsqueeze(1) | padded.unsqueeze(2)
    adjacency[either] = links[either]
    dirty = torch.cat([flat[:, :3], nodes.flatten(1), adjacency.flatten(1)], dim=1)
    assert torch.equal(outputs(ACTOR, dirty), outputs(ACTOR, flat))


@given(graphs(agent_limit=6), st.integers(1, 6))
def test_a_larger_agent_limit_with_the_same_weights_gives_the_same_action(flat, more):
    graph = decode(flat)
    k = 6 + more
    nodes, adjacency = torch.zeros(flat.shape[0], k, F), torch.zeros(flat.shape[0], k, k)
    nodes[:, :6], adjacency[:, :6, :6] = graph.nodes, graph.adjacency
    small, large = spread_actor(6), make_actor(agent_limit=k)
    large.load_state_dict(small.state_dict())
    torch.testing.assert_close(outputs(large, pack(nodes, adjacency, graph.count)), outputs(small, flat),
                               **REORDERED)


def hops_from_ego(adjacency: torch.Tensor, n: int) -> list[float]:
    hops, frontier = [0.0] + [math.inf] * (n - 1), [0]
    while frontier:
        nxt = [j for i in frontier for j in range(n) if adjacency[i, j] > 0 and hops[j] == math.inf]
        for j in nxt:
            hops[j] = hops[frontier[0]] + 1
        frontier = sorted(set(nxt))
    return hops


@given(graphs(agent_limit=8, batch=1), st.data())
def test_two_rounds_see_two_hops_and_no_further(flat, data):
    graph = decode(flat)
    n = int(graph.count[0])
    hops = hops_from_ego(graph.adjacency[0], n)
    actor = spread_actor(8)
    for node in range(1, n):
        nodes = graph.nodes.clone()
        nodes[0, node] = torch.from_numpy(data.draw(arrays(np.float32, F, elements=st.floats(-0.5, 1.5, width=32))))
        changed = not torch.equal(outputs(actor, pack(nodes, graph.adjacency, graph.count)), outputs(actor, flat))
        if hops[node] > 2:
            assert not changed, (node, hops)


def test_a_neighbour_two_hops_away_does_change_the_action():
    # ego - 1 - 2 in a line; 2 is seen through 1 only.
    nodes = torch.rand(1, 8, F, generator=torch.Generator().manual_seed(1))
    adjacency = torch.zeros(1, 8, 8)
    adjacency[0, [0, 1, 1, 2], [1, 0, 2, 1]] = 1.0
    moved = nodes.clone()
    moved[0, 2] += 0.3
    actor = spread_actor(8)
    near, far = outputs(actor, pack(nodes, adjacency, torch.tensor([3]))), outputs(actor, pack(moved, adjacency,
                                                                                               torch.tensor([3])))
    assert (near - far).abs().max() > 1e-3


@st.composite
def traffic(draw):
    agents = draw(st.integers(2, 16))
    xy = np.array(draw(st.lists(st.floats(-60, 60, width=32), min_size=2 * agents, max_size=2 * agents)))
    return {"xy": xy.reshape(1, agents, 2), "yaw": np.linspace(0, 3, agents)[None],
            "speed": np.linspace(5, 25, agents)[None],
            "valid": np.array(draw(st.lists(st.booleans(), min_size=agents, max_size=agents)))[None],
            "goal_xy": np.array([[200.0, 10.0]]), "goal_speed": np.array([15.0])}


@given(traffic(), st.randoms(use_true_random=False))
def test_shuffling_the_other_agents_in_the_simulator_arrays_keeps_the_action(state, rnd):
    ranges = ObservationRanges.from_bounding_box(-100, -100, 300, 100)
    agents = state["xy"].shape[1]
    order = [0] + rnd.sample(range(1, agents), agents - 1)
    shuffled = {k: v[:, order] if k in ("xy", "yaw", "speed", "valid") else v for k, v in state.items()}
    distances = sorted(float(np.hypot(*(state["xy"][0, a] - state["xy"][0, 0])))
                       for a in range(1, agents) if state["valid"][0, a])
    # With equal distances at the agent limit, which of them is kept depends on the input order.
    limit_ties = len(distances) >= 12 and distances[10] + 1e-9 >= distances[11]
    before = outputs(ACTOR, encode(graph_observation(**state, ranges=ranges)))
    after = outputs(ACTOR, encode(graph_observation(**shuffled, ranges=ranges)))
    if not limit_ties:
        torch.testing.assert_close(after, before, **REORDERED)


@given(graphs(agent_limit=12))
def test_actions_stay_within_the_bounds(flat):
    low, high = torch.tensor([-5.0, -0.2]), torch.tensor([4.0, 0.2])
    with torch.no_grad():
        for action in (ACTOR(flat), ACTOR.sample(flat)[0]):
            assert action.shape == (flat.shape[0], 2)
            assert ((low <= action) & (action <= high)).all()


def test_sample_log_prob_is_the_density_of_the_squashed_scaled_gaussian():
    # Default initialisation: means near 0, where tanh is still invertible in float64.
    torch.manual_seed(0)
    actor = make_actor().double()
    flat = torch.cat([example_flat(s) for s in range(4)]).double()
    with torch.no_grad():
        torch.manual_seed(0)
        action, log_prob = actor.sample(flat)
        mean, log_std = actor.distribution(flat)
    density = torch.distributions.TransformedDistribution(
        torch.distributions.Normal(mean, log_std.exp()),
        [torch.distributions.TanhTransform(), torch.distributions.AffineTransform(actor.action_center,
                                                                                  actor.action_half_range)])
    torch.testing.assert_close(log_prob, density.log_prob(action).sum(-1), atol=1e-6, rtol=1e-6)
    torch.testing.assert_close(actor(flat), actor.action_center + actor.action_half_range * torch.tanh(mean))
    assert log_prob.shape == (4,) and not torch.equal(action, actor(flat))




def test_sac_losses_reach_every_weight():
    actor, critic = make_actor().train(), make_critic()
    flat = torch.cat([example_flat(s) for s in range(8)])
    action, log_prob = actor.sample(flat)
    q1, q2 = critic(flat, action)
    assert q1.shape == q2.shape == (8,) and not torch.equal(q1, q2)
    actor_loss = (0.2 * log_prob - torch.min(q1, q2)).mean()
    target = torch.ones(8)
    c1, c2 = critic(flat, action.detach())
    ((c1 - target).pow(2) + (c2 - target).pow(2)).mean().add(actor_loss).backward()
    for name, p in [*actor.named_parameters(), *critic.named_parameters()]:
        assert p.grad is not None and torch.isfinite(p.grad).all() and p.grad.abs().sum() > 0, name


@pytest.mark.filterwarnings("ignore:`torch.jit.*` is deprecated:DeprecationWarning")
def test_scripted_saved_and_loaded_models_act_the_same(tmp_path):
    actor, critic = spread(make_actor()), make_critic()
    flat = torch.cat([example_flat(s) for s in range(5)])
    scripted, scripted_critic = torch.jit.script(actor), torch.jit.script(critic)
    torch.jit.save(scripted, tmp_path / "actor.pt")
    torch.save(actor.state_dict(), tmp_path / "weights.pt")
    with torch.no_grad():
        expected = actor(flat)
        torch.testing.assert_close(scripted(flat), expected)
        torch.testing.assert_close(load_model(str(tmp_path / "actor.pt"))(flat), expected)
        torch.testing.assert_close(
            load_model(f"{tmp_path / 'weights.pt'}=pytest_driveeval.policies.gnn:make_actor")(flat), expected)
        torch.manual_seed(3)
        sampled = actor.sample(flat)
        torch.manual_seed(3)
        torch.testing.assert_close(scripted.sample(flat), sampled)
        action = actor(flat)
        torch.testing.assert_close(scripted_critic(flat, action), critic(flat, action))


def test_the_factories_build_the_shipped_configuration():
    actor, critic = make_actor(), make_critic()
    assert not actor.training
    assert actor.encoder.observation_size == observation_size(12) == 3 + 12 * 11 + 144
    assert actor.action_center.tolist() == pytest.approx([-0.5, 0.0])
    assert actor.action_half_range.tolist() == pytest.approx([4.5, 0.2])
    assert isinstance(actor, GNNActor) and isinstance(critic, GNNCritic)
    assert critic.encoder1.observation_size == actor.encoder.observation_size


def test_a_graph_encoder_needs_a_round():
    # The shape and header checks, shared with the MLP, are tested for both networks in test_mlp.
    with pytest.raises(ValueError, match="rounds must be at least 1"):
        make_actor(rounds=0)
