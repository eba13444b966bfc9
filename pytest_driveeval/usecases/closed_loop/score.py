"""nuPlan's closed-loop score of an unrolled scene (metrics.nuplan_score) from what the engine
recorded, on the scene's map where the dataset has one (ScenarioNet) or is given one (an L5 zarr's
semantic map), and the findings that the
scenario's ``Conditions.Score`` draws from it.

The collisions the score counts are found and blamed by nuPlan's own rules, from the ego's and the
agents' boxes (metrics.nuplan_score.collisions), each agent once; ``blame="engine"`` takes the engine's
instead (metrics.collisions: one partner per frame, l5kit's rule, blamed by its own rules).
"""
from __future__ import annotations

from functools import lru_cache
import weakref
from typing import Any, Sequence

import numpy as np

from pytest_driveeval.metrics.nuplan_score import (AgentCells, SceneScore, ScoreInputs, ScoreMap, ego_from_poses,
                                                   first_collisions, score_scene)
from pytest_driveeval.metrics.nuplan_score.inputs import GROUPS
from pytest_driveeval.core.outcome import Finding
from pytest_driveeval.io.scenarionet.scenarionet_lane_graph import lane_graph

#: l5kit perception labels by the collision group nuPlan gives such an object
_VEHICLES = {"CAR", "VAN", "TRAM", "BUS", "TRUCK", "EMERGENCY_VEHICLE", "OTHER_VEHICLE"}
_VULNERABLE = {"BICYCLE", "MOTORCYCLE", "CYCLIST", "MOTORCYCLIST", "PEDESTRIAN"}


@lru_cache(maxsize=1)
def _label_groups() -> np.ndarray:
    from pytest_driveeval.io.l5.l5kit_zarr import PERCEPTION_LABELS

    names = [label.rsplit("LABEL_", 1)[-1] for label in PERCEPTION_LABELS]
    return np.array([0 if n in _VEHICLES else 1 if n in _VULNERABLE else 2 for n in names], dtype=np.int8)


def score_map_of(source: Any, scenario_map: Any) -> ScoreMap:
    """A ScenarioNet scene's map (io.scenarionet_map.ScenarioMap of its ScenarioNetScene ``source``)
    as the score reads it.  Lanes, connectors, the lane graph and the roadblocks are those the file's
    converter wrote (io.scenarionet.scenarionet_lane_graph: a lane with its own outline is a lane, one
    without a connector; nuScenes' lanes join where their centre lines meet).  The drivable area is the
    map's own (io.scenarionet.scenarionet_drivable: outlines, road edges, driveways, the lanes' own
    surfaces), lanes widened by an assumed width only where the
    map gives no other."""
    semantic = scenario_map.semantic
    ids = [str(i) for i in semantic.lane_ids]
    features = {f.id: f for f in source.map_features}
    limits = np.array([features[i].speed_limit_kmh / 3.6 if features.get(i) is not None
                       and features[i].speed_limit_kmh else np.nan for i in ids])
    unknown = None
    if "nuscenes" in str(source.dataset).lower():
        # ScenarioNet's nuScenes converter writes 100 km/h on every lane it gives a limit, a placeholder
        # ("TODO Add speed limit if needed" in its source): nuScenes maps have no speed limits.
        limits[:] = np.nan
        unknown = "ScenarioNet's nuScenes lanes carry a placeholder 100 km/h, not a speed limit"
    centres = [features[i].polyline[:, :2] if features.get(i) is not None and features[i].polyline is not None
               and len(features[i].polyline) >= 2 else scenario_map.centres[n] for n, i in enumerate(ids)]
    connector, outgoing, roadblock, _ = lane_graph(ids, features, centres)
    surfaces = [scenario_map.surfaces[n] for n in range(len(ids))]
    driveways = [f.polygon[:, :2] for f in source.map_features if f.type == "DRIVEWAY" and f.polygon is not None]
    area = scenario_map.drivable
    extra = {} if area is None else dict(
        drivable_outlines=area.outlines, road_edges=area.road_edges, drivable_reason=area.reason,
        drivable_stand_in=area.stand_in, lane_drivable=None if area.lane_counts.all() else area.lane_counts)
    # a lane whose boundaries lie unequally off its centre line (Waymo's measured widths) keeps that line
    uneven = {n for n, source in enumerate(scenario_map.width_sources) if source == "boundaries"}
    baselines = [scenario_map.centres[n] if n in uneven else (semantic.lanes_left[n] + semantic.lanes_right[n]) / 2
                 for n in range(len(ids))]
    return ScoreMap(lane_ids=ids, polygons=surfaces, baselines=baselines,
                    speed_limits=limits, connector=connector, outgoing=outgoing, roadblock=roadblock,
                    drivable=surfaces + driveways, no_limits_reason=unknown, **extra)


def dataset_score_maps(dataset: Any, ids: Sequence[int]) -> dict[int, ScoreMap | None]:
    """The score's map of each scene that has one (a ScenarioNet dataset's scenes), made afresh.
    A scenario without lanes (no ``map_features``, or none of them a lane) has no map (None): its
    map terms are not available, rather than every frame off a drivable area that is not given."""
    if not hasattr(dataset, "scenario_map"):
        return {}
    made = {int(i): dataset.scenario_map(int(i)) for i in ids}
    return {i: score_map_of(dataset.source(i), m) if len(m.semantic.lane_ids) else None for i, m in made.items()}


class SceneMaps:
    """A dataset's score maps by scene, each made when a scene is first scored and kept with the
    dataset: an unroll that is never scored (a Python test checking collisions only) costs no map,
    and one scored again (a search's replays, a second item on the same dataset) reuses them."""

    _made: "weakref.WeakKeyDictionary[Any, dict[int, ScoreMap]]" = weakref.WeakKeyDictionary()

    def __init__(self, dataset: Any, semantic_map: Any = None):
        self._dataset = dataset if hasattr(dataset, "scenario_map") else None
        # An L5 zarr's scenes score on the semantic map the caller has (made per scene, kept with this object)
        self._semantic = (dataset, semantic_map) if self._dataset is None and semantic_map is not None \
            and len(getattr(semantic_map, "lane_ids", ())) else None
        self._own: dict[int, ScoreMap | None] = {}

    def get(self, scene: int, default: Any = None) -> ScoreMap | None:
        if self._semantic is not None:
            if scene not in self._own:
                from pytest_driveeval.usecases.closed_loop.semantic_score_map import scene_ego_xy, semantic_score_map

                dataset, semantic = self._semantic
                self._own[scene] = semantic_score_map(semantic, scene_ego_xy(dataset, scene))
            return self._own[scene]
        if self._dataset is None:
            return default
        made = self._made.setdefault(self._dataset, {})
        if scene not in made:
            made[scene] = dataset_score_maps(self._dataset, [scene])[scene]
        return made[scene]


def _ego_states(unroll: Any) -> dict[int, Any]:
    """The ego states of every scene of the unroll whose unrolled frames are one run, by row, with their
    comfort signals: made once for all the scenes of a run (first frame, count), a call per run rather
    than per scene, when the unroll is first scored, and kept with it (an object that cannot keep them
    makes them again).  Each scene's numbers are those it gets alone."""
    made = getattr(unroll, "ego_states", None)
    if made is not None:
        return made
    from pytest_driveeval.metrics.nuplan_score.comfort import MIN_FRAMES, signals_of
    from pytest_driveeval.sim.logreplay import EGO_EXTENT

    r = unroll.result
    counts = r.valid.sum(axis=1)
    first = np.argmax(r.valid, axis=1)
    one_run = np.count_nonzero(np.diff(r.valid.astype(np.int8), axis=1, prepend=0) == 1, axis=1) == 1
    made = {}
    for start, n in np.unique(np.stack([first[one_run], counts[one_run]], axis=1), axis=0).tolist():
        rows = np.flatnonzero(one_run & (first == start) & (counts == n))
        times = np.arange(start, start + n) * unroll.step_time  # as score_inputs' frames * step_time
        frames = slice(start, start + n)
        states = ego_from_poses(r.driven_xy[rows, frames], r.driven_yaw[rows, frames], times, EGO_EXTENT[0],
                                EGO_EXTENT[1])
        if n >= MIN_FRAMES:
            states.comfort = signals_of(states, times)
        for name in ("heading_unit", "rear_axle", "speed", "corners"):  # each computed once for all the rows
            getattr(states, name)
        made.update({int(row): states.scene(i) for i, row in enumerate(rows)})
    if hasattr(unroll, "ego_states"):
        unroll.ego_states = made
    return made


def score_inputs(unroll: Any, row: int, score_map: ScoreMap | None, blame: str = "nuplan") -> ScoreInputs | None:
    """Scene ``row`` of an unroll as the score's inputs (None: no frame was unrolled).  ``blame``: whose rules
    find the collisions the score counts (ScoreInputs.blame); the engine's are kept in the inputs either way."""
    from pytest_driveeval.sim.logreplay import EGO_EXTENT

    r, log = unroll.result, unroll.log
    frames = np.flatnonzero(r.valid[row])
    if not len(frames):
        return None
    # The unrolled frames are the first ones (an unroll stops, it does not skip): a slice, whose arrays are
    # views of the unroll's rather than copies; a mask where they are not.
    keep = slice(0, len(frames)) if frames[-1] == len(frames) - 1 else r.valid[row]
    times = frames * unroll.step_time
    ego = _ego_states(unroll).get(row)
    if ego is None:
        ego = ego_from_poses(r.driven_xy[row][keep], r.driven_yaw[row][keep], times, EGO_EXTENT[0], EGO_EXTENT[1])
    expert = np.concatenate([r.logged_xy[row][keep], r.logged_yaw[row][keep][:, None]], axis=1)
    groups = np.take(_label_groups(), log.label[row][keep])  # take: a third of indexing's time on (T, A)
    tokens = log.track_id[row][keep]
    available = log.available[row][keep]
    # The log's own arrays, as views (float32 among them: the score widens what it reads)
    agents = AgentCells(xy=log.agent_xy[row][keep], yaw=log.agent_yaw[row][keep],
                        length=log.agent_extent[row][keep][..., 0], width=log.agent_extent[row][keep][..., 1],
                        velocity=log.agent_velocity[row][keep], available=available, token=tokens,
                        group=groups, static=groups == 2)
    hit = np.flatnonzero(r.collision_kind[row][keep] > 0)
    hit_tokens = r.collision_track_id[row][keep][hit]
    # Each agent's group at its first contact (the only frame first_collisions keeps of it)
    group_of = {}
    firsts, at = np.unique(hit_tokens, return_index=True)
    for token, k in zip(firsts.tolist(), hit[at].tolist()):
        cell = np.flatnonzero(tokens[k] == token)
        group_of[token] = GROUPS[int(groups[k, cell[0]])] if len(cell) else "object"
    collisions = first_collisions(hit, hit_tokens, r.collision_at_fault[row][keep][hit], group_of)
    return ScoreInputs(times, ego, expert, agents, collisions, score_map, frame_numbers=frames, blame=blame)


def scene_score(unroll: Any, row: int, blame: str = "nuplan") -> SceneScore | None:
    """Scene ``row``'s score; None without an unrolled frame, or without the agents' log to judge it by.
    ``blame``: "nuplan" (nuPlan's collision rules) or "engine" (the engine's collisions and blame)."""
    if unroll.log is None:
        return None
    maps = getattr(unroll, "maps", None)
    inputs = score_inputs(unroll, row, maps.get(int(unroll.result.scene_ids[row])) if maps is not None else None,
                          blame)
    return score_scene(inputs) if inputs is not None else None


def score_unroll(unroll: Any) -> dict[int, SceneScore]:
    """Each unrolled scene's score by scene id (scenes without an unrolled frame are left out)."""
    scores = {int(scene): scene_score(unroll, row) for row, scene in enumerate(unroll.result.scene_ids)}
    return {scene: score for scene, score in scores.items() if score is not None}


def _first_frame(score: SceneScore, names: Sequence[str], frame_numbers: np.ndarray) -> int | None:
    frames = [score.terms[n].frames[0] for n in names if score.terms[n].frames]
    return int(frame_numbers[min(frames)]) if frames else None


def describe(score: SceneScore) -> str:
    """What cost the scene its score, term by term."""
    parts = [f"{t.name} {t.used:.3g}" + (f" ({t.message})" if t.message else "") for t in score.failed()]
    return "; ".join(parts) if parts else "every term 1"


def score_findings(score: SceneScore | None, spec: Any, scene: int, frame_numbers: np.ndarray) -> list[Finding]:
    """Findings of scene ``scene`` against ``Conditions.Score`` (usecases.closed_loop.config.ScoreConditions)."""
    if spec is None or score is None:
        return []
    out = []
    where = ("Evaluation", "Conditions", "Score")
    if spec.AtLeast is not None and score.score < spec.AtLeast:
        names = [t.name for t in score.failed()]
        out.append(Finding(f"scene {scene}: nuPlan score {score.score:.3f} < {spec.AtLeast:g}: {describe(score)}",
                           figure="score", value=score.score, limit=spec.AtLeast,
                           frame=_first_frame(score, names, frame_numbers), scene=scene, keypath=(*where, "AtLeast")))
    for name, limit in (spec.Terms or {}).items():
        term = score.terms[name]
        if term.value is None:
            out.append(Finding(f"scene {scene}: {name} not available ({term.reason}); cannot check it is at least "
                               f"{limit:g}", figure=name, limit=limit, scene=scene, keypath=(*where, "Terms", name)))
        elif term.value < limit:
            out.append(Finding(f"scene {scene}: {name} {term.value:.3f} < {limit:g}: {term.message}", figure=name,
                               value=term.value, limit=limit, frame=_first_frame(score, [name], frame_numbers),
                               scene=scene, keypath=(*where, "Terms", name)))
    return out


def terms_json(score: SceneScore, frame_numbers: np.ndarray) -> dict:
    """Each term as the reports show it: value (None: not available), what the score used, why, the
    frames where it failed (the log's numbers, as the findings give them) and its own measures."""
    out = {}
    for name, term in score.terms.items():
        entry = {"value": term.value, "used": term.used}
        if term.reason:
            entry["reason"] = term.reason
        if term.message:
            entry["message"] = term.message
        if term.frames:
            entry["frames"] = [int(frame_numbers[k]) for k in term.frames]
        entry.update({k: v for k, v in term.detail.items() if np.isfinite(v)})
        out[name] = entry
    return out


def markers(score: SceneScore, frame_numbers: np.ndarray) -> list[tuple[int, float, float, str]]:
    """Where the GIF marks a failed term: (frame number, x, y, kind), one per term and failing frame."""
    kinds = {"drivable_area_compliance": "off_drivable_area", "driving_direction_compliance": "wrong_direction",
             "time_to_collision_within_bound": "time_to_collision", "no_ego_at_fault_collisions": "collision"}
    out = []
    for name, kind in kinds.items():
        term = score.terms[name]
        failing = set(term.frames)
        for k, (x, y) in zip(term.frames, term.places):
            if k - 1 not in failing:  # where each run of failing frames starts: one mark per episode
                out.append((int(frame_numbers[k]), float(x), float(y), kind))
    return out
