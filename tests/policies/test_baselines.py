"""Baselines: where constant velocity goes from a frame without a past."""
from __future__ import annotations

import pytest

torch = pytest.importorskip("torch")

from pytest_driveeval.policies.baselines import ConstantVelocityPolicy
from conftest import torchscript


def _batch(has_past: bool) -> dict:
    # Heading along x at 5 m/s; the logged next position is up and to the left.
    history = torch.zeros(1, 11, 2)
    history[0, 1] = torch.tensor([-0.4, -0.3])
    avail = torch.zeros(1, 11)
    avail[0, : 2 if has_past else 1] = 1.0
    return {"history_positions": history, "history_availabilities": avail, "speed": torch.tensor([5.0]),
            "target_positions": torch.tensor([[[0.3, 0.4]] * 12])}


@pytest.mark.parametrize("first_step, step", [("heading", [0.5, 0.0]), ("logged_next", [0.3, 0.4])])
def test_first_step_without_a_past(first_step, step):
    for policy in (ConstantVelocityPolicy(first_step=first_step),
                   torchscript(ConstantVelocityPolicy(first_step=first_step))):
        out = policy(_batch(has_past=False))["positions"][0]
        torch.testing.assert_close(out[:2], torch.tensor([step, [2 * step[0], 2 * step[1]]]))
        # With a past, the last step repeats whatever the option.
        torch.testing.assert_close(policy(_batch(has_past=True))["positions"][0, 0], torch.tensor([0.4, 0.3]))


def test_unknown_first_step_is_refused():
    with pytest.raises(ValueError, match="first_step must be one of heading, logged_next, not 'log'"):
        ConstantVelocityPolicy(first_step="log")
