"""driving_log_replayer's result.jsonl: one JSON object per line.

Line 1 is ``{"Condition": ...}``, line 2 the ``NoData`` header, then one
record per evaluated frame ``{"Result": {"Success", "Summary"}, "Stamp":
{"System", "ROS"}, "Frame": {...}}``, and a final record.  Their analysis
tools read exactly this, so we write the same lines.

Stamps are the cloud's header stamp in seconds for both ``System`` and
``ROS``: a replay without ROS has no wall clock worth recording, and results
must be identical run to run.
"""
from __future__ import annotations

import json
import math
from collections.abc import Iterable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ...core.atomic import atomic_path
from ...geometry.quaternions import matrix_to_quat, matrix_to_rpy, quat_to_matrix
from .result import FrameVerdict, ObstacleResult

if TYPE_CHECKING:
    from typing_extensions import Self  # typing.Self needs Python 3.11

__all__ = ["JsonlWriter", "key_structure", "read_jsonl"]


def _clean(value: Any) -> Any:
    # simplejson's ignore_nan (what driving_log_replayer uses) writes NaN as null.
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _clean(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_clean(v) for v in value]
    if hasattr(value, "item") and not hasattr(value, "__len__"):
        return _clean(value.item())
    return value


class JsonlWriter:
    """Appends records as they come, so a long evaluation never holds them all."""

    def __init__(self, path: str | Path, condition: dict, first_stamp: float = 0.0):
        self.path = Path(path)
        # Written under a temporary name and renamed when closed: a reader
        # never takes a file still being written (or cut by a kill) for a result.
        self._atomic = atomic_path(self.path)
        self._file = self._atomic.__enter__().open("w", encoding="utf-8")
        self.write({"Condition": condition})
        self.write({"Result": {"Success": False, "Summary": "NoData"}, "Stamp": {"System": first_stamp}, "Frame": {}})

    def write(self, record: dict) -> None:
        self._file.write(json.dumps(_clean(record), allow_nan=False) + "\n")

    def record(self, success: bool, summary: str, stamp_s: float, frame: dict) -> None:
        self.write({"Result": {"Success": bool(success), "Summary": summary},
                    "Stamp": {"System": stamp_s, "ROS": stamp_s}, "Frame": frame})

    def close(self) -> None:
        if not self._file.closed:
            self._file.close()
            self._atomic.__exit__(None, None, None)

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def read_jsonl(path: str | Path) -> list[dict]:
    """Records of a result.jsonl, or of driving_log_replayer's result.json (a JSON list of them)."""
    text = Path(path).read_text(encoding="utf-8")
    stripped = text.lstrip()
    if stripped.startswith("["):
        return json.loads(stripped)
    return [json.loads(line) for line in text.splitlines() if line.strip()]


def key_structure(value: Any, depth: int = 6) -> Any:
    """Keys (recursively) without values: what a reader of the file relies on.
    Dict keys that are data (UUIDs, distance bins, indices) collapse to '*'."""
    if depth == 0:
        return "..."
    if isinstance(value, dict):
        keys = list(value)
        if keys and all(_is_data_key(k) for k in keys):
            return {"*": key_structure(value[keys[0]], depth - 1)}
        return {k: key_structure(v, depth - 1) for k, v in value.items()}
    if isinstance(value, list):
        return [key_structure(value[0], depth - 1)] if value and isinstance(value[0], (dict, list)) else []
    return None


def _is_data_key(key: str) -> bool:
    k = str(key)
    return k.isdigit() or (len(k) == 32 and all(c in "0123456789abcdef" for c in k)) or "-" in k and k.replace(
        "-", "").isdigit()


def merge_structures(structures: Iterable[Any]) -> Any:
    """Union of key structures (dicts merged key-wise)."""
    out: Any = None
    for s in structures:
        if isinstance(s, dict):
            out = out if isinstance(out, dict) else {}
            for k, v in s.items():
                out[k] = merge_structures([out.get(k), v]) if k in out else v
        elif out is None:
            out = s
    return out


# -- obstacle_segmentation records ------------------------------------------------------
# driving_log_replayer's own strings, so that their parsers and eyes read ours.
def _stamp(stamp_ns: int) -> dict:
    return {"sec": int(stamp_ns // 1_000_000_000), "nanosec": int(stamp_ns % 1_000_000_000)}


def _ego(stamp_ns: int, map_T_base: np.ndarray) -> dict:
    # Euler angles from the quaternion written beside them, so the two fields always agree.
    t, q = map_T_base[:3, 3], matrix_to_quat(map_T_base[:3, :3])
    roll, pitch, yaw = matrix_to_rpy(quat_to_matrix(q))
    return {"TransformStamped": {
        "header": {"stamp": _stamp(stamp_ns), "frame_id": "map"}, "child_frame_id": "base_link",
        "transform": {"translation": dict(zip("xyz", map(float, t))), "rotation": dict(zip("xyzw", map(float, q)))},
        "rotation_euler": {"roll": roll, "pitch": pitch, "yaw": yaw}}}


def _object_info(gt, counts, i: int, stamp_ns: int) -> dict:
    w, l, h = (float(v) for v in gt.sizes[i])
    return {"Annotation": {"Scale": {"x": l, "y": w, "z": h},
                           "Position": {"position": dict(zip("xyz", map(float, gt.centers[i]))),
                                        "orientation": dict(zip("xyzw", map(float, gt.rotations[i][[1, 2, 3, 0]])))},
                           "UUID": str(gt.instance_tokens[i]), "StampFloat": gt.timestamp_us / 1e6},
            "PointCloud": {"NumPoints": int(counts.counts[i]),
                           "Nearest": [] if counts.counts[i] == 0 else [float(v) for v in counts.nearest[i]],
                           "Stamp": _stamp(stamp_ns)}}


def frame_record(frame: FrameVerdict, result: ObstacleResult) -> dict:
    """The ``Frame`` of one judged frame; ``result`` holds the frames so far, this one included."""
    gt, counts, status, stamp_ns = frame.gt, frame.counts, frame.status, frame.stamp_ns
    record: dict = {}
    if frame.map_T_base is not None:
        record["Ego"] = _ego(stamp_ns, frame.map_T_base)
    record.update(FrameName=frame.name, FrameSkip=result.skipped, StopReasons=[],
                  TopicRate="Unknown" if frame.topic_rate is None else str(bool(frame.topic_rate)))
    det_ok = "Success" if result.rate("detection") >= (result.detection_pass_rate or 0) else "Fail"
    nd_ok = "Success" if result.rate("non_detection") >= (result.non_detection_pass_rate or 0) else "Fail"
    if frame.detection is None:
        record["Detection"] = {"Result": {"Total": "Success", "Frame": "Invalid"}, "Info": {}}
    else:
        info: dict = {}
        objects = []
        for i in np.flatnonzero(frame.target):
            key = {"Success": "DetectionSuccess", "Fail": "DetectionFail", "Warn": "DetectionWarn"}[str(status[i])]
            entry = _object_info(gt, counts, i, stamp_ns)
            # DLR keeps one object per kind (the last); the full list follows in Objects.
            info[key] = entry
            objects.append({"Result": str(status[i]), **entry})
        record["Detection"] = {"Result": {"Total": det_ok, "Frame": frame.detection}, "Info": info,
                               "Objects": objects}
    if frame.non_detection is None:
        record["NonDetection"] = {"Result": {"Total": "Success", "Frame": "Invalid"}, "Info": {}}
    else:
        info = {}
        if len(counts.area_points):
            dist = np.linalg.norm(counts.area_points, axis=1)
            bins = np.bincount(np.floor(dist[dist < 100]).astype(np.int64), minlength=100)
            info = {"PointCloud": {"NumPoints": len(dist),
                                   "Distance": {f"{i}-{i + 1}": int(bins[i]) for i in range(100)}}}
        record["NonDetection"] = {"Result": {"Total": nd_ok, "Frame": frame.non_detection}, "Info": info}
    if frame.error is not None:
        record["Error"] = frame.error
    return record


def final_record(result: ObstacleResult) -> dict:
    """DLR rewrites its last line with graph data; ours: points per target box against distance."""
    objs = result.objects
    count_plot = {"x": {str(i): o["distance"] for i, o in enumerate(objs)},
                  "y": {str(i): o["points"] for i, o in enumerate(objs)},
                  "color": {str(i): o["uuid"][:6] for i, o in enumerate(objs)},
                  "legend": {str(i): o["uuid"][:6] for i, o in enumerate(objs)}}
    stamp = result.stamps_ns[-1] / 1e9
    return {"Result": {"Success": bool(result.success), "Summary": result.summary},
            "Stamp": {"System": stamp, "ROS": stamp}, "Frame": {"GraphData": {"PointcloudCount": count_plot}}}
