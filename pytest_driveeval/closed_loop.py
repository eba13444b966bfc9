"""The closed-loop Python API, at the path scenario tests import it from.

The ``closed_loop`` use case lives in :mod:`pytest_driveeval.usecases.closed_loop`;
this API is its :mod:`~pytest_driveeval.usecases.closed_loop.evaluate` module.
"""
from pytest_driveeval.usecases.closed_loop.evaluate import (KIND_CODE, KINDS, SceneVerdict, Unroll, collision_events,
                                                            judge_scene, scene_figures, select_scenes, unroll_scenes)
from pytest_driveeval.usecases.closed_loop.score import score_unroll

__all__ = ["KINDS", "KIND_CODE", "SceneVerdict", "Unroll", "collision_events", "judge_scene", "scene_figures",
           "score_unroll", "select_scenes", "unroll_scenes"]
