"""ExportedModel checks a dict of tensors (the planning model's input) once per key order and shapes:
later calls of the same skip the module's hooks and give its outputs bit for bit; a new shape still
meets the module's own check."""
from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from conftest import REPO_ROOT  # noqa: E402
from pytest_driveeval.policies.loading import load_model  # noqa: E402
from pytest_driveeval.sim.logreplay import build_batch, scenes_from_arrays, stack_scenes  # noqa: E402
from pytest_driveeval.synth.scenegen import generate_scenes  # noqa: E402


def test_a_dict_of_tensors_is_checked_once_per_shape_and_gives_the_modules_outputs():
    model = load_model(str(REPO_ROOT / "fixtures" / "models" / "planning_model.pt2"))
    log = stack_scenes(scenes_from_arrays(generate_scenes(1, 150, seed=2)))
    batch = build_batch(log, np.zeros(3, dtype=np.int64), np.array([0, 40, 90]), log.ego_xy, log.ego_yaw)
    assert type(batch) is dict
    checks = []
    model.module.register_forward_pre_hook(lambda module, args: checks.append(len(args)))
    with torch.no_grad():
        first, second, direct = model(batch), model(batch), model.module(batch)
    assert len(checks) == 2  # the first call and the module's own: the second skipped the hooks
    for key in first:
        assert torch.equal(first[key], second[key]) and torch.equal(first[key], direct[key])
    name, value = next((k, v) for k, v in batch.items() if v.dim() >= 2 and v.shape[-1] > 1)
    with pytest.raises(Exception):
        model({**batch, name: value[..., :-1]})   # a new, wrong shape: the module's own check refuses it
