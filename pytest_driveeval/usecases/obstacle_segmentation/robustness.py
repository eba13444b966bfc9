"""The obstacle-segmentation robustness search: which degraded raw cloud makes the filter fail a frame?

A case is one judged frame (numbered 0..n-1 in stream order); an example is
that frame's raw cloud under a :class:`~pytest_driveeval.strategies.CloudPerturbation`
(:mod:`.perturb`), passed through the filter under test and judged as the
item judges a frame.  It fails when the frame's Detection or NonDetection is
"Fail"; a "Warn" (an occluded target) is not the filter's doing and no
perturbation changes it, so it does not count.  The raw clouds are read once
and kept, at most ``Perturbation.Frames`` of them.

The random numbers of an example come from the item's seed and its frame
(:func:`.perturb.example_rng`), the same for every magnitude tried on that
frame, so that replaying ``frame=3,dropout=0.21`` with the same seed gives
exactly the cloud the search judged.
"""
from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass, replace

import numpy as np

from ...core.deadline import guarded_call, note
from ...core.errors import DriveEvalError
from ...io.t4.t4dataset import GroundTruth
from ...io.ros.tf import TransformError
from ...metrics.pointcloud import BoxSet
from ...core.outcome import Outcome
from ...search.engine import Example, Verdict
from ...search.item import Searchable
from ...strategies import CloudPerturbation, cloud_perturbations
from .evaluate import ObstacleEvaluation
from .perturb import GhostRegion, example_rng, perturb_cloud
from .result import FrameVerdict

__all__ = ["FilterSearch", "SearchFrame", "frame_reason", "read_frames"]


@dataclass(frozen=True)
class SearchFrame:
    """A judged frame's raw cloud and what perturbing and judging it needs."""

    name: str                 # the sample's index, as the item names frames
    stamp_ns: int
    frame_id: str
    raw: np.ndarray
    gt: GroundTruth           # in base_link
    targets: list[str] | None
    origin: np.ndarray        # the sensor in the raw cloud's frame (range noise is along rays from it)
    ghost: GhostRegion | None  # None: no non-detection area in this frame (no road in it, or a TF error)


def sensor_origin(evaluation: ObstacleEvaluation, sample_token: str, frame_id: str) -> np.ndarray:
    """Where the rays start, in the cloud's frame.  A cloud in base_link (the lidar sweeps, a
    concatenated topic) starts at the lidar's calibrated position there; a cloud in any other frame
    is taken to be in its sensor's frame, so at that frame's origin; so is a base_link cloud of a
    dataset without a calibrated lidar."""
    if frame_id in ("base_link", ""):
        try:
            return np.asarray(evaluation.dataset.lidar_to_base_link(sample_token)[1], dtype=np.float64)
        except (DriveEvalError, LookupError, ValueError):
            pass
    return np.zeros(3)


def read_frames(evaluation: ObstacleEvaluation, raw_clouds: Iterable[tuple], limit: int
                ) -> tuple[list[SearchFrame], int, bool]:
    """The first ``limit`` judged frames of ``raw_clouds``, the clouds skipped before them, and
    whether more clouds were left unread."""
    params = evaluation.cfg.SensingEvaluationConfig.evaluation_config_dict
    frames: list[SearchFrame] = []
    skipped = 0
    for stamp_ns, frame_id, points in raw_clouds:
        if len(frames) == limit:
            return frames, skipped, True
        stamp_ns = int(stamp_ns)
        selected = evaluation.select(stamp_ns)
        if selected is None:
            skipped += 1
            continue
        name, gt, targets = selected
        note(frame=name, **{"raw cloud stamped": f"{stamp_ns} ns"})
        gt_base = gt.to_base_link()
        map_T_base, _, error = evaluation.locate(name, stamp_ns, frame_id, np.zeros((0, 3)))
        area = evaluation.area(map_T_base) if error is None else None
        ghost = None
        if area is not None and not area.empty:
            boxes = BoxSet.from_ground_truth(gt_base.centers, gt_base.sizes, gt_base.yaws, params.box_scale_0m,
                                             params.box_scale_100m)
            cloud_T_base = None
            if frame_id not in ("base_link", ""):
                try:
                    cloud_T_base = evaluation.tf.lookup(frame_id, "base_link", stamp_ns)
                except (TransformError, AttributeError):
                    boxes = None  # the frame fails on its TF error anyway; no ghost to place
            ghost = GhostRegion(area, boxes, cloud_T_base) if boxes is not None else None
        frames.append(SearchFrame(name, stamp_ns, frame_id, np.asarray(points), gt_base, targets,
                                  sensor_origin(evaluation, gt.sample_token, frame_id), ghost))
    return frames, skipped, False


def frame_reason(frame: FrameVerdict, min_points: int) -> str:
    """Why a judged frame failed, in a line: the boxes short of points, the points in the area."""
    if frame.error:
        return frame.error
    why = []
    if frame.topic_rate is False:
        why.append("topic rate in ERROR")
    if frame.detection == "Fail":
        for i in np.flatnonzero(frame.target & (frame.status == "Fail")):
            why.append(f"box {str(frame.gt.instance_tokens[i])[:8]}.. has {int(frame.counts.counts[i])} of "
                       f"{min_points} point(s) needed")
        if not frame.target.any():
            why.append("no target box in the frame")
    if frame.non_detection == "Fail":
        why.append(f"{len(frame.counts.area_points)} point(s) in the non-detection area")
    return "; ".join(why)


class FilterSearch:
    """Judges examples (frame, perturbation) through the filter under test."""

    def __init__(self, evaluation: ObstacleEvaluation, frames: list[SearchFrame],
                 point_filter: Callable[[np.ndarray], np.ndarray], seed: int):
        self.evaluation, self.frames, self.filter, self.seed = evaluation, frames, point_filter, seed

    def perturbed(self, case: int, perturbation: CloudPerturbation) -> np.ndarray:
        frame = self.frames[case]
        if frame.ghost is None and perturbation.ghost_points:
            # Nowhere to put them: ghosts could only fail an area this frame does not have (or
            # cannot check: its TF error fails the frame anyway).
            perturbation = replace(perturbation, ghost_points=0)
        return perturb_cloud(frame.raw, perturbation, example_rng(self.seed, case), origin=frame.origin,
                             ghost=frame.ghost)

    def judge(self, case: int, perturbation: CloudPerturbation) -> tuple[FrameVerdict, np.ndarray]:
        """The frame's verdict under ``perturbation`` and the filtered cloud in base_link."""
        frame = self.frames[case]
        note(frame=frame.name, perturbation=lambda: str(perturbation),
             **{"the point-cloud filter on the cloud stamped": f"{frame.stamp_ns} ns"})
        filtered = np.asarray(guarded_call(self.filter, self.perturbed(case, perturbation)))
        map_T_base, points, error = self.evaluation.locate(frame.name, frame.stamp_ns, frame.frame_id, filtered)
        return self.evaluation.judge(frame.name, frame.stamp_ns, frame.gt, points, frame.targets, map_T_base,
                                     error), points

    def evaluate_many(self, examples: list[Example]) -> list[Verdict]:
        min_points = self.evaluation.cfg.SensingEvaluationConfig.evaluation_config_dict.min_points_threshold
        verdicts = []
        for example in examples:
            judged, _ = self.judge(example.case, example.perturbation)
            verdicts.append(Verdict(judged.failed, frame_reason(judged, min_points) if judged.failed else "",
                                    {"frame": example.case, "stamp_ns": judged.stamp_ns}))
        return verdicts

    def searchable(self, ranges: dict[str, tuple], show: Callable[[Example], Outcome]) -> Searchable:
        return Searchable(case_name="frame", case_labels=list(range(len(self.frames))),
                          perturbation_type=CloudPerturbation, perturbations=cloud_perturbations(**ranges),
                          evaluate_many=self.evaluate_many, show=show)
