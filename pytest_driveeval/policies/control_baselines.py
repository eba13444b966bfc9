"""Baselines of the policy benchmark: what a learnt control policy must beat.

They act on the simulator's episodes (``act_on_episodes``), not on the graph
observation, so each knows its action bounds and each episode's seed.  Every
action is a function of the episode alone (its seed and step, or its state):
a baseline's episode does not depend on which other episodes share its batch.

* :class:`RandomAction`: uniform in the bounds, the floor any policy must clear.
* :class:`ConstantAction`: keep speed and steer straight.
* :class:`~pytest_driveeval.policies.idm_expert.IDMExpert`: a lane-following IDM
  expert reading the simulator's lanes and traffic, what a learnt policy should
  come close to.
"""
from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["ConstantAction", "RandomAction", "action_bounds"]


def action_bounds(episodes: Any) -> tuple[np.ndarray, np.ndarray]:
    params = episodes.blueprint.params
    low = np.array([params.ego_accel[0], -params.ego_max_steer])
    high = np.array([params.ego_accel[1], params.ego_max_steer])
    return low, high


class RandomAction:
    """Uniform in the action bounds, drawn from (seed, step) of each running episode."""

    def __init__(self, salt: int = 0) -> None:
        self.salt = salt

    def act_on_episodes(self, episodes: Any) -> np.ndarray:
        low, high = action_bounds(episodes)
        # An ended episode ignores its action: the middle of the bounds spares it a generator,
        # which costs more than the compiled step (a search's batch waits on its longest episode).
        draws = np.full((episodes.num_episodes, 2), 0.5)
        for i in np.flatnonzero(~episodes.done):
            draws[i] = np.random.default_rng([self.salt, int(episodes.seeds[i]), int(episodes.steps[i])]).random(2)
        return low + (high - low) * draws


class ConstantAction:
    """The same action every step: by default keep speed and steer straight."""

    def __init__(self, acceleration: float = 0.0, steering: float = 0.0) -> None:
        self.action = np.array([acceleration, steering], dtype=np.float64)

    def act_on_episodes(self, episodes: Any) -> np.ndarray:
        low, high = action_bounds(episodes)
        return np.broadcast_to(np.clip(self.action, low, high), (episodes.num_episodes, 2)).copy()
