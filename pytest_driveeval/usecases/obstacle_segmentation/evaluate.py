"""Stream point clouds and judge each frame as driving_log_replayer's obstacle_segmentation does.

    result = evaluate_obstacle_segmentation(T4Dataset(root), bag_pointclouds(root), config)

``config`` is the use case's model (or the same mapping as in a scenario's
``Evaluation``).  Point clouds are any iterable of ``(stamp_ns, frame_id,
points)`` with ``points`` structured (x, y, z, ...) or (N, >=3); clouds not in
base_link are moved there by TF at their stamp.  The frame semantics, and where
we differ from driving_log_replayer, are in this package's ``__init__``.

Nothing here writes a file: a frame's points are in memory during its step
only, so whoever keeps lines or plots of frames passes ``on_frame``, called
after each judged frame with ``(frame, points, result)`` (``artefacts.py``).
"""
from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass
from functools import cached_property
from typing import Any, Protocol

import numpy as np

from ...core.deadline import note
from ...core.errors import DataError, DriveEvalError
from ...io.t4.t4dataset import GroundTruth, T4Dataset
from ...io.ros.tf import TransformError
from ...metrics.pointcloud import Area, BoxSet, evaluate_cloud, xyz_columns
from .config import ObstacleSegmentationConfig
from .result import FrameVerdict, ObstacleResult

OCCLUDED = ("none", "v0-40")  # perception_eval's Visibility.NONE and its nuScenes alias
GT_TOLERANCE_US = 75_000


class UnknownUUIDError(DataError):
    def __init__(self, message: str, uuids: list[str]):
        super().__init__(message)
        self.uuids = uuids


class FrameSink(Protocol):
    """Called after each judged frame; ``points`` is its cloud in base_link (gone after the call)."""

    def __call__(self, frame: FrameVerdict, points: np.ndarray, result: ObstacleResult) -> None: ...


def _config(config: Any) -> ObstacleSegmentationConfig:
    if hasattr(config, "condition_record"):  # the model (isinstance fails across a re-import, e.g. pytester)
        return config
    data = dict(config)
    version = data.pop("UseCaseFormatVersion", "0.3.0")
    data = {k: v for k, v in data.items() if k not in ("UseCaseName", "Datasets")}
    return ObstacleSegmentationConfig.model_validate(data, context={"version": version})


def check_uuids(dataset: T4Dataset, cfg) -> None:
    det = cfg.Conditions.detection
    wanted = list((det.windows() or {}) if det is not None else {})
    wanted += cfg.SensingEvaluationConfig.evaluation_config_dict.target_uuids or []
    known = {r.get("token") for r in dataset.table("instance")}
    missing = [u for u in dict.fromkeys(wanted) if u not in known]
    if missing:
        raise UnknownUUIDError(f"UUID(s) {', '.join(missing)} not in {dataset.annotation_dir / 'instance.json'} "
                               f"({len(known)} instances)", missing)


def _diagnostic_lookup(diagnostics, name_part: str) -> Callable[[int], bool | None]:
    """stamp_ns -> True/False/None from the worst matching status in force (None: none seen yet)."""
    if diagnostics is None:
        return lambda stamp_ns: None
    names = [n for n in diagnostics.status_names() if name_part in n]
    if not names:
        return lambda stamp_ns: None

    def lookup(stamp_ns: int):
        levels = [int(diagnostics.levels_at(n, stamp_ns)[0]) for n in names]
        levels = [lv for lv in levels if lv >= 0]
        return None if not levels else max(levels) < 2  # ERROR (2) and STALE (3) fail, as DLR's >= ERROR
    return lookup


def _auto_inputs(dataset: T4Dataset, tf, diagnostics, lanelets):
    from ...io.t4.lanelet2 import load_lanelet_map
    from ...io.ros.rosbag import Bag

    bag = dataset.input_bag
    if bag is not None and (isinstance(tf, str) or isinstance(diagnostics, str)):
        with Bag(bag) as b:
            if isinstance(tf, str):
                tf = b.read_tf() if {"/tf", "/tf_static"} & set(b.topics) else None
            if isinstance(diagnostics, str):
                topic = next((t for t in ("/diagnostics_agg", "/diagnostics") if t in b.topics), None)
                diagnostics = b.read_diagnostics(topic) if topic else None
    tf = None if isinstance(tf, str) else tf
    diagnostics = None if isinstance(diagnostics, str) else diagnostics
    if isinstance(lanelets, str):
        lanelets = load_lanelet_map(dataset.lanelet2_map) if dataset.lanelet2_map is not None else None
    return tf, diagnostics, lanelets


def _no_tf_for_the_map(dataset: T4Dataset) -> str:
    """Why no frame could place the NonDetection area: said once, rather than as every frame's error."""
    need = (f"the NonDetection area is cut to the road lanelets of {dataset.lanelet2_map} at the ego's pose "
            "(TF map -> base_link), which the bag's /tf holds")
    if dataset.input_bag is None:
        return f"t4_dataset {dataset.root}: its input bag {dataset.root / 'input_bag'} is missing: {need}"
    return f"{dataset.input_bag}: the bag has no /tf or /tf_static: {need}"


def _area(cond, lanelets, map_T_base) -> Area:
    poly = cond.ProposedArea.vertices
    zmin, zmax = cond.ProposedArea.z_min, cond.ProposedArea.z_max
    if lanelets is None:
        return Area(poly, zmin, zmax, None)
    # As driving_log_replayer: the polygon goes to map at base_link's pose, lanelet
    # outlines come back at the polygon's mean map z; only x/y are kept.
    in_map = np.c_[poly, np.zeros(len(poly))] @ map_T_base[:3, :3].T + map_T_base[:3, 3]
    near = lanelets.near(lanelets.road(), in_map[:, :2].min(axis=0), in_map[:, :2].max(axis=0))
    base_T_map = np.linalg.inv(map_T_base)
    z = in_map[:, 2].mean()
    clips = [(np.c_[ll.polygon, np.full(len(ll.polygon), z)] @ base_T_map[:3, :3].T + base_T_map[:3, 3])[:, :2]
             for ll in near]
    return Area(poly, zmin, zmax, clips)


@dataclass
class ObstacleEvaluation:
    """A dataset with its checked config and what every frame is judged against (TF, diagnostics, map).

    Loading and running are two steps so that a caller can tell a bad input
    (UUIDs, bag, map) from a failure while streaming, e.g. before it opens files."""

    dataset: T4Dataset
    cfg: ObstacleSegmentationConfig
    tf: Any
    lanelets: Any
    topic_ok: Callable[[int], bool | None]

    @classmethod
    def load(cls, dataset, config, *, tf: Any = "auto", diagnostics: Any = "auto",
             lanelets: Any = "auto") -> ObstacleEvaluation:
        """``tf`` / ``diagnostics`` / ``lanelets`` default to the dataset's bag and map."""
        ds = dataset if isinstance(dataset, T4Dataset) else T4Dataset(dataset)
        cfg = _config(config)
        check_uuids(ds, cfg)
        tf_from_bag = isinstance(tf, str)
        tf, diagnostics, lanelets = _auto_inputs(ds, tf, diagnostics, lanelets)
        if tf_from_bag and tf is None and lanelets is not None and cfg.Conditions.NonDetection is not None:
            raise DataError(_no_tf_for_the_map(ds))
        return cls(ds, cfg, tf, lanelets, _diagnostic_lookup(diagnostics, cfg.PointCloud.TopicRateDiagnostic))

    def run(self, pointclouds: Iterable[tuple], on_frame: FrameSink | None = None,
            progress: Callable[[int, int], None] | None = None) -> ObstacleResult:
        """Judge every cloud.  On a DataError the frames judged so far stay on it as ``partial_result``.
        ``progress(done, total)``: frames judged of the dataset's annotated frames."""
        result = self.new_result()
        total = len(self.dataset.sample_tokens)
        if progress is not None:
            progress(0, total)
        try:
            for stamp_ns, frame_id, points in pointclouds:
                stamp_ns = int(stamp_ns)
                selected = self.select(stamp_ns)
                if selected is None:
                    result.skipped += 1  # DLR's FrameSkip: no ground truth within 75 ms / no UUID in its window
                    continue
                name, gt, targets = selected
                note(frame=name, **{"cloud stamped": f"{stamp_ns} ns"})
                map_T_base, points, error = self.locate(name, stamp_ns, frame_id, points)
                frame = self.judge(name, stamp_ns, gt.to_base_link(), points, targets, map_T_base, error)
                result.add(frame)
                if on_frame is not None:
                    on_frame(frame, points, result)
                if progress is not None:
                    progress(result.frames, total)
        except DriveEvalError as exc:  # bad data, or out of time: the frames judged so far are kept
            exc.partial_result = result
            raise
        return result

    def new_result(self) -> ObstacleResult:
        det, nd = self.cfg.Conditions.detection, self.cfg.Conditions.NonDetection
        return ObstacleResult(detection_pass_rate=det.PassRate if det else None,
                              non_detection_pass_rate=nd.PassRate if nd else None)

    @cached_property
    def _sample_index(self) -> dict[str, int]:
        return {t: i for i, t in enumerate(self.dataset.sample_tokens)}

    @cached_property
    def _windows(self) -> dict[str, tuple[float, float]] | None:
        det = self.cfg.Conditions.detection
        return det.windows() if det is not None else None

    def select(self, stamp_ns: int) -> tuple[str, GroundTruth, list[str] | None] | None:
        """The frame a cloud stamped ``stamp_ns`` is judged as: its name, ground truth (in the
        dataset's frame) and target UUIDs (None: all); None when the cloud is skipped."""
        cfg, windows = self.cfg, self._windows
        gt = self.dataset.ground_truth_at(stamp_ns // 1000, GT_TOLERANCE_US)
        targets = cfg.SensingEvaluationConfig.evaluation_config_dict.target_uuids
        if windows is not None:
            targets = [u for u, (s, e) in windows.items() if s <= stamp_ns / 1e9 <= e]
        if gt is None or (windows is not None and not targets):
            return None
        return str(self._sample_index[gt.sample_token]), gt, targets

    def area(self, map_T_base: np.ndarray | None) -> Area | None:
        """The non-detection area at the ego pose ``map_T_base`` (None: not checked, or the map
        needs a pose that TF does not have)."""
        nd = self.cfg.Conditions.NonDetection
        if nd is not None and (self.lanelets is None or map_T_base is not None):
            return _area(nd, self.lanelets, map_T_base)
        return None

    def locate(self, name: str, stamp_ns: int, frame_id: str, points: np.ndarray
               ) -> tuple[np.ndarray | None, np.ndarray, str | None]:
        """The ego pose (map -> base_link) and the cloud in base_link at ``stamp_ns``.
        A failed lookup is the frame's error, never an identity: the cloud then stays as given."""
        tf, error, map_T_base = self.tf, None, None
        if tf is not None:
            try:
                map_T_base = tf.lookup("map", "base_link", stamp_ns)
            except TransformError as exc:
                error = f"frame {name} (stamp {stamp_ns / 1e9:.6f}): map -> base_link: {exc}"
        if frame_id not in ("base_link", "") and error is None:
            try:
                if tf is None:
                    raise TransformError(f"cloud is in {frame_id!r} and the dataset has no TF to move it to base_link")
                x, y, z = xyz_columns(points)
                points = tf.transform_points(np.stack([x, y, z], axis=1).astype(np.float64), "base_link", frame_id,
                                             stamp_ns)
            except TransformError as exc:
                error = f"frame {name} (stamp {stamp_ns / 1e9:.6f}): {frame_id} -> base_link: {exc}"
        return map_T_base, points, error

    def judge(self, name: str, stamp_ns: int, gt: GroundTruth, points: np.ndarray, targets, map_T_base, error
              ) -> FrameVerdict:
        """One frame's verdicts; ``gt`` and ``points`` in base_link, ``targets`` the UUIDs judged (None: all)."""
        det, nd = self.cfg.Conditions.detection, self.cfg.Conditions.NonDetection
        params = self.cfg.SensingEvaluationConfig.evaluation_config_dict
        area = self.area(map_T_base)
        if nd is not None and area is None and error is None:
            error = (f"frame {name} (stamp {stamp_ns / 1e9:.6f}): the map's lanelets need map -> base_link, "
                     "and TF has none")
        boxes = BoxSet.from_ground_truth(gt.centers, gt.sizes, gt.yaws, params.box_scale_0m, params.box_scale_100m)
        counts = evaluate_cloud(points, boxes, area if error is None else None)
        target = np.ones(len(gt), bool) if targets is None else np.isin(gt.instance_tokens, list(targets))
        status = np.where(np.isin(gt.visibility, OCCLUDED), "Warn",
                          np.where(counts.counts >= params.min_points_threshold, "Success", "Fail"))
        topic_rate = self.topic_ok(stamp_ns)
        rate_ok = topic_rate is not False  # unknown (no diagnostics) does not fail a frame
        det_verdict = nd_verdict = None
        if det is not None:
            st = status[target]
            det_verdict = ("Warn" if (st == "Warn").any() else "Success"
                           if error is None and rate_ok and len(st) and (st == "Success").all() else "Fail")
        if nd is not None:
            nd_verdict = "Success" if error is None and rate_ok and len(counts.area_points) == 0 else "Fail"
        return FrameVerdict(name, stamp_ns, gt, boxes, counts, status, target, det_verdict, nd_verdict, topic_rate,
                            area, map_T_base, error)


def evaluate_obstacle_segmentation(dataset, pointclouds: Iterable[tuple], config, *, tf: Any = "auto",
                                   diagnostics: Any = "auto", lanelets: Any = "auto",
                                   on_frame: FrameSink | None = None) -> ObstacleResult:
    """Judge every cloud; ``tf`` / ``diagnostics`` / ``lanelets`` default to the dataset's bag and map.
    ``on_frame(frame, points, result)`` runs after each judged frame (e.g. ``artefacts.ObstacleArtefacts``)."""
    return ObstacleEvaluation.load(dataset, config, tf=tf, diagnostics=diagnostics, lanelets=lanelets).run(
        pointclouds, on_frame)
