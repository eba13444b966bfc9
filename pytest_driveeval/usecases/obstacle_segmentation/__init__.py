"""Use case ``obstacle_segmentation``: driving_log_replayer's scenarios, evaluated without ROS.

Each cloud of ``/perception/obstacle_segmentation/pointcloud`` in the dataset's
input_bag is streamed (one message in memory) and judged as driving_log_replayer
does: ground truth within 75 ms of the cloud stamp (else FrameSkip += 1); target
boxes scaled in x/y by ``box_scale_0m .. box_scale_100m`` over 0..100 m; a box
with >= ``min_points_threshold`` points is detected, one with visibility "none"
is a Warn; the frame's Detection is Warn if any target warns, Success if every
target is detected and the topic rate is fine, else Fail.  NonDetection: the
ProposedArea prism in base_link, intersected with the map's road lanelets (moved
to base_link by TF at the cloud stamp), minus every scaled box, must hold no
point.  A part passes when its rate >= PassRate.  Artefacts: ``result.jsonl``
in driving_log_replayer's line format and bird's-eye PNGs of the first failing
frames (``Artefacts.FailingFramePlots``, default 5).

Point clouds.  ``driveeval_pointclouds`` defaults to ``PointCloud.Topic`` of the
input_bag, or, for a dataset without input_bag, to its key-frame lidar sweeps
(data/LIDAR_*/*.pcd.bin moved to base_link by their calibration; one frame per
sample).  To evaluate a point-cloud FILTER in-process, override the fixture
with a callable ``raw_points -> obstacle_points``; the use case then streams
``PointCloud.RawTopic`` (or the sweeps) and applies it::

    @pytest.fixture
    def driveeval_pointclouds():
        return my_ground_filter          # structured (x, y, z, ...) in, same or (N, 3) out

Any other value is taken as the clouds themselves (iterable of
``(stamp_ns, frame_id, points)``).  ``PointCloud.RawTopic: null`` feeds the
filter the lidar sweeps even when the dataset has a bag.

Robustness search.  A ``Perturbation`` section (Dropout, RangeNoise,
GhostPoints ranges; see ``config``) probes such a filter: hypothesis perturbs
the raw cloud of one judged frame at a time (``perturb``), runs the filter and
judges the frame; the item fails with the smallest perturbation that fails a
frame, that frame's bird's-eye PNG and the one-line replay
(``--driveeval-replay 'frame=1,dropout=0.42'``).  It needs the fixture to be a
filter: with clouds it is an error.  See ``robustness``.

Where we differ from driving_log_replayer (deliberately):

- Topic rate: DLR's callback skips the status it means to read (``if name ==
  TARGET: return``), starts at False and so fails every frame of a bag without
  diagnostics.  We read /diagnostics_agg (else /diagnostics), take the statuses
  whose name contains ``PointCloud.TopicRateDiagnostic``, fail a frame at level
  >= ERROR, and with no such status say "Unknown" (TopicRate: "Unknown" in the
  jsonl) and do not fail the frame.
- A failed TF lookup (map -> base_link, or the cloud's frame -> base_link) is an
  error for that frame: both parts Fail, the jsonl line carries ``Error`` and the
  outcome a finding; never an identity transform.
- No map in the dataset: the area is the ProposedArea prism alone (DLR needs one).
  A map with no TF to place it (input_bag/ missing, or a bag without /tf) is one
  error naming the bag, not a failed lookup in every frame.
- Overlapping lanelets: a point counts once (union), not once per lanelet.
- ProposedArea must be clockwise by signed area (DLR's check is wrong for
  non-rectangles); counter-clockwise or self-intersecting polygons are errors at
  their YAML line.  Both Detection and NonDetection null is an error.
- UUIDs (BoundingBoxConfig / target_uuids) not in the dataset are an error naming
  them at their YAML line (DLR silently evaluates nothing for them).
- BoundingBoxConfig Start/End are absolute seconds of the cloud header stamp, as
  in DLR; a frame whose windows hold no UUID is skipped and counted in FrameSkip.
- Visibility "none" and nuScenes' "v0-40" both warn (perception_eval's alias).
- jsonl: Stamp.System equals Stamp.ROS (the cloud stamp) so output is
  deterministic; Detection carries ``Objects`` (every target; DLR's ``Info``
  keeps one per kind); the final line's GraphData has PointcloudCount only.

This package: ``config`` (the scenario's YAML), ``sources`` (point-cloud
streams), ``evaluate`` (the per-frame judgement; it writes nothing), ``result``
(verdicts and pass rates), ``artefacts`` and ``jsonl`` (result.jsonl and PNGs,
fed frame by frame), ``assertions`` (``assert_pass_rate`` for Python tests),
``perturb`` (dropout, range noise, ghost clusters) and ``robustness`` (the search).
"""
from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

from ...core.errors import DriveEvalError, Problem, ScenarioError
from ...core.outcome import FAILED, PASSED, Finding, Outcome
from ...core.usecase import RunContext, UseCase, register_usecase
from . import regression
from .config import LEGACY, V3, ObstacleSegmentationConfig

if TYPE_CHECKING:
    from ...io.t4.t4dataset import T4Dataset
    from .evaluate import UnknownUUIDError
    from .result import ObstacleResult


@register_usecase
class ObstacleSegmentation(UseCase):
    name = "obstacle_segmentation"
    format_versions = (*LEGACY, V3)
    config_model = ObstacleSegmentationConfig
    fixtures = ("driveeval_dataset", "driveeval_pointclouds")
    regression_figures = regression.FIGURES

    def regression_units(self, outcome: Outcome):
        return regression.frame_units(outcome)

    # The evaluation (numpy kernels, bag reader, plots) is imported when a scenario
    # runs, so that registering the use case stays cheap.
    def load_dataset(self, ctx: RunContext) -> T4Dataset:
        from ...io.t4.t4dataset import T4Dataset

        return T4Dataset(super().load_dataset(ctx))

    def load_pointclouds(self, ctx: RunContext) -> Any:
        from .sources import dataset_pointclouds

        return dataset_pointclouds(ctx.fixtures["driveeval_dataset"], ctx.scenario.config.PointCloud.Topic)

    def run(self, config: ObstacleSegmentationConfig, ctx: RunContext) -> Outcome:
        from .artefacts import ObstacleArtefacts
        from .sources import FilteredPointClouds, dataset_pointclouds

        dataset: T4Dataset = ctx.fixtures["driveeval_dataset"]
        clouds = ctx.fixtures["driveeval_pointclouds"]
        if config.Perturbation is not None:
            return self._search(config, ctx, dataset, clouds)
        if _is_filter(clouds):
            clouds = FilteredPointClouds(dataset_pointclouds(dataset, config.PointCloud.RawTopic), clouds)
        jsonl = ctx.artefact("result.jsonl")
        evaluation = _load(ctx, config, dataset)
        # Opened only once the inputs load: a scenario with a bad UUID, bag or map leaves no result.jsonl.
        artefacts = ObstacleArtefacts(jsonl, config.condition_record(), ctx.output_dir,
                                      config.Artefacts.FailingFramePlots)
        try:
            with artefacts:
                result = evaluation.run(clouds, on_frame=artefacts, progress=ctx.progress_of("frames"))
        except DriveEvalError as exc:
            partial = getattr(exc, "partial_result", None)
            if partial is not None and partial.frames:
                exc.outcome = self._outcome(partial, config, artefacts.files, error=str(exc))
            raise
        return self._outcome(result, config, artefacts.files)

    def _search(self, config: ObstacleSegmentationConfig, ctx: RunContext, dataset: T4Dataset, point_filter: Any
                ) -> Outcome:
        """The Perturbation section's robustness search of the filter (see ``robustness``)."""
        from ...search.item import run_item
        from .robustness import FilterSearch, read_frames
        from .sources import dataset_pointclouds

        if not _is_filter(point_filter):
            keypath = ("Evaluation", "Perturbation")
            raise ScenarioError(ctx.scenario.path, [Problem(
                "a Perturbation section searches for what breaks a point-cloud filter, so driveeval_pointclouds "
                "must be overridden in conftest.py to return a callable raw_points -> obstacle_points (it is "
                f"{type(point_filter).__name__}: clouds, not a filter)", ctx.scenario.line_of(*keypath), keypath)])
        evaluation = _load(ctx, config, dataset)
        frames, skipped, more = read_frames(evaluation, dataset_pointclouds(dataset, config.PointCloud.RawTopic),
                                            config.Perturbation.Frames)
        if not frames:
            result = evaluation.new_result()
            result.skipped = skipped
            return self._outcome(result, config, {})
        search = FilterSearch(evaluation, frames, point_filter, ctx.seed)
        outcome = run_item(self.name, search.searchable(config.Perturbation.strategy_ranges(),
                                                        lambda example: self._show(config, ctx, search, example)),
                           config.Perturbation, ctx)
        searched = {"searched": len(frames), "skipped_before": skipped, "more_not_searched": more}
        outcome.details = {**outcome.details, "search_frames": searched}
        if more:
            outcome.summary += (f" (the first {len(frames)} frames only: Perturbation.Frames bounds the raw clouds "
                                "kept in memory)")
        return outcome

    def _show(self, config: ObstacleSegmentationConfig, ctx: RunContext, search, example) -> Outcome:
        """One frame under one perturbation, judged and written as the item does, always with its picture."""
        from ...strategies import describe
        from .artefacts import ObstacleArtefacts, frame_png

        frame, points = search.judge(example.case, example.perturbation)
        result = search.evaluation.new_result()
        note = describe(example.perturbation)
        artefacts = ObstacleArtefacts(ctx.artefact("result.jsonl"), config.condition_record(), ctx.output_dir,
                                      max_plots=1, title_note=note)
        with artefacts:
            result.add(frame)
            artefacts(frame, points, result)
        if not artefacts.plots:  # a passing frame (a replay of the edge) is shown too
            artefacts.plots.append(frame_png(ctx.output_dir, frame, points, note))
        outcome = self._outcome(result, config, artefacts.files)
        outcome.details = {**outcome.details, "frame": example.case,
                           "perturbation": example.perturbation.to_json()}
        return outcome

    def _outcome(self, result: ObstacleResult, config, files: dict[str, Path], error: str | None = None) -> Outcome:
        cond = config.Conditions
        findings: list[Finding] = []
        for part, key in (("detection", cond.detection_key), ("non_detection", "NonDetection")):
            texts, failing = result.failing_texts(part)
            finding = result.counters[part].finding(
                result.required(part), what=key, failing=texts, failing_total=failing, figure=f"{part}_rate",
                keypath=("Evaluation", "Conditions", key, "PassRate"))
            if finding is not None:
                findings.append(finding)
        errors = [e for e in result.errors if e]
        if errors:
            findings.append(Finding(f"{len(errors)} frame(s) could not be evaluated: {errors[0]}",
                                    figure="frame_errors", value=len(errors)))
        if result.frames == 0:
            findings.append(Finding(f"no frame evaluated: {result.skipped} cloud(s) skipped (no ground truth within "
                                    "75 ms, or no UUID in its BoundingBoxConfig window)"))
        unknown_rate = result.frames and all(t is None for t in result.topic_rate)
        figures = {"frames": result.frames, "frames_skipped": result.skipped, "frame_errors": len(errors)}
        if result.detection_pass_rate is not None:
            figures.update(detection_rate=result.rate("detection"), detection_warn=result.counters["detection"].warned)
        if result.non_detection_pass_rate is not None:
            figures.update(non_detection_rate=result.rate("non_detection"),
                           max_area_points=max(result.area_points, default=0))
        summary = result.summary + f" ({result.skipped} skipped)" + (
            "; topic rate unknown (no diagnostics status)" if unknown_rate else "")
        if error:
            summary += f"; stopped early: {error}"
        details = {"frames": [{"frame": n, "stamp_ns": s, "detection": d, "non_detection": nd, "topic_rate": t,
                               "area_points": a, "error": e} for n, s, d, nd, t, a, e in
                              zip(result.frame_names, result.stamps_ns, result.detection, result.non_detection,
                                  result.topic_rate, result.area_points, result.errors)]}
        ok = result.success and not errors and error is None
        return Outcome(self.name, PASSED if ok else FAILED, summary, figures=figures, findings=findings,
                       artefacts=dict(files), details=details)


def _is_filter(clouds: Any) -> bool:
    """A point-cloud filter (raw -> obstacle points), not the clouds themselves."""
    return callable(clouds) and not hasattr(clouds, "__iter__")


def _load(ctx: RunContext, config, dataset: T4Dataset):
    from .evaluate import ObstacleEvaluation, UnknownUUIDError

    try:
        return ObstacleEvaluation.load(dataset, config)
    except UnknownUUIDError as exc:
        raise ScenarioError(ctx.scenario.path, _uuid_problems(ctx, config, exc)) from None


def _uuid_problems(ctx: RunContext, config, exc: UnknownUUIDError) -> list[Problem]:
    problems = []
    det = config.Conditions.Detection
    for uuid in exc.uuids:
        keypath: tuple = ()
        for i, entry in enumerate((det.BoundingBoxConfig or []) if det is not None else []):
            if uuid in entry:
                keypath = ("Evaluation", "Conditions", "Detection", "BoundingBoxConfig", i, uuid)
        targets = config.SensingEvaluationConfig.evaluation_config_dict.target_uuids or []
        if not keypath and uuid in targets:
            keypath = ("Evaluation", "SensingEvaluationConfig", "evaluation_config_dict", "target_uuids",
                       targets.index(uuid))
        where = ctx.dataset.path if ctx.dataset is not None else "the dataset"
        problems.append(Problem(f"UUID '{uuid}' is not an instance of dataset {where} (annotation/instance.json)",
                                ctx.scenario.line_of(*keypath), keypath))
    return problems
