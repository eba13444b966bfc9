"""The shipped GNN actor (fixtures/models/gnn_actor_merging.pt2) is what
examples/train_gnn_policy.py says it is, and still drives better than chance."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
torch = pytest.importorskip("torch")  # a Python without torch skips the file

pytest.importorskip("scipy")

from pytest_driveeval import assert_beats  # noqa: E402
from pytest_driveeval.policies.control_baselines import RandomAction  # noqa: E402
from pytest_driveeval.policies.loading import ExportedModel, load_model  # noqa: E402
from pytest_driveeval.sim.episodes import reset  # noqa: E402
from pytest_driveeval.usecases.policy_benchmark.evaluate import observe, run_policy, seeds_for  # noqa: E402

MODEL = Path(__file__).resolve().parents[3] / "fixtures" / "models" / "gnn_actor_merging.pt2"
OBSERVATION_SIZE = 279  # 3 + 12 agents * 11 features + 12 * 12 adjacency


@pytest.fixture(scope="module")
def actor():
    # An exported program carries its graph, so load_model takes it without unpickling anything.
    model = load_model(str(MODEL))
    assert isinstance(model, ExportedModel) and isinstance(model.module, torch.fx.GraphModule)
    return model


def test_takes_the_flat_graph_observation_and_returns_bounded_actions(actor):
    episodes = reset("merging", np.arange(5), agent_limit=12)
    obs = observe(episodes, 12)
    assert obs.shape == (5, OBSERVATION_SIZE) and obs.dtype == torch.float32
    with torch.no_grad():
        action = actor(obs)
    assert action.shape == (5, 2)
    low = np.array([episodes.blueprint.params.ego_accel[0], -episodes.blueprint.params.ego_max_steer])
    high = np.array([episodes.blueprint.params.ego_accel[1], episodes.blueprint.params.ego_max_steer])
    assert np.all(action.numpy() >= low - 1e-6) and np.all(action.numpy() <= high + 1e-6)
    with pytest.raises(Exception, match="279"):
        actor(obs[:, :-1])


def test_beats_random_on_held_out_episodes(actor):
    seeds, strata = seeds_for(0, 32, 4)
    gnn = run_policy("merging", seeds, actor, "gnn", strata=strata)
    random = run_policy("merging", seeds, RandomAction(), "random", strata=strata)
    assert_beats(gnn, random, metric="goal_rate")
    assert gnn.goal.mean() >= 0.75, gnn.figures()
