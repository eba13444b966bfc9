"""Flat graph observations of random traffic, for the actor tests of both networks."""
from __future__ import annotations

import numpy as np
import torch

from pytest_driveeval.policies.graph import ObservationRanges, encode, graph_observation


def example_flat(seed: int, agents: int = 9) -> torch.Tensor:
    """(1, 279) one observation: ``agents`` vehicles scattered around the ego, about 80 % of them present."""
    rng = np.random.default_rng(seed)
    return encode(graph_observation(
        xy=rng.uniform(-40, 40, (1, agents, 2)), yaw=rng.uniform(0, 6, (1, agents)),
        speed=rng.uniform(0, 30, (1, agents)), valid=rng.random((1, agents)) < 0.8,
        goal_xy=np.array([[150.0, 0.0]]), goal_speed=np.array([15.0]),
        ranges=ObservationRanges.from_bounding_box(-100, -100, 200, 100)))
