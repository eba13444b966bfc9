"""The kinematic state every simulator steps: where the agents are, where they
head, how fast they go.

Arrays share their leading dimensions, (scenes or episodes, agents, ...) or
any prefix of them, so one state holds a whole batch and a dynamics model
steps it in one vectorised call.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

__all__ = ["AgentState"]


@dataclass(frozen=True)
class AgentState:
    """A batch of planar poses with their speeds.

    ``xy`` (..., 2) m in the world frame; ``yaw`` (...) rad; ``speed`` (...)
    m/s, signed along the heading (negative when reversing).
    """

    xy: np.ndarray
    yaw: np.ndarray
    speed: np.ndarray

    @property
    def shape(self) -> tuple[int, ...]:
        """The leading (batch) dimensions."""
        return np.shape(self.yaw)

    def take(self, rows) -> "AgentState":
        """The state of ``rows`` (an index, slice or mask along the first axis)."""
        return AgentState(self.xy[rows], self.yaw[rows], self.speed[rows])

    def replace(self, **fields: np.ndarray) -> "AgentState":
        """A copy with the given fields swapped; the arrays themselves are shared, not copied."""
        return dataclasses.replace(self, **fields)
