"""What the obstacle_segmentation judgement says: one :class:`FrameVerdict` per frame,
gathered in an :class:`ObstacleResult` (per-frame lists and the two pass rates).

Verdict strings are driving_log_replayer's ("Success", "Warn", "Fail"), so that
its parsers and eyes read ours.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ...io.t4.t4dataset import GroundTruth
from ...metrics.pointcloud import Area, BoxSet, CloudCounts
from ...verdict import MAX_FRAMES_LISTED, PassRate

PARTS = ("detection", "non_detection")


@dataclass(frozen=True, eq=False)
class FrameVerdict:
    """One judged frame: what the result counts, and what a sink writes or plots."""

    name: str                    # the sample's index in the dataset, as driving_log_replayer names frames
    stamp_ns: int                # the cloud's header stamp
    gt: GroundTruth              # in base_link
    boxes: BoxSet                # the ground-truth boxes as scaled for the count
    counts: CloudCounts
    status: np.ndarray           # per box: Success / Warn / Fail
    target: np.ndarray           # per box: whether Detection judges it
    detection: str | None        # None: the scenario has no Detection condition
    non_detection: str | None    # None: no NonDetection condition
    topic_rate: bool | None      # None: no diagnostics status to tell
    area: Area | None            # the non-detection area (None: not checked)
    map_T_base: np.ndarray | None  # the ego pose, when TF has it at the stamp
    error: str | None            # why the frame could not be evaluated (both parts then fail)

    @property
    def failed(self) -> bool:
        return "Fail" in (self.detection, self.non_detection)


def _new_counters() -> dict[str, PassRate]:
    return {part: PassRate() for part in PARTS}


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
    counters: dict[str, PassRate] = field(default_factory=_new_counters)  # by part: "detection", "non_detection"
    detection_pass_rate: float | None = None       # the condition's PassRate (None: not evaluated)
    non_detection_pass_rate: float | None = None

    @property
    def frames(self) -> int:
        return len(self.frame_names)

    def required(self, part: str) -> float | None:
        """The scenario's PassRate of ``part`` (None: the part is not evaluated)."""
        return self.detection_pass_rate if part == "detection" else self.non_detection_pass_rate

    def rate(self, part: str) -> float:
        return self.counters[part].rate

    @property
    def success(self) -> bool:
        return self.frames > 0 and all(self.counters[part].meets(self.required(part)) for part in PARTS)

    @property
    def summary(self) -> str:
        """driving_log_replayer's Summary of the frames so far ("NoData" before the first)."""
        if not self.frames:
            return "NoData"
        parts = []
        for title, part in (("Detection", "detection"), ("NonDetection", "non_detection")):
            required = self.required(part)
            if required is None:
                parts.append("Invalid")
                continue
            c = self.counters[part]
            text = f"{title} ({'Success' if c.meets(required) else 'Fail'}): {c.passed} / {c.total} -> {c.rate:.2f}%"
            parts.append(text + (f" (Warn: {c.warned})" if part == "detection" else ""))
        ok = all(p == "Invalid" or "(Success)" in p for p in parts)
        return f"{'Passed' if ok else 'Failed'}: {', '.join(parts)}"

    def add(self, frame: FrameVerdict) -> None:
        for part, verdict in zip(PARTS, (frame.detection, frame.non_detection)):
            if verdict is not None:
                self.counters[part].add(verdict)
        gt, counts = frame.gt, frame.counts
        for i in np.flatnonzero(frame.target):
            self.objects.append({"frame": frame.name, "stamp_ns": frame.stamp_ns, "uuid": str(gt.instance_tokens[i]),
                                 "points": int(counts.counts[i]), "status": str(frame.status[i]),
                                 "distance": float(np.linalg.norm(gt.centers[i]))})
        self.frame_names.append(frame.name)
        self.stamps_ns.append(frame.stamp_ns)
        self.detection.append(frame.detection)
        self.non_detection.append(frame.non_detection)
        self.topic_rate.append(frame.topic_rate)
        self.area_points.append(len(counts.area_points))
        self.errors.append(frame.error)

    def failing_frames(self, part: str) -> list[int]:
        verdicts = self.detection if part == "detection" else self.non_detection
        return [i for i, v in enumerate(verdicts) if v is not None and v != "Success"]

    def failing_texts(self, part: str, limit: int = MAX_FRAMES_LISTED) -> tuple[list[str], int]:
        """How the first ``limit`` frames that did not pass ``part`` failed, and how many did not pass.
        Only the listed few are described: describing one scans every object."""
        bad = self.failing_frames(part)
        return [self.describe(i, part) for i in bad[:limit]], len(bad)

    def describe(self, i: int, part: str) -> str:
        """Frame ``i``'s verdict on ``part`` and why: errors, topic rate, the UUIDs or area points at fault."""
        name, stamp = self.frame_names[i], self.stamps_ns[i] / 1e9
        verdict = (self.detection if part == "detection" else self.non_detection)[i]
        why = []
        if self.errors[i]:
            why.append(self.errors[i])
        if self.topic_rate[i] is False:
            why.append("topic rate in ERROR")
        if part == "detection":
            why += [f"UUID {o['uuid']} {o['status']} ({o['points']} point(s))"
                    for o in self.objects if o["frame"] == name and o["stamp_ns"] == self.stamps_ns[i]
                    and o["status"] != "Success"]
        elif self.area_points[i]:
            why.append(f"{self.area_points[i]} point(s) in the non-detection area")
        return f"frame {name} @ {stamp:.6f}s {verdict}" + (f" ({', '.join(why)})" if why else "")
