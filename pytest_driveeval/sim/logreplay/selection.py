"""Which logged agents replay: the others are dropped from the scene before it
is stacked, so the policy never sees them and the ego cannot hit them.

l5kit's closed loop keeps every agent unless ``disable_new_agents`` is set;
then only the cars (``label_probabilities`` of CAR above the threshold) within
``distance_th_close`` of the ego at the start frame stay, in every frame, and
the rest are blanked out (``l5kit.simulation.dataset.SimulationDataset`` and
``disable_agents``).  :class:`ReplayedAgents` expresses both that and a plain
label filter.
"""
from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from pytest_driveeval.io.l5.l5kit_zarr import L5Scene, label_index
from pytest_driveeval.sim.logreplay.logarrays import rows_by_frame

__all__ = ["ReplayedAgents", "keep_agents"]


@dataclasses.dataclass(frozen=True)
class ReplayedAgents:
    """``labels``: keep agent rows whose probability of one of these labels
    (``"CAR"`` or ``"PERCEPTION_LABEL_CAR"``) is above ``label_threshold``,
    judged row by row as l5kit's ``filter_agents_by_labels``; None keeps every
    label.  ``within_at_start`` (m): keep only the tracks that pass the label
    test at the start frame closer than this to the ego, and those in every
    frame whatever their later labels (l5kit's ``disable_new_agents``).
    """

    labels: Sequence[str] | None = None
    label_threshold: float = 0.5
    within_at_start: float | None = None

    def __post_init__(self):
        for name in self.labels or ():
            label_index(name)  # an unknown name fails here, listing the known ones


def keep_agents(scene: L5Scene, rule: ReplayedAgents, start_frame: int = 0) -> L5Scene:
    """The scene with only the agent rows ``rule`` keeps, in their stored order."""
    if rule.labels is None and rule.within_at_start is None:
        return scene
    rows, frame, _ = rows_by_frame(scene)
    agents = scene.agents[rows]
    keep = np.ones(rows.size, bool)
    if rule.labels is not None:
        columns = [label_index(name) for name in rule.labels]
        keep = (agents["label_probabilities"][:, columns] > rule.label_threshold).any(axis=1)
    if rule.within_at_start is not None:
        ego = scene.frames["ego_translation"][min(start_frame, scene.num_frames - 1), :2]
        near = np.linalg.norm(agents["centroid"] - ego, axis=-1) < rule.within_at_start
        allowed = agents["track_id"][keep & near & (frame == start_frame)]
        keep = np.isin(agents["track_id"], allowed)
    counts = np.bincount(frame[keep], minlength=scene.num_frames)
    frames = scene.frames.copy()
    ends = np.cumsum(counts)
    frames["agent_index_interval"] = np.stack([ends - counts, ends], axis=1)
    # The kept rows are no longer one block of the store: agent_offset no longer locates them.
    return dataclasses.replace(scene, frames=frames, agents=agents[keep], agent_offset=-1)
