"""The networks' feature scaling (gnn.NodeScaling): it standardises the nodes in use and nothing
else, keeps the GNN blind to the order of the other vehicles, travels with the weights and the
exported program, and weights saved before it existed still load, unscaled."""
from __future__ import annotations

import pytest

torch = pytest.importorskip("torch")

from pytest_driveeval.policies import gnn, mlp  # noqa: E402
from pytest_driveeval.policies.export import export_program  # noqa: E402
from pytest_driveeval.policies.graph import HEADER  # noqa: E402

from flat_examples import example_flat  # noqa: E402

K, F = 12, 11
FLAT = torch.cat([example_flat(s) for s in range(6)])
NETWORKS = pytest.mark.parametrize("network", [gnn, mlp], ids=["gnn", "mlp"])


def scaled(actor: torch.nn.Module, seed: int = 0) -> tuple[torch.nn.Module, torch.Tensor, torch.Tensor]:
    generator = torch.Generator().manual_seed(seed)
    shift, scale = torch.rand(F, generator=generator), 0.05 + torch.rand(F, generator=generator)
    with torch.no_grad():
        actor.encoder.scaling.shift.copy_(shift)
        actor.encoder.scaling.scale.copy_(scale)
    return actor, shift, scale


def standardised_by_hand(flat: torch.Tensor, shift: torch.Tensor, scale: torch.Tensor) -> torch.Tensor:
    out = flat.clone()
    nodes = out[:, HEADER:HEADER + K * F].view(len(flat), K, F)
    for row, count in enumerate(flat[:, 1].long().tolist()):
        nodes[row, :count] = (nodes[row, :count] - shift) / scale
    return out


@NETWORKS
def test_the_nodes_in_use_are_standardised_and_nothing_else(network):
    torch.manual_seed(0)
    actor, shift, scale = scaled(network.make_actor())
    plain = network.make_actor()
    plain.load_state_dict({k: v for k, v in actor.state_dict().items() if "scaling" not in k}, strict=False)
    assert torch.equal(plain.encoder.scaling.scale, torch.ones(F))
    expected = plain(standardised_by_hand(FLAT, shift, scale))
    torch.testing.assert_close(actor(FLAT), expected)
    assert not torch.allclose(plain(FLAT), expected)  # the scaling changed the actions


@NETWORKS
def test_weights_saved_without_the_scaling_load_unscaled(network):
    torch.manual_seed(1)
    before = network.make_actor()
    old = {k: v for k, v in before.state_dict().items() if "scaling" not in k}
    actor, _, _ = scaled(network.make_actor(), seed=2)
    actor.load_state_dict(old)  # strict: the missing buffers are the identity, not an error
    assert torch.equal(actor.encoder.scaling.shift, torch.zeros(F))
    torch.testing.assert_close(actor(FLAT), before(FLAT), rtol=0, atol=0)


@NETWORKS
@pytest.mark.filterwarnings("ignore:`torch.jit.*` is deprecated:DeprecationWarning")
def test_the_scaling_travels_with_the_weights_and_the_exported_program(network, tmp_path):
    torch.manual_seed(3)
    actor, _, _ = scaled(network.make_actor(), seed=4)
    expected = actor(FLAT)
    again = network.make_actor()
    again.load_state_dict(actor.state_dict())
    torch.testing.assert_close(again(FLAT), expected, rtol=0, atol=0)
    program = export_program(actor, (FLAT[:2],), tmp_path / "actor.pt2")
    torch.testing.assert_close(program(FLAT), expected)
    torch.testing.assert_close(torch.jit.script(actor)(FLAT), expected)


def test_a_scaled_gnn_still_ignores_the_order_of_the_other_vehicles():
    torch.manual_seed(5)
    actor, _, _ = scaled(gnn.make_actor(), seed=6)
    flat = example_flat(7)
    count = int(flat[0, 1])
    order = torch.tensor([0, *reversed(range(1, count)), *range(count, K)])
    nodes = flat[:, HEADER:HEADER + K * F].view(K, F)[order]
    adjacency = flat[:, HEADER + K * F:].view(K, K)[order][:, order]
    moved = torch.cat([flat[:, :HEADER], nodes.reshape(1, -1), adjacency.reshape(1, -1)], dim=1)
    assert count >= 3 and not torch.equal(moved, flat)
    torch.testing.assert_close(actor(moved), actor(flat), rtol=1e-5, atol=1e-5)
