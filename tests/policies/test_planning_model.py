"""The shipped planning model and the code that trains it."""
from __future__ import annotations

import importlib.util

import numpy as np
import pytest
torch = pytest.importorskip("torch")  # a Python without torch skips the file

from pytest_driveeval.policies.baselines import ConstantVelocityPolicy  # noqa: E402
from pytest_driveeval.policies.loading import ExportedModel, load_model  # noqa: E402
from pytest_driveeval.policies.planning_model import PlanningModel  # noqa: E402
from pytest_driveeval.sim.logreplay import UnrollConfig, build_batch, scenes_from_arrays, stack_scenes, unroll  # noqa: E402
from pytest_driveeval.synth.scenegen import generate_scenes  # noqa: E402

from conftest import REPO_ROOT  # noqa: E402

MODEL = REPO_ROOT / "fixtures" / "models" / "planning_model.pt2"
TRAIN_SCRIPT = REPO_ROOT / "examples" / "train_planning_model.py"
# A validation scene of the training run (seed 2, never trained on) where
# constant velocity drives into a queue at the red light.
HELD_OUT_SEED, HELD_OUT_SCENE = 2, 0
CLOSED_LOOP = UnrollConfig(drift_threshold=10.0, freeze_on_collision=True)


@pytest.fixture(scope="module")
def shipped():
    return load_model(str(MODEL))


@pytest.fixture(scope="module")
def held_out_log():
    return stack_scenes(scenes_from_arrays(generate_scenes(HELD_OUT_SCENE + 1, 150, seed=HELD_OUT_SEED)))


@pytest.fixture(scope="module")
def trainer():
    # The script lives in examples/, not in the package: load it by path.
    spec = importlib.util.spec_from_file_location("train_planning_model", TRAIN_SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _batch(log, frames=(0, 40, 90)):
    rows = np.repeat(np.arange(log.shape[0]), len(frames))
    return build_batch(log, rows, np.tile(frames, log.shape[0]), log.ego_xy, log.ego_yaw)


def test_shipped_model_is_a_small_exported_program(shipped):
    assert MODEL.stat().st_size < 2_000_000
    assert isinstance(shipped, ExportedModel) and isinstance(shipped.module, torch.fx.GraphModule)


def test_output_shapes_finite_and_deterministic(shipped, held_out_log):
    batch = _batch(held_out_log)
    with torch.no_grad():
        a, b = shipped(batch), shipped(batch)
    assert a["positions"].shape == (3, 12, 2) and a["yaws"].shape == (3, 12, 1)
    assert torch.isfinite(a["positions"]).all() and torch.isfinite(a["yaws"]).all()
    assert torch.equal(a["positions"], b["positions"]) and torch.equal(a["yaws"], b["yaws"])


def test_first_step_follows_the_ego_motion(shipped, held_out_log):
    # Mid-scene, with traffic ahead or not, the first pose is a plausible
    # 10 Hz step forward: not standing still, not metres away.
    with torch.no_grad():
        first = shipped(_batch(held_out_log, frames=(20,)))["positions"][:, 0]
    assert (first[:, 0] > 0.2).all() and (first[:, 0] < 2.5).all() and (first[:, 1].abs() < 0.3).all()


def test_closed_loop_beats_constant_velocity(shipped, held_out_log):
    model = unroll(held_out_log, shipped, CLOSED_LOOP)
    cv = unroll(held_out_log, ConstantVelocityPolicy(), CLOSED_LOOP)
    assert cv.collision_at_fault.sum() > 0  # the scene is a real test: the baseline fails it
    assert model.collision_at_fault.sum() < cv.collision_at_fault.sum()
    assert np.nanmean(model.displacement_error) < np.nanmean(cv.displacement_error)
    assert all(e is None for e in model.errors)


def test_perturbation_without_offset_is_identity(trainer):
    log = trainer.generated_log(1, seed=3, num_frames=40)
    data = trainer.samples(log, *trainer.frames_with_full_future(log))
    out = trainer.perturb(data, torch.Generator().manual_seed(0), prob=0.0)
    for key in data:
        torch.testing.assert_close(out[key], data[key], atol=1e-5, rtol=0)


def test_training_code_smoke(trainer, tmp_path):
    torch.manual_seed(0)
    log = trainer.generated_log(2, seed=3, num_frames=40)
    data = trainer.samples(log, *trainer.frames_with_full_future(log))
    model = PlanningModel(d=32, ffn=64)
    before = [p.detach().clone() for p in model.parameters()]
    history = trainer.train(model, data, {"val": data}, epochs=1, batch_size=16, max_steps=2, log=lambda s: None)
    assert history[0]["steps"] == 2 and np.isfinite(history[0]["loss"]) and np.isfinite(history[0]["val_ade"])
    assert any(not torch.equal(a, b) for a, b in zip(before, model.parameters()))
    # Traced on the batch the closed loop gives: an exported program takes the keys it was traced with.
    batch = _batch(log, frames=(5, 20))
    reloaded = trainer.export(model, tmp_path / "m.pt2", example=batch)
    model.eval()
    with torch.no_grad():
        torch.testing.assert_close(load_model(str(tmp_path / "m.pt2"))(batch)["positions"], model(batch)["positions"])
    figures = trainer.closed_loop_figures(unroll(log, reloaded, UnrollConfig(num_steps=5)))
    assert figures["scenes"] == 2 and figures["errors"] == 0
