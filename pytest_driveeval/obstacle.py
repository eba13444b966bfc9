"""Obstacle segmentation as a Python API: stream clouds, judge each frame like driving_log_replayer.

    result = evaluate_obstacle_segmentation(T4Dataset(root), bag_pointclouds(root), config)
    assert_pass_rate(result, detection=99.0, non_detection=99.0)

``config`` is the use case's model (or the same mapping as in a scenario's
``Evaluation``).  Point clouds are any iterable of ``(stamp_ns, frame_id,
points)`` with ``points`` structured (x, y, z, ...) or (N, >=3); clouds not in
base_link are moved there by TF at their stamp.  The frame semantics, and where
we differ from driving_log_replayer, are in ``usecases/obstacle_segmentation.py``.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator

import numpy as np

from .errors import DataError
from .io.t4dataset import T4Dataset
from .geometry.quaternions import matrix_to_quat, quat_wxyz_to_matrix
from .io.tf import TransformError
from .metrics.pointcloud import Area, BoxSet, evaluate_cloud, xyz_columns
from .report import jsonl as rec
from .report.jsonl import JsonlWriter
from .report.pointcloud_plot import plot_frame

OCCLUDED = ("none", "v0-40")  # perception_eval's Visibility.NONE and its nuScenes alias
GT_TOLERANCE_US = 75_000
MAX_LISTED = 5


class UnknownUUIDError(DataError):
    def __init__(self, message: str, uuids: list[str]):
        super().__init__(message)
        self.uuids = uuids


# -- point-cloud sources --------------------------------------------------------------
def bag_pointclouds(dataset: T4Dataset | str | os.PathLike, topic: str) -> Iterator[tuple]:
    """Stream ``topic`` from the dataset's input_bag, one message in memory at a time."""
    from .io.rosbag import Bag

    ds = dataset if isinstance(dataset, T4Dataset) else T4Dataset(dataset)
    if ds.input_bag is None:
        raise DataError(f"{ds.root}: no input_bag/ (with metadata.yaml) to read {topic} from")
    with Bag(ds.input_bag) as bag:
        yield from bag.pointclouds(topic)


def sweep_pointclouds(dataset: T4Dataset | str | os.PathLike) -> Iterator[tuple]:
    """Key-frame lidar sweeps (data/LIDAR_*/*.pcd.bin) moved to base_link by their calibration."""
    ds = dataset if isinstance(dataset, T4Dataset) else T4Dataset(dataset)
    for token in ds.sample_tokens:
        sd = ds.lidar_sample_data(token)
        cs = ds.get("calibrated_sensor", sd["calibrated_sensor_token"], f"sample_data {sd['token']}")
        raw = ds.read_lidar(token)
        rot, trans = quat_wxyz_to_matrix(cs["rotation"]), np.asarray(cs["translation"], dtype=np.float64)
        x, y, z = xyz_columns(raw)
        xyz = np.stack([x, y, z], axis=1).astype(np.float64) @ rot.T + trans
        yield int(sd["timestamp"]) * 1000, "base_link", xyz


def dataset_pointclouds(dataset: T4Dataset, topic: str) -> Iterator[tuple]:
    """The bag's topic when the dataset has an input_bag, else its lidar sweeps."""
    return bag_pointclouds(dataset, topic) if dataset.input_bag is not None else sweep_pointclouds(dataset)


@dataclass
class FilteredPointClouds:
    """A raw-cloud source mapped through a filter under test (raw -> obstacle points)."""

    source: Iterable[tuple]
    filter: Callable[[np.ndarray], np.ndarray]

    def __iter__(self):
        for stamp_ns, frame_id, points in self.source:
            yield stamp_ns, frame_id, np.asarray(self.filter(points))


# -- result ---------------------------------------------------------------------------
@dataclass
class ObstacleResult:
    frame_names: list[str] = field(default_factory=list)
    stamps_ns: list[int] = field(default_factory=list)
    detection: list[str | None] = field(default_factory=list)      # Success / Warn / Fail per frame
    non_detection: list[str | None] = field(default_factory=list)  # Success / Fail per frame
    topic_rate: list[bool | None] = field(default_factory=list)    # None: no diagnostics to tell
    area_points: list[int] = field(default_factory=list)
    errors: list[str | None] = field(default_factory=list)
    objects: list[dict] = field(default_factory=list)  # frame, stamp_ns, uuid, points, status, distance
    skipped: int = 0
    counters: dict = field(default_factory=lambda: rec.new_counters())
    detection_pass_rate: float | None = None       # the condition's PassRate (None: not evaluated)
    non_detection_pass_rate: float | None = None
    summary: str = "NoData"
    plots: list[Path] = field(default_factory=list)
    jsonl: Path | None = None

    @property
    def frames(self) -> int:
        return len(self.frame_names)

    def rate(self, part: str) -> float:
        return rec.rate(self.counters[part])

    @property
    def success(self) -> bool:
        return self.frames > 0 and rec.part_success(self.counters, self.detection_pass_rate,
                                                    self.non_detection_pass_rate)

    def failing_frames(self, part: str) -> list[int]:
        verdicts = self.detection if part == "detection" else self.non_detection
        return [i for i, v in enumerate(verdicts) if v is not None and v != "Success"]


def _config(config: Any):
    from .usecases.obstacle_segmentation_config import ObstacleSegmentationConfig

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


def _diagnostic_lookup(diagnostics, name_part: str):
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
    from .io.lanelet2 import load_lanelet_map
    from .io.rosbag import Bag

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


def evaluate_obstacle_segmentation(dataset, pointclouds: Iterable[tuple], config, *, tf: Any = "auto",
                                   diagnostics: Any = "auto", lanelets: Any = "auto", jsonl: str | Path | None = None,
                                   plots_dir: str | Path | None = None, max_plots: int = 5) -> ObstacleResult:
    """Judge every cloud; ``tf`` / ``diagnostics`` / ``lanelets`` default to the dataset's bag and map."""
    ds = dataset if isinstance(dataset, T4Dataset) else T4Dataset(dataset)
    cfg = _config(config)
    check_uuids(ds, cfg)
    tf, diagnostics, lanelets = _auto_inputs(ds, tf, diagnostics, lanelets)
    det, nd = cfg.Conditions.detection, cfg.Conditions.NonDetection
    params = cfg.SensingEvaluationConfig.evaluation_config_dict
    windows = det.windows() if det is not None else None
    topic_ok = _diagnostic_lookup(diagnostics, cfg.PointCloud.TopicRateDiagnostic)
    index = {t: i for i, t in enumerate(ds.sample_tokens)}
    result = ObstacleResult(detection_pass_rate=det.PassRate if det else None,
                            non_detection_pass_rate=nd.PassRate if nd else None)
    writer = JsonlWriter(jsonl, cfg.condition_record()) if jsonl is not None else None
    result.jsonl = Path(jsonl) if jsonl is not None else None
    try:
        for stamp_ns, frame_id, points in pointclouds:
            stamp_ns = int(stamp_ns)
            gt = ds.ground_truth_at(stamp_ns // 1000, GT_TOLERANCE_US)
            targets = params.target_uuids
            if windows is not None:
                targets = [u for u, (s, e) in windows.items() if s <= stamp_ns / 1e9 <= e]
            if gt is None or (windows is not None and not targets):
                result.skipped += 1  # DLR's FrameSkip: no ground truth within 75 ms / no UUID in its window
                continue
            _frame(result, writer, ds, cfg, gt.to_base_link(), index[gt.sample_token], stamp_ns, frame_id, points,
                   targets, tf, lanelets, topic_ok(stamp_ns), plots_dir, max_plots)
    except DataError as exc:
        exc.partial_result = result
        raise
    finally:
        if writer is not None:
            if result.frames:
                writer.write(rec.final_record(result))
            writer.close()
    return result


def _frame(result, writer, ds, cfg, gt, frame_index, stamp_ns, frame_id, points, targets, tf, lanelets,
           topic_rate, plots_dir, max_plots) -> None:
    det, nd = cfg.Conditions.detection, cfg.Conditions.NonDetection
    params = cfg.SensingEvaluationConfig.evaluation_config_dict
    name = str(frame_index)
    error, map_T_base = None, None
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
    area = None
    if nd is not None and (lanelets is None or map_T_base is not None):
        area = _area(nd, lanelets, map_T_base)
    elif nd is not None and error is None:
        error = f"frame {name} (stamp {stamp_ns / 1e9:.6f}): the map's lanelets need map -> base_link, and TF has none"
    boxes = BoxSet.from_ground_truth(gt.centers, gt.sizes, gt.yaws, params.box_scale_0m, params.box_scale_100m)
    counts = evaluate_cloud(points, boxes, area if error is None else None)
    target = np.ones(len(gt), bool) if targets is None else np.isin(gt.instance_tokens, list(targets))
    status = np.where(np.isin(gt.visibility, OCCLUDED), "Warn",
                      np.where(counts.counts >= params.min_points_threshold, "Success", "Fail"))
    rate_ok = topic_rate is not False  # unknown (no diagnostics) does not fail a frame
    det_verdict = nd_verdict = None
    if det is not None:
        st = status[target]
        det_verdict = ("Warn" if (st == "Warn").any() else "Success"
                       if error is None and rate_ok and len(st) and (st == "Success").all() else "Fail")
        rec.count(result.counters["detection"], det_verdict)
    if nd is not None:
        nd_verdict = "Success" if error is None and rate_ok and len(counts.area_points) == 0 else "Fail"
        rec.count(result.counters["non_detection"], nd_verdict)
    for i in np.flatnonzero(target):
        result.objects.append({"frame": name, "stamp_ns": stamp_ns, "uuid": str(gt.instance_tokens[i]),
                               "points": int(counts.counts[i]), "status": str(status[i]),
                               "distance": float(np.linalg.norm(gt.centers[i]))})
    for key, value in (("frame_names", name), ("stamps_ns", stamp_ns), ("detection", det_verdict),
                       ("non_detection", nd_verdict), ("topic_rate", topic_rate),
                       ("area_points", len(counts.area_points)), ("errors", error)):
        getattr(result, key).append(value)
    result.summary = rec.summary(result.counters, det, nd)
    if writer is not None:
        ego = None if map_T_base is None else (map_T_base[:3, 3], matrix_to_quat(map_T_base[:3, :3]))
        writer.record(result.success, result.summary, stamp_ns / 1e9,
                      rec.frame_record(name, result.skipped, topic_rate, stamp_ns, gt, counts, status, target,
                                       det_verdict, nd_verdict, result, ego, error))
    failed = "Fail" in (det_verdict, nd_verdict)
    if plots_dir is not None and failed and len(result.plots) < max_plots:
        result.plots.append(plot_frame(Path(plots_dir), name, stamp_ns, points, boxes, status, target,
                                           gt.instance_tokens, area, counts.area_points, det_verdict, nd_verdict))


def assert_pass_rate(result: ObstacleResult, detection: float | None = None, non_detection: float | None = None
                     ) -> None:
    """Fail unless each part's pass rate reaches its bound (default: the scenario's PassRate);
    the message names the frames (name, stamp) and UUIDs that did not pass."""
    __tracebackhide__ = True
    problems = []
    if result.frames == 0:
        problems.append(f"no frame was evaluated ({result.skipped} skipped: no ground truth within 75 ms or no "
                        "UUID in its BoundingBoxConfig window)")
    for part, bound in (("detection", detection if detection is not None else result.detection_pass_rate),
                        ("non_detection", non_detection if non_detection is not None
                         else result.non_detection_pass_rate)):
        c = result.counters[part]
        if bound is None or not c["total"] or rec.rate(c) >= bound:
            continue
        bad = result.failing_frames(part)
        listed = "; ".join(rec.describe_frame(result, i, part) for i in bad[:MAX_LISTED])
        more = f"; ... {len(bad) - MAX_LISTED} more" if len(bad) > MAX_LISTED else ""
        problems.append(f"{part} pass rate {rec.rate(c):.2f}% < {bound:g}%: {len(bad)} of {c['total']} frame(s) "
                        f"did not pass: {listed}{more}")
    if problems:
        raise AssertionError("\n".join(problems))
