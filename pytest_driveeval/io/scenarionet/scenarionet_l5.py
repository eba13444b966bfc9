"""ScenarioNet scenes in the l5kit layout the closed-loop engine replays.

Each scenario becomes one L5 scene: a frame per step while the self-driving car's track is valid
(from step 0; a scenario whose car is not valid at step 0 is refused), the car's pose as the frame's
ego pose, and every other track valid at a step as an agent row of that frame (its ScenarioNet type
as the nearest l5kit label, its row number + 1 as its track id).  The engine steps at 0.1 s: a
scenario whose timestamps jitter around 0.1 s within :mod:`.scenarionet_steps`' tolerance is treated
as sampled at 0.1 s (the scene's ``notes`` say how far they jitter), one sampled at another rate or
with a gap is refused with the step that is out and the way to resample it.

:class:`ScenarioNetDataset` has the reading side of ``L5Dataset``'s interface (``num_scenes``,
``scenes``, ``scene(i)``, ``path``), reading each file when its scene is first asked for.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ...core.errors import DataError, display_path
from ...geometry import yaw_as_rotation33
from ..l5.l5kit_zarr import AGENT_DTYPE, FRAME_DTYPE, PERCEPTION_LABELS, SCENE_DTYPE, TL_FACE_DTYPE, L5Scene, label_index
from .scenarionet import ScenarioNetError, ScenarioNetScene, read_scenario, scenario_files
from .scenarionet_map import ScenarioMap, active_faces, merged, scenario_map
from .scenarionet_steps import check_steps
from .scenarionet_types import TRACK_LABELS, UNKNOWN_TRACK_LABEL

STEP_TIME = 0.1
#: ScenarioNet track type -> l5kit perception label (the table is scenarionet_types')
LABELS = TRACK_LABELS


def l5_scene(scene: ScenarioNetScene, index: int = 0) -> L5Scene:
    here = f"{display_path(scene.path)} (scenario {scene.id})"
    jitter = check_steps(scene, STEP_TIME)
    if jitter is not None and jitter not in scene.notes:
        scene.notes.append(jitter)
    tracks, ego = scene.tracks, scene.sdc
    valid = tracks.valid[ego]
    if not valid[0]:
        raise ScenarioNetError(f"{here}, track {tracks.ids[ego]} (the self-driving car): not valid at step 0")
    steps = int(np.argmin(valid)) if not valid.all() else len(valid)  # the first valid run
    others = np.array([i for i in range(len(tracks.ids)) if i != ego], dtype=np.int64)
    live = tracks.valid[others, :steps] if len(others) else np.zeros((0, steps), bool)
    counts = live.sum(axis=0)
    frames = np.zeros(steps, FRAME_DTYPE)
    frames["timestamp"] = np.round((scene.timestamps[:steps] - scene.timestamps[0]) * 1e9).astype(np.int64)
    ends = np.cumsum(counts)
    frames["agent_index_interval"][:, 0] = ends - counts
    frames["agent_index_interval"][:, 1] = ends
    frames["ego_translation"] = tracks.position[ego, :steps]
    frames["ego_rotation"] = yaw_as_rotation33(tracks.heading[ego, :steps])
    step_of, row_of = np.nonzero(live.T)  # frame-major: each frame's agents together, in track order
    rows = others[row_of]
    agents = np.zeros(len(rows), AGENT_DTYPE)
    agents["centroid"] = tracks.position[rows, step_of, :2]
    agents["extent"] = tracks.size[rows, step_of]
    agents["yaw"] = tracks.heading[rows, step_of]
    agents["velocity"] = tracks.velocity[rows, step_of]
    agents["track_id"] = rows + 1
    labels = np.array([label_index(LABELS.get(kind, UNKNOWN_TRACK_LABEL)) for kind in tracks.types], dtype=np.int64)
    agents["label_probabilities"][np.arange(len(rows)), labels[rows]] = 1.0
    faces_per_step = [active_faces(scene, t, index) for t in range(steps)]
    lit = [len(f) for f in faces_per_step]
    ends = np.cumsum(lit)
    frames["traffic_light_faces_index_interval"][:, 0] = ends - lit
    frames["traffic_light_faces_index_interval"][:, 1] = ends
    faces = np.zeros(int(ends[-1]) if steps else 0, TL_FACE_DTYPE)
    faces["face_id"] = [f for step in faces_per_step for f in step]
    faces["traffic_light_id"] = [f.rsplit(":", 1)[0] for step in faces_per_step for f in step]
    faces["traffic_light_face_status"] = (1.0, 0.0, 0.0)  # ACTIVE: only lit faces are listed
    start = int(round(scene.timestamps[0] * 1e9))
    return L5Scene(index=index, host=scene.dataset[:16] or "scenarionet", start_time=start,
                   end_time=start + int(frames["timestamp"][-1]), frames=frames, agents=agents,
                   traffic_light_faces=faces, source=str(scene.path))


class ScenarioNetDataset:
    """A ScenarioNet file or folder as a closed-loop dataset, one scene per scenario file."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self.files = scenario_files(self.path)
        self._scenes: dict[int, L5Scene] = {}
        self._sources: dict[int, ScenarioNetScene] = {}
        self._maps: dict[int, ScenarioMap] = {}

    @classmethod
    def open(cls, path: str | Path) -> "ScenarioNetDataset":
        return cls(path)

    @property
    def num_scenes(self) -> int:
        return len(self.files)

    def __len__(self) -> int:
        return self.num_scenes

    def source(self, index: int) -> ScenarioNetScene:
        """The scenario as read (tracks, map features, lights) behind scene ``index``."""
        if index not in self._sources:
            self._sources[index] = read_scenario(self.files[index])
        return self._sources[index]

    def scene(self, index: int) -> L5Scene:
        n = self.num_scenes
        if isinstance(index, bool) or not -n <= index < n:
            raise ScenarioNetError(f"{self.path}: scene index {index} out of range; valid scene indices: [0, {n - 1}]")
        index %= n
        if index not in self._scenes:
            self._scenes[index] = l5_scene(self.source(index), index)
        return self._scenes[index]

    def problem(self, index: int) -> str | None:
        """Why scene ``index`` cannot be read (its file, scenario and object named), or None: a
        folder's broken scenario fails alone, the others still run."""
        try:
            self.scene(index)
        except DataError as exc:
            return str(exc)
        except (ValueError, TypeError, IndexError, KeyError, AttributeError, OverflowError, RecursionError,
                MemoryError) as exc:
            # a file the checks above did not foresee: still this scene's error, named, not the item's
            return (f"{display_path(self.files[index % self.num_scenes])} could not be read as a ScenarioNet scenario "
                    f"({type(exc).__name__}: {str(exc)[:200]}); if ScenarioNet wrote it, please report it")
        return None

    def read_notes(self, index: int) -> dict[str, list] | None:
        """What reading scene ``index`` did not take as written, for an item's details: ``skipped``
        (one line per feature, track or light: id, type, why; the records themselves are
        ``source(index).skipped``) and ``notes`` (timestamps' jitter, ...); None when nothing was, or
        when the scene cannot be read (its problem says why)."""
        if self.problem(index) is not None:
            return None
        source = self.source(index % self.num_scenes)
        if not source.skipped and not source.notes:
            return None
        return {"skipped": [str(s) for s in source.skipped], "notes": list(source.notes)}

    @property
    def scenes(self) -> np.ndarray:
        """The l5kit scene table (frame intervals as if the scenes were stored one after another);
        a scenario that cannot be read has no frames."""
        table = np.zeros(self.num_scenes, SCENE_DTYPE)
        start = 0
        for i in range(self.num_scenes):
            if self.problem(i) is not None:
                table[i]["frame_index_interval"] = (start, start)
                continue
            scene = self.scene(i)
            table[i] = ((start, start + scene.num_frames), scene.host, scene.start_time, scene.end_time)
            start += scene.num_frames
        return table

    def __iter__(self):
        return (self.scene(i) for i in range(self.num_scenes))

    def semantic_map(self, ids: list[int]) -> Any:
        """The map of scenes ``ids`` as one semantic map, for rasters that draw it.  Their scenarios must
        share a map (``metadata.map``): two cities' coordinates overlap, and one would be drawn under
        the other's roads."""
        places = {str(self.source(i).metadata.get("map", "")) for i in ids}
        if len(places) > 1:
            raise ScenarioNetError(f"{self.path}: the scenes {ids} lie on {len(places)} maps ({', '.join(sorted(places))}); "
                                   "a raster with the map draws one: choose the scenes of one map with Unroll.Scenes")
        return merged([self.scenario_map(i) for i in ids])

    def scenario_map(self, index: int) -> ScenarioMap:
        """Scene ``index``'s map (lanes, lights, drivable surfaces), made once."""
        if index not in self._maps:
            self._maps[index] = scenario_map(self.source(index), index)
        return self._maps[index]


__all__ = ["LABELS", "PERCEPTION_LABELS", "ScenarioNetDataset", "l5_scene"]
