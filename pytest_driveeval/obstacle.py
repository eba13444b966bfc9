"""Obstacle segmentation as a Python API: stream clouds, judge each frame like driving_log_replayer.

    result = evaluate_obstacle_segmentation(T4Dataset(root), bag_pointclouds(root), config)
    assert_pass_rate(result, detection=99.0, non_detection=99.0)

Kept at this path for the imports that name it; the use case lives in
``pytest_driveeval/usecases/obstacle_segmentation/`` (its ``__init__`` has the
frame semantics and where we differ from driving_log_replayer).
"""
from __future__ import annotations

from .usecases.obstacle_segmentation.assertions import assert_pass_rate
from .usecases.obstacle_segmentation.evaluate import evaluate_obstacle_segmentation
from .usecases.obstacle_segmentation.result import ObstacleResult
from .usecases.obstacle_segmentation.sources import (FilteredPointClouds, bag_pointclouds, dataset_pointclouds,
                                                     sweep_pointclouds)

__all__ = ["FilteredPointClouds", "ObstacleResult", "assert_pass_rate", "bag_pointclouds", "dataset_pointclouds",
           "evaluate_obstacle_segmentation", "sweep_pointclouds"]
