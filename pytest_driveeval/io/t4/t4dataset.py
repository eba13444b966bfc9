"""t4_dataset (TIER IV's nuScenes-derived format) ground truth.

Layout: ``annotation/*.json`` tables linked by tokens (timestamps in
microseconds), ``data/LIDAR_*/*.pcd.bin`` sweeps, optionally ``input_bag/``
(the rosbag the scenario replays) and ``map/lanelet2_map.osm``.

Boxes come out as arrays per sample.  sample_annotation poses are in the
global ("map") frame; :meth:`GroundTruth.to_base_link` uses the ego pose of
the sample's lidar sample_data (nuScenes convention) to express them in the
vehicle frame.  Quaternions in the tables are (w, x, y, z).
"""
from __future__ import annotations

import json
import os
from dataclasses import dataclass, replace
from functools import cached_property
from pathlib import Path

import numpy as np

from ...core.errors import DataError
from ...geometry.quaternions import (
    matrix_to_quat_wxyz,
    quat_wxyz_to_matrix,
    yaw_from_quat_wxyz,
)
from .pcd import PCDError, read_pcd_bin

__all__ = ["GroundTruth", "T4Dataset", "T4DatasetError"]

REQUIRED_TABLES = ("sample", "sample_data", "sample_annotation", "instance", "category",
                   "visibility", "ego_pose", "calibrated_sensor", "sensor", "scene", "log")


class T4DatasetError(DataError, ValueError):
    """Missing/invalid table, a token that points nowhere, or a missing sweep file.

    The message starts with the dataset folder: a session often reads several
    datasets, whose annotation/*.json files all have the same names."""


@dataclass(frozen=True)
class GroundTruth:
    """Annotated boxes of one sample, as parallel arrays (length N)."""

    sample_token: str
    timestamp_us: int
    frame_id: str                 # "map" as stored, "base_link" after to_base_link()
    centers: np.ndarray           # (N, 3)
    sizes: np.ndarray             # (N, 3) width, length, height
    rotations: np.ndarray         # (N, 4) w, x, y, z
    instance_tokens: np.ndarray   # (N,) str; the UUIDs driving_log_replayer scenarios use
    category_names: np.ndarray    # (N,) str
    visibility: np.ndarray        # (N,) str, visibility table "level" (e.g. "v80-100", "full")
    num_lidar_pts: np.ndarray     # (N,) int
    annotation_tokens: np.ndarray  # (N,) str
    ego_pose: np.ndarray          # (4, 4) map <- base_link at the lidar sample_data
    lidar_path: Path | None = None

    def __len__(self) -> int:
        return len(self.annotation_tokens)

    @property
    def yaws(self) -> np.ndarray:
        return yaw_from_quat_wxyz(self.rotations) if len(self) else np.zeros(0)

    def to_base_link(self) -> GroundTruth:
        if self.frame_id == "base_link":
            return self
        inv_r = self.ego_pose[:3, :3].T
        centers = (self.centers - self.ego_pose[:3, 3]) @ inv_r.T
        rot = inv_r @ quat_wxyz_to_matrix(self.rotations) if len(self) else np.zeros((0, 3, 3))
        quats = matrix_to_quat_wxyz(rot) if len(self) else np.zeros((0, 4))
        return replace(self, frame_id="base_link", centers=centers, rotations=quats)


class T4Dataset:
    """Lazy reader of a t4_dataset folder."""

    def __init__(self, root: str | os.PathLike, lidar_channel: str | None = None):
        self.root = Path(root)
        self.annotation_dir = self.root / "annotation"
        if not self.annotation_dir.is_dir():
            raise self.error("no annotation/ folder (not a t4_dataset)")
        missing = [t for t in REQUIRED_TABLES if not (self.annotation_dir / f"{t}.json").is_file()]
        if missing:
            raise self.error(f"annotation/ lacks table(s) {', '.join(t + '.json' for t in missing)}")
        self.lidar_channel = lidar_channel
        self._tables: dict[str, list[dict]] = {}
        self._index: dict[str, dict[str, dict]] = {}

    def error(self, message: str, table: str | None = None) -> T4DatasetError:
        """An error located in this dataset (and in one of its tables)."""
        where = f"t4_dataset {self.root}" + (f": annotation/{table}.json" if table else "")
        return T4DatasetError(f"{where}: {message}")

    # -- tables ------------------------------------------------------------
    def table(self, name: str) -> list[dict]:
        if name not in self._tables:
            path = self.annotation_dir / f"{name}.json"
            if not path.is_file():
                raise self.error("table missing", name)
            try:
                rows = json.loads(path.read_text(encoding="utf-8"))
            except (json.JSONDecodeError, UnicodeDecodeError) as exc:
                raise self.error(f"invalid JSON: {exc}", name) from exc
            if not isinstance(rows, list) or not all(isinstance(r, dict) for r in rows):
                raise self.error("expected a JSON list of records", name)
            self._tables[name] = rows
        return self._tables[name]

    def get(self, name: str, token: str, referrer: str = "") -> dict:
        """Record of table ``name`` with ``token``; error names the table and who referred."""
        if name not in self._index:
            rows = self.table(name)
            try:
                self._index[name] = {r["token"]: r for r in rows}
            except KeyError:
                raise self.error("record without 'token'", name) from None
        rec = self._index[name].get(token)
        if rec is None:
            via = f" (referenced by {referrer})" if referrer else ""
            raise self.error(f"no record with token {token!r}{via}", name)
        return rec

    def _field(self, rec: dict, key: str, table: str):
        try:
            return rec[key]
        except KeyError:
            raise self.error(f"record {rec.get('token')!r} lacks {key!r}", table) from None

    def _vectors(self, anns: list[dict], key: str, n: int) -> np.ndarray:
        """(len(anns), n) float64 of each annotation's ``key``; one of another length, or
        not finite, is an error naming its annotation."""
        out = np.empty((len(anns), n))
        for row, ann in zip(out, anns):
            value = self._field(ann, key, "sample_annotation")
            try:
                row[:] = np.asarray(value, dtype=np.float64)
                ok = bool(np.isfinite(row).all())
            except (TypeError, ValueError):
                ok = False
            if not ok:
                raise self.error(f"record {ann.get('token')!r}: {key} should be {n} finite numbers, "
                                 f"found {value!r}", "sample_annotation")
        return out

    # -- paths -------------------------------------------------------------
    @property
    def input_bag(self) -> Path | None:
        """The input_bag/ folder if there is one, readable or not: one that cannot be read is
        an error when it is opened, never a silent fall-back to other data."""
        bag = self.root / "input_bag"
        return bag if bag.is_dir() else None

    @property
    def lanelet2_map(self) -> Path | None:
        osm = self.root / "map" / "lanelet2_map.osm"
        return osm if osm.is_file() else None

    # -- samples -----------------------------------------------------------
    @cached_property
    def _samples(self) -> tuple[np.ndarray, list[str]]:
        rows = sorted(self.table("sample"), key=lambda r: int(self._field(r, "timestamp", "sample")))
        return (np.array([int(r["timestamp"]) for r in rows], dtype=np.int64),
                [r["token"] for r in rows])

    @property
    def sample_timestamps_us(self) -> np.ndarray:
        return self._samples[0]

    @property
    def sample_tokens(self) -> list[str]:
        return list(self._samples[1])

    def _channel(self, sd: dict) -> tuple[str, str]:
        """(channel, modality) of a sample_data via calibrated_sensor -> sensor."""
        cs = self.get("calibrated_sensor", self._field(sd, "calibrated_sensor_token", "sample_data"),
                      f"sample_data {sd['token']}")
        sensor = self.get("sensor", self._field(cs, "sensor_token", "calibrated_sensor"),
                          f"calibrated_sensor {cs['token']}")
        return sensor.get("channel", ""), sensor.get("modality", "")

    @cached_property
    def _lidar_by_sample(self) -> dict[str, dict]:
        """Key-frame lidar sample_data per sample (preferring the configured channel)."""
        out: dict[str, dict] = {}
        for sd in self.table("sample_data"):
            channel, modality = self._channel(sd)
            if modality != "lidar" or not sd.get("is_key_frame", True):
                continue
            if self.lidar_channel and channel != self.lidar_channel:
                continue
            prev = out.get(sd["sample_token"])
            # LIDAR_CONCAT (t4) / LIDAR_TOP (nuScenes) first: they are what is annotated.
            if prev is None or channel in ("LIDAR_CONCAT", "LIDAR_TOP"):
                out[sd["sample_token"]] = sd
        return out

    def lidar_sample_data(self, sample_token: str) -> dict:
        sd = self._lidar_by_sample.get(sample_token)
        if sd is None:
            raise self.error(f"no key-frame lidar sample_data for sample {sample_token!r}", "sample_data")
        return sd

    def lidar_path(self, sample_token: str) -> Path:
        return self.root / self._field(self.lidar_sample_data(sample_token), "filename", "sample_data")

    def read_lidar(self, sample_token: str) -> np.ndarray:
        """The sample's lidar sweep (.pcd.bin, x y z intensity ring float32), sensor frame."""
        sd = self.lidar_sample_data(sample_token)
        path = self.lidar_path(sample_token)
        which = f"sample {sample_token!r} (sample_data {sd['token']!r}, timestamp {sd.get('timestamp')} us)"
        if not path.is_file():
            raise self.error(f"{which}: lidar sweep {sd['filename']} does not exist")
        try:
            return read_pcd_bin(path)
        except PCDError as exc:  # it names the file by its full path; the dataset is named already
            raise self.error(f"{which}: {str(exc).replace(str(path), sd['filename'], 1)}") from exc

    def lidar_to_base_link(self, sample_token: str) -> tuple[np.ndarray, np.ndarray]:
        """(rotation 3x3, translation 3) of the sample's lidar in base_link, from its calibrated_sensor."""
        sd = self.lidar_sample_data(sample_token)
        cs = self.get("calibrated_sensor", self._field(sd, "calibrated_sensor_token", "sample_data"),
                      f"sample_data {sd['token']}")
        rot = quat_wxyz_to_matrix(self._field(cs, "rotation", "calibrated_sensor"))
        return rot, np.asarray(self._field(cs, "translation", "calibrated_sensor"), dtype=np.float64)

    def ego_pose(self, sample_token: str) -> np.ndarray:
        sd = self.lidar_sample_data(sample_token)
        pose = self.get("ego_pose", self._field(sd, "ego_pose_token", "sample_data"),
                        f"sample_data {sd['token']}")
        m = np.eye(4)
        m[:3, :3] = quat_wxyz_to_matrix(self._field(pose, "rotation", "ego_pose"))
        m[:3, 3] = self._field(pose, "translation", "ego_pose")
        return m

    @cached_property
    def _annotations_by_sample(self) -> dict[str, list[dict]]:
        out: dict[str, list[dict]] = {}
        for ann in self.table("sample_annotation"):
            out.setdefault(self._field(ann, "sample_token", "sample_annotation"), []).append(ann)
        return out

    def _category(self, ann: dict) -> str:
        if ann.get("category_name"):  # denormalised copy (nuScenes devkit exports it)
            return ann["category_name"]
        inst = self.get("instance", ann["instance_token"], f"sample_annotation {ann['token']}")
        cat = self.get("category", self._field(inst, "category_token", "instance"),
                       f"instance {inst['token']}")
        return cat["name"]

    def ground_truth(self, sample_token: str) -> GroundTruth:
        sample = self.get("sample", sample_token)
        anns = self._annotations_by_sample.get(sample_token, [])
        where = "sample_annotation"
        for ann in anns:
            self.get("instance", self._field(ann, "instance_token", where), f"{where} {ann['token']}")
        vis = []
        for ann in anns:
            tok = ann.get("visibility_token", "")
            vis.append(self.get("visibility", tok, f"{where} {ann['token']}").get("level", tok)
                       if tok else "")
        strs = lambda xs: np.array(xs, dtype=object)
        return GroundTruth(
            sample_token=sample_token,
            timestamp_us=int(sample["timestamp"]),
            frame_id="map",
            centers=self._vectors(anns, "translation", 3),
            sizes=self._vectors(anns, "size", 3),
            rotations=self._vectors(anns, "rotation", 4),
            instance_tokens=strs([a["instance_token"] for a in anns]),
            category_names=strs([self._category(a) for a in anns]),
            visibility=strs(vis),
            num_lidar_pts=np.array([int(a.get("num_lidar_pts", -1)) for a in anns], dtype=np.int64),
            annotation_tokens=strs([a["token"] for a in anns]),
            ego_pose=self.ego_pose(sample_token),
            lidar_path=self.lidar_path(sample_token),
        )

    def ground_truth_at(self, stamp_us: int, tolerance_us: int = 75_000) -> GroundTruth | None:
        """Nearest sample's ground truth if within ``tolerance_us`` of ``stamp_us``, else None."""
        ts, tokens = self._samples
        if ts.size == 0:
            return None
        i = int(np.searchsorted(ts, stamp_us))
        cands = [j for j in (i - 1, i) if 0 <= j < ts.size]
        j = min(cands, key=lambda k: abs(int(ts[k]) - int(stamp_us)))
        if abs(int(ts[j]) - int(stamp_us)) > tolerance_us:
            return None
        return self.ground_truth(tokens[j])

    def __iter__(self):
        for token in self._samples[1]:
            yield self.ground_truth(token)

    def __len__(self) -> int:
        return len(self._samples[1])
