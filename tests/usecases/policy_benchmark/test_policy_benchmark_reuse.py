"""A policy benchmark's chunks in one process (as on a Ray worker, which runs chunk after chunk):
the policy loaded for the first chunk serves the next ones of the same item, a changed model file
is loaded again, an item whose spec differs never gets another's model, and the episodes are
those of one batch with and without reuse.  The cache itself: tests/execute/test_reuse.py."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pytest_driveeval.execute import reuse
from reuse_items import nothing_kept, settled_copy  # noqa: F401  (tests/reuse_items.py; the fixture by name)

pytest.importorskip("torch")
pytest.importorskip("scipy")

REPO = Path(__file__).resolve().parents[3]
GNN = REPO / "fixtures" / "models" / "gnn_actor_merging.pt2"
MLP = REPO / "fixtures" / "models" / "mlp_actor_merging.pt2"
FIELDS = ("outcome", "returns", "steps")


def chunks(spec: str, base: Path, seeds, size: int, params: dict | None = None):
    from pytest_driveeval.usecases.policy_benchmark.chunked import PolicySource, episode_chunks

    return episode_chunks("p", PolicySource(spec, str(base)), "merging", params or {}, np.asarray(seeds), 12, size)


def run(work) -> dict[str, np.ndarray]:
    from pytest_driveeval.usecases.policy_benchmark.chunked import merged, run_episode_chunk

    done = merged([run_episode_chunk(chunk) for chunk in work])
    return {name: getattr(done, name) for name in FIELDS}


def one_batch(model: Path, seeds, params: dict | None = None) -> dict[str, np.ndarray]:
    from pytest_driveeval.policies.loading import load_model
    from pytest_driveeval.sim.blueprints import make_blueprint
    from pytest_driveeval.usecases.policy_benchmark.evaluate import run_policy

    done = run_policy(make_blueprint("merging", **(params or {})), np.asarray(seeds), load_model(str(model)), "p")
    return {name: getattr(done, name) for name in FIELDS}


def same(a: dict, b: dict) -> bool:
    return all(np.array_equal(a[k], b[k]) and a[k].dtype == b[k].dtype for k in FIELDS)


SEEDS = list(range(100, 113))


def test_an_items_chunks_load_its_model_once_and_give_the_one_batch_episodes_with_and_without_reuse(monkeypatch):
    work = chunks(GNN.name, GNN.parent, SEEDS, 4)
    assert len(work) == 4
    kept = run(work)
    assert reuse.loads == {"model": 1}, "the first chunk loads the model, the other three reuse it"
    assert same(kept, one_batch(GNN, SEEDS))
    monkeypatch.setenv(reuse.SWITCH, "0")
    assert same(run(work), kept)
    assert reuse.loads == {"model": 5}, "without reuse, each chunk loads its own"


def test_a_model_file_changed_between_chunks_is_loaded_again(tmp_path):
    policy = settled_copy(GNN, tmp_path / "policy.pt2")
    first, second = chunks("policy.pt2", tmp_path, SEEDS[:5], 5), chunks("policy.pt2", tmp_path, SEEDS[5:10], 5)
    assert same(run(first), one_batch(GNN, SEEDS[:5]))
    assert reuse.loads == {"model": 1}
    settled_copy(MLP, policy)  # another network under the same name: another size and mtime
    mlp = one_batch(MLP, SEEDS[5:10])
    assert not same(mlp, one_batch(GNN, SEEDS[5:10])), "the two networks must drive apart for this test to tell"
    assert same(run(second), mlp)
    assert reuse.loads == {"model": 2}
    assert reuse.held("model") == 1, "the old network is dropped, not kept beside the new one"


def test_items_whose_spec_differs_never_share_a_model(tmp_path):
    # The same relative spec in two scenario folders names two networks; their chunks interleave.
    a = settled_copy(GNN, tmp_path / "a" / "policy.pt2")
    b = settled_copy(MLP, tmp_path / "b" / "policy.pt2")
    work_a = chunks("policy.pt2", a.parent, SEEDS, 7)
    work_b = chunks("policy.pt2", b.parent, SEEDS, 7)
    # the same network by another spec (its absolute path) and another blueprint's parameters
    params = {"gap": (9.0, 12.0)}
    work_c = chunks(str(a), tmp_path, SEEDS, 7, params)
    interleaved = [chunk for pair in zip(work_a, work_b, work_c) for chunk in pair]
    results = run(interleaved[0::3]), run(interleaved[1::3]), run(interleaved[2::3])
    assert reuse.loads == {"model": 3}
    assert same(results[0], one_batch(GNN, SEEDS))
    assert same(results[1], one_batch(MLP, SEEDS))
    assert same(results[2], one_batch(GNN, SEEDS, params))
    assert not same(results[0], results[2]), "the blueprint's parameters must change the episodes"


def test_baselines_and_factories_are_built_for_each_chunk(tmp_path, monkeypatch):
    # Nothing keyed by a file: a baseline may keep state, a factory's files are unknown.
    from pytest_driveeval.usecases.policy_benchmark.chunked import PolicySource, episode_chunks, run_episode_chunk

    (tmp_path / "reuse_factory.py").write_text("import torch\n\n\ndef make():\n    return lambda observation: torch.zeros(observation.shape[0], 2)\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    for spec in ("random", "reuse_factory:make"):
        for chunk in episode_chunks("p", PolicySource(spec, None), "merging", {}, np.asarray(SEEDS), 12, 5):
            run_episode_chunk(chunk)
    assert reuse.loads == {}
