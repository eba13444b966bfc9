"""The MLP actor and critic (the seed's SAC): the GNN's interface, bounds, sampling and loading, with
the flat observation read as one vector."""
from __future__ import annotations

import pytest

torch = pytest.importorskip("torch")

from pytest_driveeval.policies import gnn, mlp  # noqa: E402
from pytest_driveeval.policies.export import export_program  # noqa: E402
from pytest_driveeval.policies.graph import observation_size  # noqa: E402
from pytest_driveeval.policies.loading import load_model  # noqa: E402
from pytest_driveeval.policies.mlp import MLPActor, MLPCritic, make_actor, make_critic, parameter_count  # noqa: E402

from flat_examples import example_flat  # noqa: E402


@pytest.fixture(autouse=True, scope="module")
def one_thread():
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


FLAT = torch.cat([example_flat(s) for s in range(6)])


def spread(module: torch.nn.Module, seed: int = 0, scale: float = 0.6) -> torch.nn.Module:
    generator = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for p in module.parameters():
            p.copy_(torch.randn(p.shape, generator=generator) * scale)
    return module


def test_the_factories_build_the_gnn_interface_at_the_gnn_size():
    actor, critic = make_actor(), make_critic()
    assert isinstance(actor, MLPActor) and isinstance(critic, MLPCritic) and not actor.training
    assert actor.encoder.observation_size == observation_size(12) == 279
    assert actor.action_center.tolist() == pytest.approx([-0.5, 0.0])
    assert actor.action_half_range.tolist() == pytest.approx([4.5, 0.2])
    # The comparison is of architectures, not of sizes.
    assert parameter_count(actor) == parameter_count(gnn.make_actor()) == 17508
    assert parameter_count(critic) == parameter_count(gnn.make_critic()) == 34882
    # One head implementation: the same class gives both actors sample() and distribution().
    assert type(actor).sample is type(gnn.make_actor()).sample


def test_actions_have_the_shapes_and_stay_within_the_bounds():
    low, high = torch.tensor([-5.0, -0.2]), torch.tensor([4.0, 0.2])
    actor = spread(make_actor(), scale=2.0)  # saturating weights: the bounds must still hold
    with torch.no_grad():
        for action in (actor(FLAT), actor.sample(FLAT)[0]):
            assert action.shape == (6, 2)
            assert ((low <= action) & (action <= high)).all()
        assert actor.sample(FLAT)[1].shape == (6,)
        q1, q2 = make_critic()(FLAT, actor(FLAT))
    assert q1.shape == q2.shape == (6,)


def test_sac_losses_reach_every_weight():
    actor, critic = make_actor().train(), make_critic()
    action, log_prob = actor.sample(FLAT)
    q1, q2 = critic(FLAT, action)
    assert not torch.equal(q1, q2)
    c1, c2 = critic(FLAT, action.detach())
    ((c1 - 1).pow(2) + (c2 - 1).pow(2)).mean().add((0.2 * log_prob - torch.min(q1, q2)).mean()).backward()
    for name, p in [*actor.named_parameters(), *critic.named_parameters()]:
        assert p.grad is not None and torch.isfinite(p.grad).all() and p.grad.abs().sum() > 0, name


@pytest.mark.filterwarnings("ignore:`torch.jit.*` is deprecated:DeprecationWarning")
def test_scripted_exported_saved_and_loaded_models_act_the_same(tmp_path):
    actor, critic = spread(make_actor(), scale=0.1), make_critic()
    scripted, scripted_critic = torch.jit.script(actor), torch.jit.script(critic)
    torch.jit.save(scripted, tmp_path / "actor.pt")
    torch.save(actor.state_dict(), tmp_path / "weights.pt")
    with torch.no_grad():
        expected = actor(FLAT)
        assert expected.std(0).min() > 1e-4  # the observations lead to different actions
        torch.testing.assert_close(scripted(FLAT), expected)
        torch.testing.assert_close(load_model(str(tmp_path / "actor.pt"))(FLAT), expected)
        torch.testing.assert_close(
            load_model(f"{tmp_path / 'weights.pt'}=pytest_driveeval.policies.mlp:make_actor")(FLAT), expected)
        program = export_program(actor, (FLAT[:4],), tmp_path / "actor.pt2")
        torch.testing.assert_close(program(FLAT), expected)  # another batch size than the example's
        torch.testing.assert_close(load_model(str(tmp_path / "actor.pt2"))(FLAT[:1]), expected[:1])
        torch.manual_seed(3)
        sampled = actor.sample(FLAT)
        torch.manual_seed(3)
        torch.testing.assert_close(scripted.sample(FLAT), sampled)
        torch.testing.assert_close(scripted_critic(FLAT, expected), critic(FLAT, expected))


@pytest.mark.parametrize("network", [gnn, mlp], ids=["gnn", "mlp"])
def test_observations_of_another_shape_are_refused_with_the_shapes(network):
    # The checks and the head are one implementation (gnn.check_flat, gnn.SquashedGaussianActor):
    # each network is held to them.
    with pytest.raises(ValueError, match=r"expected shape \(B, 155\) for K=8, F=11, found \[6, 279\]"):
        network.make_actor(agent_limit=8)(FLAT)
    lying = FLAT.clone()
    lying[0, 2] = 10
    with pytest.raises(ValueError, match=r"header \[K, n, F\] does not say K=12, F=11"):
        network.make_actor()(lying)
    with pytest.raises(ValueError, match=r"action: expected shape \(B, 2\), found \[6, 3\]"):
        network.make_critic()(FLAT, torch.zeros(6, 3))
    with pytest.raises(ValueError, match="low < high"):
        network.make_actor(action_low=(1.0, 0.0), action_high=(0.0, 1.0))
    with pytest.raises(ValueError, match="agent_limit"):
        network.make_actor(agent_limit=0)
