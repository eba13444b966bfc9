"""nuPlan's closed-loop score (CLS) of an unrolled scene, term by term, as nuplan-devkit's source
computes it (docs/nuplan_score.md), from arrays: the ego's states, the expert's path, the agents, the
collisions the engine already found and blamed, and the map.

    score = collisions x drivable area x making progress x driving direction
            x (5 progress + 5 time to collision + 4 speed limit + 2 comfort) / 16

A term the scene cannot support (no map, no speed limits, too few frames) is reported as not available
with the reason, and the score follows nuPlan's rule for it (see :class:`~.term.Term`).
"""
from .inputs import GROUPS, AgentCells, Collision, EgoStates, ScoreInputs, ego_from_poses, first_collisions
from .lanes import ScoreMap
from .score import SceneScore, combine, item_figures, score_scene
from .term import MULTIPLIERS, TERMS, WEIGHTS, Term

__all__ = ["GROUPS", "MULTIPLIERS", "TERMS", "WEIGHTS", "AgentCells", "Collision", "EgoStates", "SceneScore",
           "ScoreInputs", "ScoreMap", "Term", "combine", "ego_from_poses", "first_collisions", "item_figures",
           "score_scene"]
