"""What the GNN gains over the MLP (issue 24): on real observations of the benchmark's episodes,
relabelling the other vehicles (their node order in the flat observation, with their rows and
columns of the adjacency) leaves the GNN's actions as they were and changes the MLP's."""
from __future__ import annotations

import functools

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from pytest_driveeval.policies import gnn, mlp  # noqa: E402
from pytest_driveeval.policies.graph import GraphObservation, decode, edge_features, encode  # noqa: E402
from pytest_driveeval.policies.idm_expert import IDMExpert  # noqa: E402
from pytest_driveeval.policies.loading import load_model  # noqa: E402
from pytest_driveeval.sim.episodes import reset  # noqa: E402
from pytest_driveeval.usecases.policy_benchmark.evaluate import observer  # noqa: E402

from conftest import REPO_ROOT  # noqa: E402

SHIPPED_GNN = REPO_ROOT / "fixtures" / "models" / "gnn_actor_merging.pt2"
# float32 sums over neighbours in another order: a few ulps of terms of order one.
SAME = {"rtol": 1e-5, "atol": 1e-5}


@functools.cache
def real_observations(blueprint: str) -> torch.Tensor:
    """The observations the benchmark's policy sees (evaluate.observer), at the start and along the
    IDM expert's drive, of 16 episodes: every state with two or more other vehicles."""
    episodes = reset(blueprint, np.arange(16), 12)
    observe, expert = observer(episodes, 12), IDMExpert()
    seen = [observe(episodes)]
    for step in range(60):
        episodes.step(np.where(episodes.done[:, None], 0.0, expert.act_on_episodes(episodes)))
        if step % 10 == 9:
            seen.append(observe(episodes))
    flat = torch.cat(seen)
    return flat[flat[:, 1] >= 3]


def relabelled(flat: torch.Tensor, seed: int) -> torch.Tensor:
    """The same graphs with the other vehicles (nodes 1..n-1) in another order; the ego stays node 0
    and padded nodes stay last.  Node rows and adjacency rows and columns move together."""
    graph = decode(flat)
    rng = np.random.default_rng(seed)
    nodes, adjacency = graph.nodes.clone(), graph.adjacency.clone()
    for b, n in enumerate(graph.count.tolist()):
        others = rng.permutation(np.arange(1, n))
        while n > 2 and (others == np.arange(1, n)).all():
            others = rng.permutation(np.arange(1, n))
        order = torch.tensor([0, *others.tolist(), *range(n, flat_k(flat))])
        nodes[b] = graph.nodes[b, order]
        adjacency[b] = graph.adjacency[b][order][:, order]
    return encode(GraphObservation(nodes, adjacency, edge_features(nodes, adjacency), graph.count, graph.mask))


def flat_k(flat: torch.Tensor) -> int:
    return int(flat[0, 0])


def spread(module: torch.nn.Module, seed: int = 0) -> torch.nn.Module:
    """Weights large enough that the output moves with its input (PyTorch's default initialisation
    leaves them nearly flat), kept small enough that tanh does not saturate the actions."""
    generator = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for p in module.parameters():
            p.copy_(torch.randn(p.shape, generator=generator) * 0.3)
    return module


def actions(actor, flat: torch.Tensor) -> torch.Tensor:
    with torch.no_grad():
        return actor(flat)


def means(actor, flat: torch.Tensor) -> torch.Tensor:
    """The Gaussian's mean before tanh: spread weights can saturate an action, never the mean."""
    with torch.no_grad():
        return actor.distribution(flat)[0]


@pytest.mark.parametrize("blueprint", ["highway", "merging", "intersection"])
def test_the_real_observations_are_relabelled_consistently(blueprint):
    flat = real_observations(blueprint)
    moved = relabelled(flat, seed=1)
    assert len(flat) >= 16
    assert not torch.equal(moved, flat)
    # The same graphs: the header and the ego row are untouched, the others' rows are a permutation,
    # and each other vehicle keeps its links (degree) and its edge features' multiset.
    before, after = decode(flat), decode(moved)
    torch.testing.assert_close(moved[:, :3], flat[:, :3], rtol=0, atol=0)
    torch.testing.assert_close(after.nodes[:, 0], before.nodes[:, 0], rtol=0, atol=0)
    torch.testing.assert_close(after.edge_features[:, 0].sort(dim=1).values,
                               before.edge_features[:, 0].sort(dim=1).values, rtol=0, atol=0)
    torch.testing.assert_close(after.adjacency.sum((1, 2)), before.adjacency.sum((1, 2)), rtol=0, atol=0)
    torch.testing.assert_close(after.nodes.sum(1), before.nodes.sum(1))


@pytest.mark.parametrize("blueprint", ["highway", "merging", "intersection"])
def test_relabelling_the_other_vehicles_keeps_the_gnn_actions_and_moves_the_mlp_actions(blueprint):
    flat = real_observations(blueprint)
    moved = relabelled(flat, seed=2)
    graph_actor, flat_actor = spread(gnn.make_actor()), spread(mlp.make_actor())
    torch.testing.assert_close(actions(graph_actor, moved), actions(graph_actor, flat), **SAME)
    torch.testing.assert_close(means(graph_actor, moved), means(graph_actor, flat), **SAME)
    # Means of order one that move by 1e-2 moved for a reason, not by rounding; in most states.
    moved_means = (means(flat_actor, moved) - means(flat_actor, flat)).abs().amax(dim=1)
    assert (moved_means > 1e-2).float().mean() > 0.5, moved_means
    # And the acceleration itself (range 9 m/s^2) moves by more than 1e-3 of its range somewhere.
    assert (actions(flat_actor, moved) - actions(flat_actor, flat))[:, 0].abs().max() > 9e-3


@pytest.mark.parametrize("blueprint", ["merging", "highway"])
def test_the_shipped_gnn_actor_ignores_the_order_of_the_other_vehicles(blueprint):
    actor = load_model(str(SHIPPED_GNN))
    flat = real_observations(blueprint)
    torch.testing.assert_close(actions(actor, relabelled(flat, seed=3)), actions(actor, flat), **SAME)


def test_the_default_initialised_mlp_is_moved_too():
    # Not only a spread MLP: PyTorch's own initialisation already reads node order.
    torch.manual_seed(0)
    actor = mlp.make_actor()
    flat = real_observations("merging")
    assert (actions(actor, relabelled(flat, seed=4)) - actions(actor, flat)).abs().max() > 1e-4
