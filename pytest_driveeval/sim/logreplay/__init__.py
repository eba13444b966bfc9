"""Log replay: the ego is driven by a policy through logged L5 scenes while the
other agents replay the log (l5kit's closed loop), many scenes in one batch.

:mod:`.selection` says which logged agents replay, :mod:`.logarrays` stacks
the logged scenes, :mod:`.inputs` builds the policy inputs (l5kit's planning-dataset layout), :mod:`.engine` steps the batch,
:mod:`.perturb` moves starts off the log for robustness searches, :mod:`.reactive`
lets the logged vehicles brake by IDM for what the simulation puts in their way.
Importing this package imports torch.
"""
from pytest_driveeval.sim.logreplay.engine import UnrollConfig, UnrollResult, unroll
from pytest_driveeval.sim.logreplay.inputs import build_batch, collate_training_samples
from pytest_driveeval.sim.logreplay.logarrays import (EGO_EXTENT, STEP_TIME, LogArrays, scenes_from_arrays,
                                                      stack_scenes, window_columns)
from pytest_driveeval.sim.logreplay.perturb import perturb_history, scale_agent_time
from pytest_driveeval.sim.logreplay.reactive import ReactiveAgents
from pytest_driveeval.sim.logreplay.selection import ReplayedAgents, keep_agents

__all__ = [
    "EGO_EXTENT", "STEP_TIME", "LogArrays", "ReactiveAgents", "ReplayedAgents", "UnrollConfig", "UnrollResult", "build_batch",
    "collate_training_samples", "keep_agents", "perturb_history", "scale_agent_time", "scenes_from_arrays", "stack_scenes", "unroll", "window_columns",
]
