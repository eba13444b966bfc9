"""The YAML of an ``obstacle_segmentation`` scenario: driving_log_replayer's, unchanged.

UseCaseFormatVersion 0.3.0::

    Conditions:
      Detection:                     # or null
        PassRate: 99.0
        BoundingBoxConfig:           # or null; overrides target_uuids
          - dcb2b352232fff50c4fad23718f31611: {Start: null, End: null}
      NonDetection:                  # or null
        PassRate: 99.0
        ProposedArea:
          polygon_2d: [[10.0, 1.5], [10.0, -1.5], [0.0, -1.5], [0.0, 1.5]]   # clockwise, base_link
          z_min: 0.0
          z_max: 1.5
    SensingEvaluationConfig:
      evaluation_config_dict:
        evaluation_task: sensing
        target_uuids: null           # null: every annotated box
        box_scale_0m: 1.0
        box_scale_100m: 1.0
        min_points_threshold: 1

0.1.0 / 0.2.0 name the detection part ``ObstacleDetection: {PassRate}`` and take
the targets from ``target_uuids``.  Keys of our own, all optional (a
driving_log_replayer file needs none of them)::

    PointCloud: {Topic: /perception/obstacle_segmentation/pointcloud,
                 RawTopic: /sensing/lidar/concatenated/pointcloud,   # read when a filter is given;
                                                                     # null: the lidar sweeps
                 TopicRateDiagnostic: topic_state_monitor_obstacle_segmentation_pointcloud}
    Artefacts: {FailingFramePlots: 5}
    Perturbation:              # a robustness search of the point-cloud filter (see robustness.py)
      Dropout: [0.0, 0.5]      # fraction of raw points dropped
      RangeNoise: [0.0, 0.1]   # m, standard deviation along each point's ray
      GhostPoints: [0, 40]     # points of a ghost cluster in the non-detection area
      Frames: 200              # the first judged frames searched (their raw clouds stay in memory)
      Examples: 100            # Batch, Tolerance, Replay: see pytest_driveeval.search.spec
"""
from __future__ import annotations

from typing import ClassVar, Literal

import numpy as np
from pydantic import (
    Field,
    NonNegativeInt,
    PositiveFloat,
    PositiveInt,
    ValidationInfo,
    field_validator,
    model_validator,
)

from ...geometry.polygons import polygon_self_intersects, polygon_signed_area
from ...search.spec import SearchSpec
from ...core.usecase import ConditionsModel, Section, check_fits

V3 = "0.3.0"
LEGACY = ("0.1.0", "0.2.0")


RATE = Field(ge=0.0, le=100.0)


class Window(Section):
    """Seconds of the cloud's header stamp (absolute ROS time, as driving_log_replayer compares)."""

    Start: float | None = Field(None, description=(
        "s of the cloud's header stamp (absolute ROS time) from which the box is judged; null: from the start"))
    End: float | None = Field(None, description=(
        "s of the cloud's header stamp up to which the box is judged; null: to the end"))

    @model_validator(mode="after")
    def _ordered(self):
        if self.Start is not None and self.End is not None and self.End < self.Start:
            raise ValueError(f"End ({self.End}) is before Start ({self.Start})")
        return self


class DetectionCondition(Section):
    PassRate: float = Field(ge=0.0, le=100.0, description=(
        "% of the judged frames in which every target box must have enough points"))
    BoundingBoxConfig: list[dict[str, Window | None]] | None = Field(None, description=(
        "the target boxes by annotation UUID, each with an optional time Window; overrides target_uuids"))

    def windows(self) -> dict[str, tuple[float, float]] | None:
        if self.BoundingBoxConfig is None:
            return None
        out: dict[str, tuple[float, float]] = {}
        for entry in self.BoundingBoxConfig:
            for uuid, w in entry.items():
                w = w or Window()
                out[uuid] = (-np.inf if w.Start is None else w.Start, np.inf if w.End is None else w.End)
        return out


class LegacyDetectionCondition(Section):
    PassRate: float = Field(ge=0.0, le=100.0, description=(
        "% of the judged frames in which every target box must have enough points"))


def polygon_problem(vertices: np.ndarray) -> str | None:
    """Why a proposed-area polygon is unusable, or None."""
    if len(vertices) < 3:
        return f"a polygon needs at least 3 vertices; found {len(vertices)}"
    if not np.all(np.isfinite(vertices)):
        return "vertices must be finite numbers"
    if polygon_self_intersects(vertices):
        return "the polygon intersects itself; list the vertices in order around its boundary"
    area = polygon_signed_area(vertices)
    if abs(area) < 1e-9:
        return "the polygon has no area (its vertices are collinear or repeated)"
    if area > 0:
        # driving_log_replayer documents clockwise and rejects the other way round
        # (its own check is wrong for non-rectangles; the signed area is not).
        return (f"the polygon is counter-clockwise (signed area {area:.3g} m^2); driving_log_replayer "
                "requires clockwise: list the same vertices in reverse order")
    return None


class ProposedAreaSpec(Section):
    polygon_2d: list[tuple[float, float]] = Field(description="the area's vertices [x, y] in base_link, clockwise")
    z_min: float = Field(description="m, the area's floor in base_link")
    z_max: float = Field(description="m, the area's ceiling in base_link, at least z_min")

    @field_validator("polygon_2d")
    @classmethod
    def _valid_polygon(cls, v):
        problem = polygon_problem(np.asarray(v, dtype=float).reshape(-1, 2))
        if problem:
            raise ValueError(problem)
        return v

    @model_validator(mode="after")
    def _z_range(self):
        if self.z_max < self.z_min:
            raise ValueError(f"z_max ({self.z_max}) is below z_min ({self.z_min})")
        return self

    @property
    def vertices(self) -> np.ndarray:
        return np.asarray(self.polygon_2d, dtype=np.float64)


class NonDetectionCondition(Section):
    PassRate: float = Field(ge=0.0, le=100.0, description=(
        "% of frames in which the proposed area must hold no obstacle point"))
    ProposedArea: ProposedAreaSpec = Field(description="the area in front of the vehicle that must stay empty")


class ConditionsSpec(Section):
    Detection: DetectionCondition | None = Field(None, description=(
        "the annotated boxes must hold points (format 0.3.0); null: not judged"))
    ObstacleDetection: LegacyDetectionCondition | None = Field(None, description=(
        "the 0.1.0 / 0.2.0 name of Detection, with the targets from target_uuids"))  # 0.1.0 / 0.2.0 name
    NonDetection: NonDetectionCondition | None = Field(None, description=(
        "no obstacle point in the proposed area; null: not judged"))

    @model_validator(mode="after")
    def _by_version(self, info: ValidationInfo):
        version = (info.context or {}).get("version")
        if self.ObstacleDetection is not None and self.Detection is not None:
            raise ValueError("give Detection (0.3.0) or ObstacleDetection (0.1.0/0.2.0), not both")
        if version == V3 and self.ObstacleDetection is not None:
            raise ValueError("ObstacleDetection is the 0.1.0/0.2.0 name; UseCaseFormatVersion 0.3.0 calls it Detection")
        if version in LEGACY and self.Detection is not None:
            raise ValueError(f"Detection is the 0.3.0 name; UseCaseFormatVersion {version} calls it ObstacleDetection")
        if self.Detection is None and self.ObstacleDetection is None and self.NonDetection is None:
            raise ValueError("nothing to evaluate: Detection and NonDetection are both null")
        return self

    @property
    def detection(self) -> DetectionCondition | None:
        if self.ObstacleDetection is not None:
            return DetectionCondition(PassRate=self.ObstacleDetection.PassRate)
        return self.Detection

    @property
    def detection_key(self) -> str:
        return "ObstacleDetection" if self.ObstacleDetection is not None else "Detection"


class EvaluationConfigDict(Section):
    evaluation_task: Literal["sensing"] = Field("sensing", description=(
        "driving_log_replayer's task; sensing is the one there is"))
    target_uuids: list[str] | None = Field(None, description=(
        "annotation UUIDs judged for Detection; null: every annotated box"))
    box_scale_0m: PositiveFloat = Field(1.0, description=(
        "scale of a box at 0 m from the vehicle (interpolated linearly to box_scale_100m)"))
    box_scale_100m: PositiveFloat = Field(1.0, description="scale of a box at 100 m from the vehicle")
    min_points_threshold: NonNegativeInt = Field(1, description="points a target box must hold to count as detected")
    label_prefix: str | None = Field(None, description=(
        "driving_log_replayer sets it to autoware; not read here"))


class SensingSpec(Section):
    evaluation_config_dict: EvaluationConfigDict = Field(default_factory=EvaluationConfigDict, description=(
        "driving_log_replayer's sensing evaluation settings"))


class PointCloudOptions(Section):
    Topic: str = Field("/perception/obstacle_segmentation/pointcloud", description=(
        "the bag's topic of the obstacle points that are judged"))
    RawTopic: str | None = Field("/sensing/lidar/concatenated/pointcloud", description=(
        "the raw cloud handed to a driveeval_pointclouds filter; null: the dataset's lidar sweeps"))
    TopicRateDiagnostic: str = Field("topic_state_monitor_obstacle_segmentation_pointcloud", description=(
        "the diagnostics name whose topic rate state each frame reports (Unknown when the bag has none)"))


class ArtefactOptions(Section):
    FailingFramePlots: NonNegativeInt = Field(5, description="bird's-eye PNGs of the first failing frames")


#: memory a ghost point takes while a cloud is perturbed: the point (up to 32 bytes with its
#: fields), the normal and uniform draws that place it (~40 bytes), rounded up
GHOST_POINT_BYTES = 96.0


class ObstaclePerturbation(SearchSpec):
    """What a robustness search may do to each raw cloud (strategies.CloudPerturbation)."""

    NEUTRAL: ClassVar[dict[str, float]] = {"Dropout": 0.0, "RangeNoise": 0.0, "GhostPoints": 0}
    BOUNDS: ClassVar[dict[str, tuple[float, float, str]]] = {
        "Dropout": (0.0, 1.0, "a fraction of the points, within [0, 1]"),
        "RangeNoise": (0.0, float("inf"), "a standard deviation (m) cannot be negative")}
    WHOLE: ClassVar[frozenset[str]] = frozenset({"GhostPoints"})

    Dropout: tuple[float, float] | None = Field(None, description=(
        "[low, high]: the fraction of raw points dropped; the range holds 0"))
    RangeNoise: tuple[float, float] | None = Field(None, description=(
        "[low, high] m: standard deviation of noise along each point's ray; the range holds 0"))
    GhostPoints: tuple[NonNegativeInt, NonNegativeInt] | None = Field(None, description=(
        "[low, high]: points of a ghost (spray, dust) cluster put in the non-detection area; the range holds 0"))
    # Each searched frame's raw cloud is read once and kept: this bounds the memory of a long bag.
    Frames: PositiveInt = Field(200, description="the first judged frames searched (their raw clouds stay in memory)")

    def strategy_ranges(self) -> dict[str, tuple]:
        """The ranges as ``cloud_perturbations`` takes them (ghost points as whole numbers)."""
        ranges: dict[str, tuple] = dict(self.ranges())
        if "ghost_points" in ranges:
            ranges["ghost_points"] = tuple(int(b) for b in ranges["ghost_points"])
        return ranges


class ObstacleSegmentationConfig(ConditionsModel):
    Conditions: ConditionsSpec = Field(description=(
        "what each frame must meet: Detection (or ObstacleDetection) and NonDetection"))
    SensingEvaluationConfig: SensingSpec = Field(default_factory=SensingSpec, description=(
        "driving_log_replayer's sensing settings: targets, box scales, minimum points"))
    PointCloud: PointCloudOptions = Field(default_factory=PointCloudOptions, description=(
        "which topics hold the clouds (keys of our own; a driving_log_replayer file needs none)"))
    Artefacts: ArtefactOptions = Field(default_factory=ArtefactOptions, description="the pictures each item leaves")
    Perturbation: ObstaclePerturbation | None = Field(None, description=(
        "a robustness search of the point-cloud filter (needs driveeval_pointclouds overridden with a filter)"))

    @model_validator(mode="after")
    def _ghosts_need_an_area(self):
        p = self.Perturbation
        if p is not None and p.GhostPoints is not None and max(p.GhostPoints) > 0 \
                and self.Conditions.NonDetection is None:
            # A ghost cluster is placed in the non-detection area: without one it has nowhere to go.
            raise ValueError("Perturbation.GhostPoints needs a NonDetection condition: the ghost cluster is "
                             "placed in its ProposedArea")
        if p is not None and p.GhostPoints is not None:
            most = max(p.GhostPoints)
            check_fits(("Perturbation", "GhostPoints"), list(p.GhostPoints), GHOST_POINT_BYTES * most * p.Batch,
                       f"{p.Batch} perturbed clouds of up to {most} ghost points each")
        return self

    def condition_record(self) -> dict:
        """The ``Condition`` driving_log_replayer writes first in result.jsonl."""
        return self.Conditions.model_dump(mode="json", exclude_none=False,
                                          exclude={"ObstacleDetection"} if self.Conditions.ObstacleDetection is None
                                          else {"Detection"})
