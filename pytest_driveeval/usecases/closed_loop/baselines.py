"""The policies a closed-loop scenario names instead of a model file: the constant-velocity and log-replay
baselines, and the PDM-Closed planner.  Its own module so that the use case and its Ray chunks (chunked)
build them alike."""
from __future__ import annotations

from pytest_driveeval.usecases.closed_loop.config import ClosedLoopConfig

__all__ = ["BASELINES", "baseline"]

#: pdm_closed is the package's own planner (policies.pdm_closed): named here, it needs no opt-in for code
BASELINES = ("constant_velocity", "log_replay", "pdm_closed")


def baseline(name: str, config: ClosedLoopConfig | None = None):
    from pytest_driveeval.policies.baselines import (
        ConstantVelocityPolicy,
        ReplayLogPolicy,
    )

    if name == "pdm_closed":
        from pytest_driveeval.policies.pdm_closed import PDMClosed

        return PDMClosed()
    if name == "constant_velocity":
        spec = config.ConstantVelocity if config is not None else None
        return ConstantVelocityPolicy(first_step=spec.FirstStep if spec else "heading").eval()
    return {"log_replay": ReplayLogPolicy}[name]().eval()
