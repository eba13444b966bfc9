"""Read and write Lyft Level 5 (l5kit) datasets stored as zarr format 2.

l5kit is no longer installable and zarr 3 cannot read its structured dtypes, so
the arrays are read and written by ``zarr_v2`` (``.zarray`` JSON + one file per
chunk, decoded with ``numcodecs``); this module knows l5kit's schema and scenes.

Layout of a store (a zarr v2 group directory)::

    .zgroup  .zattrs
    scenes/               SCENE_DTYPE, frame_index_interval -> frames
    frames/               FRAME_DTYPE, agent_index_interval -> agents,
                          traffic_light_faces_index_interval -> traffic_light_faces
    agents/               AGENT_DTYPE
    traffic_light_faces/  TL_FACE_DTYPE

All index intervals are half-open ``[start, end)`` into the next array.

Public API::

    ds = L5Dataset.open(path)            # validates metadata, reads nothing else
    ds.num_scenes; ds.attrs
    scene = ds.scene(i)                  # L5Scene, decodes only the chunks it needs
    scene.frames / .agents / .traffic_light_faces   # structured arrays, re-based
    scene.ego_positions(); scene.ego_yaws(); scene.agents_of_frame(t)
    scene.agent_tensor()                 # AgentTensor, dense (T, A, ...) view
    scene.agent_rows()                   # AgentRows, the rows as stored, with their tracks
    ds.read_all()                        # L5Arrays of the four whole arrays
    write_l5_zarr(path, scenes, frames, agents, traffic_light_faces)
"""
from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import numcodecs
import numpy as np

from ...geometry import yaw_from_rotation33
from .zarr_v2 import ZarrArray1D, ZarrFormatError, describe_dtype, dtype_mismatch, write_array, zarr_json

__all__ = [
    "AGENT_DTYPE",
    "ARRAY_NAMES",
    "AgentRows",
    "AgentTensor",
    "EXPECTED_DTYPES",
    "FRAME_DTYPE",
    "L5Arrays",
    "L5Dataset",
    "L5FormatError",
    "L5Scene",
    "PERCEPTION_LABELS",
    "SCENE_DTYPE",
    "TL_FACE_DTYPE",
    "label_index",
    "write_l5_zarr",
]

SCENE_DTYPE = np.dtype(
    [
        ("frame_index_interval", np.int64, (2,)),
        ("host", "<U16"),
        ("start_time", np.int64),
        ("end_time", np.int64),
    ]
)
FRAME_DTYPE = np.dtype(
    [
        ("timestamp", np.int64),
        ("agent_index_interval", np.int64, (2,)),
        ("traffic_light_faces_index_interval", np.int64, (2,)),
        ("ego_translation", np.float64, (3,)),
        ("ego_rotation", np.float64, (3, 3)),
    ]
)
AGENT_DTYPE = np.dtype(
    [
        ("centroid", np.float64, (2,)),
        ("extent", np.float32, (3,)),
        ("yaw", np.float32),
        ("velocity", np.float32, (2,)),
        ("track_id", np.uint64),
        ("label_probabilities", np.float32, (17,)),
    ]
)
TL_FACE_DTYPE = np.dtype(
    [
        ("face_id", "<U16"),
        ("traffic_light_id", "<U16"),
        ("traffic_light_face_status", np.float32, (3,)),
    ]
)

ARRAY_NAMES = ("scenes", "frames", "agents", "traffic_light_faces")
EXPECTED_DTYPES = dict(zip(ARRAY_NAMES, (SCENE_DTYPE, FRAME_DTYPE, AGENT_DTYPE, TL_FACE_DTYPE)))

# Order matters: label_probabilities[:, i] is the probability of PERCEPTION_LABELS[i].
PERCEPTION_LABELS = (
    "PERCEPTION_LABEL_NOT_SET",
    "PERCEPTION_LABEL_UNKNOWN",
    "PERCEPTION_LABEL_DONTCARE",
    "PERCEPTION_LABEL_CAR",
    "PERCEPTION_LABEL_VAN",
    "PERCEPTION_LABEL_TRAM",
    "PERCEPTION_LABEL_BUS",
    "PERCEPTION_LABEL_TRUCK",
    "PERCEPTION_LABEL_EMERGENCY_VEHICLE",
    "PERCEPTION_LABEL_OTHER_VEHICLE",
    "PERCEPTION_LABEL_BICYCLE",
    "PERCEPTION_LABEL_MOTORCYCLE",
    "PERCEPTION_LABEL_CYCLIST",
    "PERCEPTION_LABEL_MOTORCYCLIST",
    "PERCEPTION_LABEL_PEDESTRIAN",
    "PERCEPTION_LABEL_ANIMAL",
    "AVRESEARCH_LABEL_DONTCARE",
)

# l5kit's defaults, also what the real sample uses.
DEFAULT_CHUNK_SIZES = {"scenes": 10_000, "frames": 10_000, "agents": 20_000, "traffic_light_faces": 10_000}


def label_index(name: str) -> int:
    """Column of ``label_probabilities`` for a label, e.g. ``"CAR"`` -> 3."""
    full = name if name.startswith(("PERCEPTION_LABEL_", "AVRESEARCH_")) else f"PERCEPTION_LABEL_{name.upper()}"
    try:
        return PERCEPTION_LABELS.index(full)
    except ValueError:
        raise ValueError(f"unknown perception label {name!r}; known: {', '.join(PERCEPTION_LABELS)}") from None


class L5FormatError(ZarrFormatError):
    """The store does not hold what the l5kit format promises."""


class L5Arrays(NamedTuple):
    scenes: np.ndarray
    frames: np.ndarray
    agents: np.ndarray
    traffic_light_faces: np.ndarray


# --------------------------------------------------------------------------- scenes


class AgentTensor(NamedTuple):
    """Agents of a scene aligned by track id: axis 0 is the frame, axis 1 the track.

    Entries where ``available`` is False hold zeros.
    """

    track_id: np.ndarray  # (A,) uint64, sorted
    centroid: np.ndarray  # (T, A, 2) float64
    yaw: np.ndarray  # (T, A) float32
    extent: np.ndarray  # (T, A, 3) float32
    velocity: np.ndarray  # (T, A, 2) float32
    label: np.ndarray  # (A,) int64, index into PERCEPTION_LABELS, most probable over the track's rows
    available: np.ndarray  # (T, A) bool


class AgentRows(NamedTuple):
    """A scene's agent rows as they are stored (R rows), with their tracks (A)."""

    frame: np.ndarray  # (R,) int64
    rank: np.ndarray  # (R,) int64, the row's position among its frame's rows
    track: np.ndarray  # (R,) int64, index into track_ids
    track_ids: np.ndarray  # (A,) uint64, sorted
    first: np.ndarray  # (A,) int64, each track's first frame
    last: np.ndarray  # (A,) int64, and its last
    label: np.ndarray  # (A,) int64, index into PERCEPTION_LABELS, most probable over the track's rows
    # The row fields are read-only views of the scene's agent rows (strided, not copied).
    centroid: np.ndarray  # (R, 2) float64
    yaw: np.ndarray  # (R,) float32
    extent: np.ndarray  # (R, 3) float32
    velocity: np.ndarray  # (R, 2) float32


def _concat_ranges(starts: np.ndarray, ends: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Row indices of all ``[start, end)`` ranges and the range each row came from."""
    counts = ends - starts
    owner = np.repeat(np.arange(counts.size), counts)
    offsets = np.cumsum(counts) - counts
    rows = np.arange(counts.sum()) - offsets[owner] + starts[owner]
    return rows, owner


class TrackTable(NamedTuple):
    """A scene's tracks, from its rows' track ids (R rows, A distinct ids)."""

    track_ids: np.ndarray  # (A,) the distinct ids, sorted
    track: np.ndarray  # (R,) int64, each row's index into track_ids
    first: np.ndarray  # (A,) int64, each track's first frame
    last: np.ndarray  # (A,) int64, and its last
    label: np.ndarray  # (A,) int64, the most frequent per-row argmax of label_probabilities (first on ties)
    repeated_frame: int  # the earliest frame in which a track id occurs twice, -1 if none


# Ids up to this many times the row count are indexed through a lookup table, not a sort.
# Logged ids are small and dense (a scene's ids run up to about a tenth of its rows).
DENSE_IDS = 8


def track_table(ids: np.ndarray, frame: np.ndarray, probabilities: np.ndarray, num_frames: int) -> TrackTable:
    """The track table of rows with these ids, frames (nondecreasing) and label probabilities."""
    if ids.size and int(ids.max()) < DENSE_IDS * ids.size:
        present = np.zeros(int(ids.max()) + 1, bool)
        present[ids] = True
        track_ids = np.flatnonzero(present).astype(ids.dtype)
        track = (np.cumsum(present) - 1)[ids]
    else:
        track_ids, track = np.unique(ids, return_inverse=True)
        track = track.astype(np.int64)
    num_tracks = track_ids.size
    first = np.full(num_tracks, num_frames, np.int64)
    np.minimum.at(first, track, frame)
    last = np.full(num_tracks, -1, np.int64)
    np.maximum.at(last, track, frame)
    return TrackTable(track_ids, track, first, last, _track_labels(probabilities, track, num_tracks),
                      _repeated_frame(frame, track, num_frames, num_tracks))


def _repeated_frame(frame: np.ndarray, track: np.ndarray, num_frames: int, num_tracks: int) -> int:
    key = frame * num_tracks + track
    if num_frames * num_tracks <= 64 * max(frame.size, 1 << 16):  # a bitmap of (frame, track) pairs
        seen = np.zeros(num_frames * num_tracks, bool)
        seen[key] = True
        if np.count_nonzero(seen) == key.size:
            return -1
    ordered = np.sort(key)
    repeated = ordered[1:][ordered[1:] == ordered[:-1]]
    return int(repeated[0] // num_tracks) if repeated.size else -1


def _track_labels(probabilities: np.ndarray, column: np.ndarray, num_tracks: int) -> np.ndarray:
    # A dense (T, A, 17) copy would dominate agent_tensor's cost and a track's class
    # rarely changes, so keep one label per track: the most frequent per-row argmax.
    num_labels = probabilities.shape[1]
    votes = np.bincount(column * num_labels + probabilities.argmax(axis=1), minlength=num_tracks * num_labels)
    return votes.reshape(num_tracks, num_labels).argmax(axis=1)


def _field(rows: np.ndarray, name: str) -> np.ndarray:
    # A read-only view of the stored rows' field: copying four fields out of 116-byte
    # records cost a tenth of loading a scene, and every reader only reads them.
    view = rows[name]
    view.flags.writeable = False
    return view


def _is_partition(intervals: np.ndarray, length: int) -> bool:
    """True if the intervals tile ``[0, length)`` in order, back to back."""
    if len(intervals) == 0:
        return length == 0
    return bool(intervals[0, 0] == 0 and intervals[-1, 1] == length
                and np.array_equal(intervals[1:, 0], intervals[:-1, 1]) and np.all(intervals[:, 1] >= intervals[:, 0]))


@dataclass(frozen=True)
class L5Scene:
    """One scene with its frames, agents and traffic-light faces.

    Intervals in ``frames`` are re-based: they index ``self.agents`` and
    ``self.traffic_light_faces``.  The ``*_offset`` fields give the row of
    element 0 in the whole store.
    """

    index: int
    host: str
    start_time: int
    end_time: int
    frames: np.ndarray
    agents: np.ndarray
    traffic_light_faces: np.ndarray
    frame_offset: int = 0
    agent_offset: int = 0
    tl_face_offset: int = 0
    source: str = ""

    @property
    def num_frames(self) -> int:
        return len(self.frames)

    def ego_positions(self) -> np.ndarray:
        return self.frames["ego_translation"][:, :2]

    def ego_yaws(self) -> np.ndarray:
        return yaw_from_rotation33(self.frames["ego_rotation"])  # as l5kit's rotation33_as_yaw

    def agents_of_frame(self, t: int) -> np.ndarray:
        if not -self.num_frames <= t < self.num_frames:
            raise IndexError(f"scene {self.index} of {self.source}: frame {t} outside [0, {self.num_frames})")
        start, end = self.frames["agent_index_interval"][t]
        return self.agents[start:end]

    def tl_faces_of_frame(self, t: int) -> np.ndarray:
        if not -self.num_frames <= t < self.num_frames:
            raise IndexError(f"scene {self.index} of {self.source}: frame {t} outside [0, {self.num_frames})")
        start, end = self.frames["traffic_light_faces_index_interval"][t]
        return self.traffic_light_faces[start:end]

    def agent_rows(self, tables=track_table) -> AgentRows:
        """The scene's agent rows, frame by frame in stored order, with each row's
        track (an index into the sorted track ids) and place in its frame.

        ``tables`` computes the :class:`TrackTable` (a compiled equal of :func:`track_table`
        may be passed: the io layer itself stays free of numba)."""
        intervals = self.frames["agent_index_interval"].astype(np.int64)
        counts = intervals[:, 1] - intervals[:, 0]
        if _is_partition(intervals, len(self.agents)):  # the usual layout: no gather copy needed
            agents, frame = self.agents, np.repeat(np.arange(self.num_frames), counts)
        else:
            rows, frame = _concat_ranges(intervals[:, 0], intervals[:, 1])
            agents = self.agents[rows]
        rank = np.arange(frame.size) - np.repeat(np.cumsum(counts) - counts, counts)
        table = tables(agents["track_id"], frame, agents["label_probabilities"], self.num_frames)
        if table.repeated_frame >= 0:
            raise L5FormatError(f"{self.source}: scene {self.index}: a track id occurs twice in one frame "
                                f"(first at frame {table.repeated_frame})")
        return AgentRows(
            frame=frame, rank=rank, track=table.track, track_ids=table.track_ids, first=table.first,
            last=table.last, label=table.label,
            centroid=_field(agents, "centroid"), yaw=_field(agents, "yaw"), extent=_field(agents, "extent"),
            velocity=_field(agents, "velocity"),
        )

    def agent_tensor(self) -> AgentTensor:
        """Dense ``(T, A, ...)`` arrays, one column per distinct track id."""
        rows = self.agent_rows()
        shape = (self.num_frames, rows.track_ids.size)
        available = np.zeros(shape, dtype=bool)
        available[rows.frame, rows.track] = True

        def dense(values: np.ndarray) -> np.ndarray:
            out = np.zeros(shape + values.shape[1:], dtype=values.dtype)
            out[rows.frame, rows.track] = values
            return out

        return AgentTensor(track_id=rows.track_ids, centroid=dense(rows.centroid), yaw=dense(rows.yaw),
                           extent=dense(rows.extent), velocity=dense(rows.velocity), label=rows.label,
                           available=available)


class L5Dataset:
    """A read-only l5kit zarr store; use :meth:`open`."""

    def __init__(self, path: Path, arrays: dict[str, ZarrArray1D], attrs: dict):
        self.path = path
        self._arrays = arrays
        self.attrs = attrs
        self._scenes = arrays["scenes"].read()  # one row per scene: small even for the full dataset

    @classmethod
    def open(cls, path: str | os.PathLike) -> "L5Dataset":
        path = Path(path)
        if not path.is_dir():
            raise L5FormatError(f"{path}: not a zarr directory store")
        if not (path / ".zgroup").is_file():
            raise L5FormatError(f"{path}: missing .zgroup, not a zarr v2 group")
        attrs: dict = {}
        if (path / ".zattrs").is_file():
            try:
                attrs = json.loads((path / ".zattrs").read_text())
            except ValueError as exc:
                raise L5FormatError(f"{path / '.zattrs'}: invalid JSON: {exc}") from exc
        arrays = {name: ZarrArray1D(path, name, EXPECTED_DTYPES[name], error=L5FormatError, every_chunk_written=True)
                  for name in ARRAY_NAMES}
        return cls(path, arrays, attrs)

    def __repr__(self) -> str:
        sizes = ", ".join(f"{n}={a.length}" for n, a in self._arrays.items())
        return f"L5Dataset({str(self.path)!r}, {sizes})"

    @property
    def num_scenes(self) -> int:
        return len(self._scenes)

    @property
    def scenes(self) -> np.ndarray:
        return self._scenes

    def __len__(self) -> int:
        return self.num_scenes

    def array_length(self, name: str) -> int:
        return self._arrays[name].length

    def read_array(self, name: str, start: int = 0, stop: int | None = None) -> np.ndarray:
        if name not in self._arrays:
            raise KeyError(f"{self.path}: no array {name!r}; arrays are {', '.join(ARRAY_NAMES)}")
        return self._arrays[name].read(start, stop)

    def read_all(self) -> L5Arrays:
        return L5Arrays(*(self._arrays[n].read() for n in ARRAY_NAMES))

    def scene(self, index: int) -> L5Scene:
        n = self.num_scenes
        if not -n <= index < n or isinstance(index, bool):
            valid = f"[0, {n - 1}]" if n else "none (the store has no scenes)"
            raise L5FormatError(f"{self.path}: scene index {index} out of range; valid scene indices: {valid}")
        index = index % n
        row = self._scenes[index]
        f0, f1 = (int(v) for v in row["frame_index_interval"])
        self._check_interval(f"scenes[{index}].frame_index_interval", f0, f1, "frames")
        frames = self._arrays["frames"].read(f0, f1)
        a0, a1 = self._span(frames["agent_index_interval"], f"scene {index} frames", "agents")
        t0, t1 = self._span(frames["traffic_light_faces_index_interval"], f"scene {index} frames", "traffic_light_faces")
        agents = self._arrays["agents"].read(a0, a1)
        faces = self._arrays["traffic_light_faces"].read(t0, t1)
        frames["agent_index_interval"] -= a0
        frames["traffic_light_faces_index_interval"] -= t0
        return L5Scene(index=index, host=str(row["host"]), start_time=int(row["start_time"]),
                       end_time=int(row["end_time"]), frames=frames, agents=agents, traffic_light_faces=faces,
                       frame_offset=f0, agent_offset=a0, tl_face_offset=t0, source=str(self.path))

    def __iter__(self):
        return (self.scene(i) for i in range(self.num_scenes))

    def _check_interval(self, what: str, start: int, end: int, target: str) -> None:
        length = self._arrays[target].length
        if not 0 <= start <= end <= length:
            raise L5FormatError(f"{self.path}: {what} = [{start}, {end}) is not inside array {target!r} of length {length}")

    def _span(self, intervals: np.ndarray, what: str, target: str) -> tuple[int, int]:
        if len(intervals) == 0:
            return 0, 0
        bad = np.flatnonzero(intervals[:, 0] > intervals[:, 1])
        if bad.size:
            raise L5FormatError(f"{self.path}: {what}: {target} interval {intervals[bad[0]].tolist()} "
                                f"has start > end")
        start, end = int(intervals[:, 0].min()), int(intervals[:, 1].max())
        self._check_interval(f"{what} {target} intervals", start, end, target)
        return start, end


# --------------------------------------------------------------------------- writer


def _check_for_write(name: str, array: np.ndarray) -> np.ndarray:
    array = np.asarray(array)
    expected = EXPECTED_DTYPES[name]
    diff = dtype_mismatch(expected, array.dtype)
    if diff:
        raise L5FormatError(f"cannot write array {name!r}: wrong dtype ({diff}); expected {describe_dtype(expected)}")
    if array.ndim != 1:
        raise L5FormatError(f"cannot write array {name!r}: 1-D expected, found shape {array.shape}")
    return np.ascontiguousarray(array)


def _check_intervals(owner: str, field: str, intervals: np.ndarray, target: str, target_len: int) -> None:
    if intervals.size == 0:
        return
    bad = np.flatnonzero((intervals[:, 0] < 0) | (intervals[:, 0] > intervals[:, 1]) | (intervals[:, 1] > target_len))
    if bad.size:
        raise L5FormatError(f"cannot write: {owner}[{bad[0]}].{field} = {intervals[bad[0]].tolist()} "
                            f"is not a valid interval of {target!r} (length {target_len})")


def write_l5_zarr(
    path: str | os.PathLike,
    scenes: np.ndarray,
    frames: np.ndarray,
    agents: np.ndarray,
    traffic_light_faces: np.ndarray,
    chunk_sizes: dict[str, int] | None = None,
    attrs: dict | None = None,
    overwrite: bool = False,
) -> Path:
    """Write the four arrays as an l5kit zarr v2 store (blosc/lz4, as l5kit does).

    ``attrs`` is merged into the group ``.zattrs`` (which always gets the
    ``format_version`` and ``labels`` keys l5kit writes).  Intervals are checked
    against the array lengths before anything is written.
    """
    path = Path(path)
    data = {name: _check_for_write(name, arr)
            for name, arr in zip(ARRAY_NAMES, (scenes, frames, agents, traffic_light_faces))}
    _check_intervals("scenes", "frame_index_interval", data["scenes"]["frame_index_interval"], "frames", len(data["frames"]))
    _check_intervals("frames", "agent_index_interval", data["frames"]["agent_index_interval"], "agents", len(data["agents"]))
    _check_intervals("frames", "traffic_light_faces_index_interval",
                     data["frames"]["traffic_light_faces_index_interval"], "traffic_light_faces",
                     len(data["traffic_light_faces"]))
    sizes = {**DEFAULT_CHUNK_SIZES, **(chunk_sizes or {})}
    for name, size in sizes.items():
        if name not in EXPECTED_DTYPES or int(size) < 1:
            raise ValueError(f"chunk_sizes: {name!r}={size!r}; need a positive size for one of {', '.join(ARRAY_NAMES)}")
    occupied = path.is_file() or (path.is_dir() and any(path.iterdir()))
    if occupied and not overwrite:
        raise FileExistsError(f"{path} exists and is not empty; pass overwrite=True to replace the arrays")

    path.mkdir(parents=True, exist_ok=True)
    (path / ".zgroup").write_text(zarr_json({"zarr_format": 2}))
    root_attrs = {"format_version": 2, "labels": list(PERCEPTION_LABELS), **(attrs or {})}
    (path / ".zattrs").write_text(zarr_json(root_attrs))
    codec = numcodecs.Blosc(cname="lz4", clevel=5, shuffle=numcodecs.Blosc.SHUFFLE, blocksize=0)
    for name, array in data.items():
        write_array(path / name, array, int(sizes[name]), codec)
    return path
