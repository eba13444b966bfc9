"""The policies a closed-loop scenario names instead of a model file: the constant-velocity and log-replay
baselines.  Its own module so that the use case and its Ray chunks (chunked) build them alike."""
from __future__ import annotations

from pytest_driveeval.usecases.closed_loop.config import ClosedLoopConfig

__all__ = ["BASELINES", "baseline"]

BASELINES = ("constant_velocity", "log_replay")


def baseline(name: str, config: ClosedLoopConfig | None = None):
    from pytest_driveeval.policies.baselines import (
        ConstantVelocityPolicy,
        ReplayLogPolicy,
    )

    if name == "constant_velocity":
        spec = config.ConstantVelocity if config is not None else None
        return ConstantVelocityPolicy(first_step=spec.FirstStep if spec else "heading").eval()
    return {"log_replay": ReplayLogPolicy}[name]().eval()
