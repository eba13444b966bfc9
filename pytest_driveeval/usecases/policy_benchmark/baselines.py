"""The control policies a policy-benchmark scenario names instead of a model file (``config.BASELINES``).
Its own module so that the use case and its Ray chunks (chunked) build them alike."""
from __future__ import annotations

from typing import Any

__all__ = ["baseline"]


def baseline(name: str) -> Any:
    from pytest_driveeval.policies.control_baselines import ConstantAction, RandomAction

    if name == "random":
        return RandomAction()
    if name == "constant":
        return ConstantAction()
    from pytest_driveeval.policies.idm_expert import IDMExpert  # reads the simulator's lanes

    return IDMExpert()
