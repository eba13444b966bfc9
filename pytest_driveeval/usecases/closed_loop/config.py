"""The YAML of a ``closed_loop`` scenario (UseCaseFormatVersion 0.1.0).

    Evaluation:
      UseCaseName: closed_loop
      UseCaseFormatVersion: 0.1.0
      Datasets:
        - real_scene: {Path: ../fixtures/l5kit/single_scene.zarr}
      Model: ../fixtures/models/planning_mlp.pt   # or constant_velocity / log_replay
      Unroll:
        Scenes: [0]            # or SceneStride: 10 (every 10th, as the seed does); default all
        StartFrame: 10
        Steps: 100             # default: to the end of the scene
        DriftThreshold: 10.0   # reset the ego to the log when it drifts further (seed rule)
        FreezeOnCollision: true
        Kinematic: false
      Conditions:
        Collisions: {Front: 0, Side: 0, Rear: 0, AtFaultOnly: true}
        Displacement: {Max: 4.0, Duration: 0.5}   # metres; seconds above tolerated
        DistanceToReference: {Max: 2.0}
        MaxResets: 0
        ScenePassRate: 100.0   # % of unrolled scenes that must pass
      Artefacts: {Animations: all}   # all | failing | none
"""
from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, NonNegativeFloat, NonNegativeInt, PositiveInt, model_validator

from pytest_driveeval.usecase import ConditionsModel


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


class UnrollSpec(_Strict):
    Scenes: list[NonNegativeInt] | None = None
    SceneStride: PositiveInt | None = None
    StartFrame: NonNegativeInt = 0
    Steps: PositiveInt | None = None
    DriftThreshold: NonNegativeFloat | None = 10.0
    FreezeOnCollision: bool = True
    Kinematic: bool = False
    HistoryFrames: PositiveInt = 10
    FutureFrames: PositiveInt = 12
    MaxAgents: PositiveInt = 30

    @model_validator(mode="after")
    def _one_selection(self):
        if self.Scenes is not None and self.SceneStride is not None:
            raise ValueError("give Scenes or SceneStride, not both")
        return self


class CollisionLimits(_Strict):
    Front: NonNegativeInt = 0
    Side: NonNegativeInt = 0
    Rear: NonNegativeInt = 0
    AtFaultOnly: bool = False


class RangeLimit(_Strict):
    """A per-frame figure must stay <= Max; up to Duration seconds above it are tolerated."""

    Max: NonNegativeFloat
    Duration: NonNegativeFloat = 0.0


class ClosedLoopConditions(_Strict):
    Collisions: CollisionLimits = Field(default_factory=CollisionLimits)
    Displacement: RangeLimit | None = None
    DistanceToReference: RangeLimit | None = None
    SpeedDifference: RangeLimit | None = None
    MaxResets: NonNegativeInt | None = None
    ScenePassRate: float = Field(100.0, ge=0.0, le=100.0)


class ArtefactSpec(_Strict):
    Animations: Literal["all", "failing", "none"] = "failing"
    Charts: bool = True


class ClosedLoopConfig(ConditionsModel):
    Model: str | None = None
    Unroll: UnrollSpec = Field(default_factory=UnrollSpec)
    Conditions: ClosedLoopConditions = Field(default_factory=ClosedLoopConditions)
    Artefacts: ArtefactSpec = Field(default_factory=ArtefactSpec)
