"""ScenarioNet's scenario files (MetaDrive's "scenario description") as plain arrays.

ScenarioNet converts nuPlan, Waymo Open Motion, nuScenes, Argoverse 2, Lyft L5 and others into one
format: per scenario a pickled dict with ``id``, ``version``, ``length``, ``metadata`` (``sdc_id``,
``ts``, ``sample_rate``, ``dataset``, ``map``), ``tracks`` (per object: ``type``, ``state`` with
``position`` (T, 3), ``heading`` (T,), ``velocity`` (T, 2), ``valid`` (T,), ``length`` / ``width`` /
``height`` (T,) or (T, 1)), ``map_features`` (per id: ``type`` and a ``polyline`` and / or
``polygon``; lanes may carry ``speed_limit_kmh``, ``entry_lanes``, ``exit_lanes``, neighbours) and
``dynamic_map_states`` (traffic lights: per id a ``state`` with ``object_state`` per step, the
``lane`` it controls, its ``stop_point``).  Files are read with :mod:`.safe_pickle` (data only).

Every type ScenarioNet's converters write is read into what it means (:mod:`.scenarionet_types`,
the one table).  A problem names the file, the scenario id and the object or feature id.  What the
datasets really write is read, not refused, and what was not read is listed on the scene
(:attr:`ScenarioNetScene.skipped`, one :class:`Skipped` per feature, track or light, with its id,
type and why; :attr:`ScenarioNetScene.notes` for what was read other than as written):

- a map feature that cannot be drawn (a one-point or zero-length line, an empty or one-point polygon,
  NaN coordinates, a type no converter writes) is skipped; where only one of its polyline and
  polygon is unusable, the feature is kept from the other;
- a speed limit that is not a speed is dropped (the lane is kept, without a limit);
- a track of no type (``None``) is UNSET, and one of a type no converter writes is kept as an
  object of unknown kind (still a box one can hit);
- a light state no converter writes lights no face, as an unknown state does.

What is refused, rather than read into something else:

- an id, type, lane or light state that is not text (an integer id is taken as its digits);
- ``map_features`` / ``dynamic_map_states`` that are not mappings (absent: none; a scenario
  without lanes then has no map, and the score's map terms are not available);
- a ``length`` that is not a whole number, or outside 1 .. :data:`MAX_STEPS` (checked before
  anything per step is made), and ``metadata.ts`` that is not finite and increasing (whether its
  steps suit the closed loop, within a tolerance, is :mod:`.scenarionet_steps`' question);
- a NaN, infinite or negative ``length`` / ``width`` / ``height`` where a track is valid: an agent
  without a size could never be hit.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ...core.errors import DataError, display_path
from .safe_pickle import load_data_pickle
from .scenarionet_features import MapFeature, Skipped, read_feature
from .scenarionet_types import LIGHT_FACES, NO_LIGHT_STATE, TRACK_LABELS, feature_group

__all__ = ["MAX_STEPS", "MapFeature", "ScenarioNetError", "ScenarioNetScene", "Skipped", "TrafficLight", "Tracks",
           "feature_group", "read_scenario", "scenario_files"]

SUMMARY_FILES = ("dataset_summary.pkl", "dataset_mapping.pkl")
#: the most steps a scenario may have: an hour at 10 Hz (ScenarioNet's scenarios last 9 to 20 s);
#: checked before anything per step is made
MAX_STEPS = 36_000


class ScenarioNetError(DataError, ValueError):
    """A scenario file that is not what ScenarioNet writes: names the file, scenario and object."""


@dataclass
class Tracks:
    ids: list[str]
    types: list[str]
    position: np.ndarray  # (N, T, 3) float64
    heading: np.ndarray   # (N, T)
    velocity: np.ndarray  # (N, T, 2)
    valid: np.ndarray     # (N, T) bool
    size: np.ndarray      # (N, T, 3): length, width, height


@dataclass
class TrafficLight:
    id: str
    lane: str | None
    states: list[str]  # per step
    stop_point: np.ndarray | None


@dataclass
class ScenarioNetScene:
    path: Path
    id: str
    dataset: str
    sample_rate: float  # seconds per step
    timestamps: np.ndarray  # (T,)
    sdc: int  # the self-driving car's row in tracks
    tracks: Tracks
    map_features: list[MapFeature]
    lights: list[TrafficLight]
    metadata: dict[str, Any]
    #: what was not read (or only partly), and why: one entry per feature, track or light
    skipped: list[Skipped] = field(default_factory=list)
    #: what was read other than as written, in a sentence each (timestamps' jitter, placeholders)
    notes: list[str] = field(default_factory=list)

    @property
    def steps(self) -> int:
        return int(self.timestamps.shape[0])


def scenario_files(path: str | Path) -> list[Path]:
    """The scenario files of a file or folder (``sd_*.pkl`` and any other pickle but the summaries).
    A ``.pkl`` that is not a regular file (a link to ``/dev/zero``, a FIFO, a broken link) is listed
    too: reading it says what it is, as that scene's error, rather than leaving it out unsaid."""
    path = Path(path)
    if path.is_file() or path.suffix == ".pkl" and path.is_symlink() or path.suffix == ".pkl" and path.exists() \
            and not path.is_dir():
        return [path]
    if not path.is_dir():
        raise ScenarioNetError(f"{display_path(path)}: no ScenarioNet scenario file or folder there")
    files = sorted(p for p in path.rglob("*.pkl") if p.name not in SUMMARY_FILES and not p.is_dir())
    if not files:
        raise ScenarioNetError(f"{display_path(path)}: a folder without scenario files (*.pkl)")
    return files


def _kind(value: Any) -> str:
    if isinstance(value, (list, tuple, dict, set, np.ndarray)):
        return f"a {type(value).__name__} of {len(value)} item(s)"
    return f"{type(value).__name__} {str(value)[:40]!r}"


def _text(value: Any, here: str, key: str) -> str:
    """An id, a type or a state: text as ScenarioNet writes it (an integer id is taken as its digits)."""
    if isinstance(value, (str, np.str_)) or isinstance(value, (int, np.integer)) and not isinstance(value, bool):
        return str(value)
    raise ScenarioNetError(f"{here}: {key} is {_kind(value)}, not text; ScenarioNet writes ids, types and states "
                           "as text")


def _mapping(value: Any, here: str, key: str) -> dict:
    """A mapping of ids (``map_features``, ``dynamic_map_states``); absent: none."""
    if value is None:
        return {}
    if not isinstance(value, dict):
        raise ScenarioNetError(f"{here}: {key} is {_kind(value)}; ScenarioNet gives a mapping of id -> "
                               f"{key.rstrip('s').replace('_', ' ')}")
    return value


def _count(steps: Any, here: str, key: str) -> int:
    if isinstance(steps, bool) or not isinstance(steps, (int, np.integer)):
        raise ScenarioNetError(f"{here}: {key} is {_kind(steps)}, not a whole number of steps")
    if steps > MAX_STEPS:
        raise ScenarioNetError(f"{here}: {key} is {steps} steps, more than the {MAX_STEPS} a scenario may have (an "
                               "hour at 10 Hz): cut the log into scenarios (ScenarioNet's last 9 to 20 s)")
    if steps < 1:
        raise ScenarioNetError(f"{here}: {key} is {steps} steps: a scenario has at least one step")
    return int(steps)


def _times(timestamps: np.ndarray, declared: int | None, here: str) -> int:
    steps = _count(timestamps.shape[0], here, "metadata.ts's length")
    if declared is not None and steps != declared:
        raise ScenarioNetError(f"{here}: metadata.ts has {steps} steps, 'length' says {declared}")
    bad = np.flatnonzero(~np.isfinite(timestamps))
    if bad.size:
        raise ScenarioNetError(f"{here}: metadata.ts is NaN or infinite at step {int(bad[0])}: each step needs its "
                               "time in seconds")
    back = np.flatnonzero(np.diff(timestamps) <= 0)
    if back.size:
        raise ScenarioNetError(f"{here}: metadata.ts does not increase at step {int(back[0]) + 1} "
                               f"({timestamps[back[0]]:g} s, then {timestamps[back[0] + 1]:g} s)")
    return steps


def read_scenario(path: str | Path) -> ScenarioNetScene:
    path = Path(path)
    data = load_data_pickle(path)
    where = display_path(path)
    if not isinstance(data, dict) or not isinstance(data.get("tracks"), dict):
        found = type(data).__name__ if not isinstance(data, dict) else f"'tracks' as {_kind(data.get('tracks'))}"
        raise ScenarioNetError(f"{where}: not a ScenarioNet scenario (a dict with 'tracks' (a mapping of id -> "
                               f"track), 'map_features', 'metadata'); found {found}")
    metadata = data.get("metadata")
    if not isinstance(metadata, dict):
        raise ScenarioNetError(f"{where}: no 'metadata' mapping (found {_kind(metadata)})")
    sid = _text(data.get("id") or metadata.get("scenario_id") or path.stem, where, "id")
    here = f"{where} (scenario {sid})"
    declared = None if data.get("length") is None else _count(data["length"], here, "length")
    timestamps = _array(metadata.get("ts"), here, "metadata.ts", ndim=1)
    steps = _times(timestamps, declared, here)
    rate = metadata.get("sample_rate")
    if rate is None and steps > 1:
        rate = float(np.median(np.diff(timestamps)))
    if isinstance(rate, bool) or not isinstance(rate, (int, float)) or not np.isfinite(rate) or rate <= 0:
        raise ScenarioNetError(f"{here}: metadata.sample_rate {rate!r} is not a positive number of seconds")
    skipped: list[Skipped] = []
    tracks = _tracks(data["tracks"], steps, here, skipped)
    if metadata.get("sdc_id") is None:
        raise ScenarioNetError(f"{here}: no metadata.sdc_id, the self-driving car's track id")
    sdc_id = _text(metadata.get("sdc_id"), here, "metadata.sdc_id")
    if sdc_id not in tracks.ids:
        raise ScenarioNetError(f"{here}: the self-driving car's track (metadata.sdc_id {sdc_id!r}) is not among "
                               f"its {len(tracks.ids)} tracks")
    features = [feature for fid, raw in _mapping(data.get("map_features"), here, "map_features").items()
                for feature in [read_feature(str(fid), raw, skipped)] if feature is not None]
    lights = [_light(str(lid), light, steps, here, skipped)
              for lid, light in _mapping(data.get("dynamic_map_states"), here, "dynamic_map_states").items()]
    dataset = "" if not metadata.get("dataset") else _text(metadata["dataset"], here, "metadata.dataset")
    notes = _placeholder_limits(dataset, features)
    return ScenarioNetScene(path, sid, dataset, float(rate), timestamps, tracks.ids.index(sdc_id), tracks, features,
                            lights, {k: v for k, v in metadata.items() if k not in ("ts", "object_summary")}, skipped,
                            notes)


def _placeholder_limits(dataset: str, features: list[MapFeature]) -> list[str]:
    """ScenarioNet's Argoverse 2 converter writes 85 mph on every lane (``_HIGHWAY_SPEED_LIMIT_MPH``;
    Argoverse 2's maps give none): not a limit, so its lanes are read without one, and said."""
    if dataset != "av2":
        return []
    lanes = [f for f in features if f.group == "lane" and f.speed_limit_kmh is not None]
    for lane in lanes:
        lane.speed_limit_kmh = None
    return [f"speed_limit_kmh of {len(lanes)} lane(s) not read: ScenarioNet's Argoverse 2 converter writes 85 mph on "
            "every lane, a placeholder (Argoverse 2's maps give no limits)"] if lanes else []


def _array(value: Any, here: str, key: str, ndim: int | None = None, width: tuple[int, ...] = ()) -> np.ndarray:
    try:
        array = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ScenarioNetError(f"{here}: {key} is not an array of numbers") from None
    if ndim is not None and array.ndim != ndim or width and (array.ndim < 2 or array.shape[1] not in width):
        raise ScenarioNetError(f"{here}: {key} has shape {array.shape}, expected "
                               f"{'(K, ' + ' or '.join(map(str, width)) + ')' if width else f'{ndim} dimension(s)'}")
    return array


def _track_type(tid: str, value: Any, what: str, skipped: list[Skipped]) -> str:
    """A track's type: None (what a converter leaves on a track it did not type) is UNSET; a type no
    converter writes is kept, and the engine gives it the label of an object of unknown kind."""
    if value is None:
        skipped.append(Skipped(tid, "None", "no type: read as UNSET, an object of unknown kind", "track"))
        return "UNSET"
    kind = _text(value, what, "type")
    if kind not in TRACK_LABELS:
        skipped.append(Skipped(tid, kind, "not a track type ScenarioNet's converters write: read as an object of "
                                          "unknown kind (collided with, not fed to a model as an agent)", "track"))
    return kind


def _tracks(tracks: dict, steps: int, here: str, skipped: list[Skipped]) -> Tracks:
    ids, types, rows = [], [], []
    for tid, track in tracks.items():
        what = f"{here}, track {tid}"
        if not isinstance(track, dict) or not isinstance(track.get("state"), dict):
            raise ScenarioNetError(f"{what}: no 'state' mapping")
        state = track["state"]
        position = _array(state.get("position"), what, "state.position", ndim=2, width=(2, 3))
        if position.shape[1] == 2:
            position = np.concatenate([position, np.zeros((position.shape[0], 1))], axis=1)
        columns = {"position": position,
                   "heading": _array(state.get("heading"), what, "state.heading").reshape(-1),
                   "velocity": _array(state.get("velocity"), what, "state.velocity", ndim=2, width=(2,)),
                   "valid": _array(state.get("valid"), what, "state.valid").reshape(-1)}
        for key in ("length", "width", "height"):
            columns[key] = _array(state.get(key, np.zeros(steps)), what, f"state.{key}").reshape(-1)
        lengths = {key: value.shape[0] for key, value in columns.items()}
        if set(lengths.values()) != {steps}:
            odd = ", ".join(f"{k} {n}" for k, n in lengths.items() if n != steps)
            raise ScenarioNetError(f"{what}: the scenario has {steps} steps, but {odd}")
        valid = columns["valid"] > 0
        moving = np.concatenate([columns["position"], columns["heading"][:, None], columns["velocity"]], axis=1)
        if not np.isfinite(moving[valid]).all():
            raise ScenarioNetError(f"{what}: NaN or infinite position, heading or velocity at a valid step "
                                   f"(first at step {int(np.flatnonzero(~np.isfinite(moving).all(1) & valid)[0])})")
        for key in ("length", "width", "height"):
            # an agent without a size could never be hit: refused, not replayed as a point
            bad = np.flatnonzero(valid & ~(np.isfinite(columns[key]) & (columns[key] >= 0)))
            if bad.size:
                raise ScenarioNetError(f"{what}: state.{key} is {columns[key][bad[0]]:g} at valid step {int(bad[0])}; "
                                       "a size in metres >= 0 is needed where the track is valid")
        ids.append(str(tid))
        types.append(_track_type(str(tid), track.get("type", "UNSET"), what, skipped))
        rows.append(columns)
    if not rows:
        return Tracks([], [], np.zeros((0, steps, 3)), np.zeros((0, steps)), np.zeros((0, steps, 2)),
                      np.zeros((0, steps), bool), np.zeros((0, steps, 3)))
    stack = {key: np.stack([row[key] for row in rows]) for key in rows[0]}
    return Tracks(ids, types, stack["position"], stack["heading"], stack["velocity"], stack["valid"] > 0,
                  np.stack([stack["length"], stack["width"], stack["height"]], axis=-1))


def _light(lid: str, light: Any, steps: int, here: str, skipped: list[Skipped]) -> TrafficLight:
    what = f"{here}, traffic light {lid}"
    if not isinstance(light, dict):
        raise ScenarioNetError(f"{what}: not a mapping")
    state = light.get("state") or {}
    if not isinstance(state, dict):
        raise ScenarioNetError(f"{what}: state is {_kind(state)}; ScenarioNet gives a mapping with 'object_state'")
    raw = state.get("object_state", [])
    if not isinstance(raw, (list, tuple, np.ndarray)) or getattr(raw, "ndim", 1) != 1:
        raise ScenarioNetError(f"{what}: state.object_state is {_kind(raw)}, not one state per step")
    if len(raw) and len(raw) != steps:
        raise ScenarioNetError(f"{what}: {len(raw)} states for {steps} steps")
    # Waymo leaves None where it lists no state for the light at a step: an unknown state
    states = [_text(s, what, f"its state at step {t}") if s is not None else NO_LIGHT_STATE
              for t, s in enumerate(raw)]
    odd = sorted(set(states) - LIGHT_FACES.keys())
    if odd:
        skipped.append(Skipped(lid, "TRAFFIC_LIGHT", f"state(s) {', '.join(odd)[:120]} not among those ScenarioNet's "
                                                     "converters write: read as unknown (no face lit)",
                               "traffic light"))
    stop = light.get("stop_point")
    lane = light.get("lane")
    return TrafficLight(lid, None if lane is None else _text(lane, what, "lane"),
                        states or [NO_LIGHT_STATE] * steps,
                        None if stop is None else _array(stop, what, "stop_point").reshape(-1))
