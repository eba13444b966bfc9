"""Closed-loop evaluation as a Python API: unroll, then judge per scene.

The ``closed_loop`` use case (YAML scenarios) and Python tests both use these:

    unroll = unroll_scenes(driveeval_dataset, driveeval_model, scenes=[0], steps=100)
    assert_collision_free(unroll, kinds=("front", "side"), at_fault_only=True)
    assert_drift_within(unroll, meters=4.0)
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Callable, Sequence

import numpy as np

from pytest_driveeval.core.errors import DataError
from pytest_driveeval.metrics.drift import distance_to_reference_l5kit
from pytest_driveeval.core.outcome import Finding
from pytest_driveeval.verdict import violations, within

if TYPE_CHECKING:  # the reader imports numcodecs, the engine torch; a dataset arrives already open
    from pytest_driveeval.io.l5.l5kit_zarr import L5Dataset
    from pytest_driveeval.sim.logreplay import ReplayedAgents
    from pytest_driveeval.sim.logreplay.reactive import ReactiveAgents
    from pytest_driveeval.strategies import StartPerturbation

KINDS = ("front", "side", "rear")
KIND_CODE = {"front": 1, "side": 2, "rear": 3}


@dataclass
class Unroll:
    """An unroll with what is needed to judge and draw it."""

    result: Any          # sim.logreplay.UnrollResult
    log: Any             # sim.logreplay.LogArrays: the agents where they were (the log, or the reactive agents' moves)
    drift_threshold: float | None
    step_time: float
    #: scene id -> the score's map (metrics.nuplan_score.ScoreMap) of the scenes whose dataset has one:
    #: anything with ``get(scene)`` (usecases.closed_loop.score.SceneMaps makes them when asked)
    maps: Any = field(default_factory=dict)
    #: row -> the score's ego states (metrics.nuplan_score.EgoStates), made for every row when first scored
    ego_states: Any = field(default=None, repr=False)
    #: scene index -> which scene in the data (usecases.closed_loop.names.scene_identity), for messages
    identities: dict = field(default_factory=dict)

    @property
    def scene_ids(self) -> list[int]:
        return [int(s) for s in self.result.scene_ids]

    def scene_name(self, scene: int) -> str:
        """``scene N (its scenario id and file, or its zarr)`` as messages name it."""
        from pytest_driveeval.usecases.closed_loop.names import named

        return named(int(scene), self.identities.get(int(scene), {}))


def select_scenes(num_scenes: int, scenes: Sequence[int] | None = None, stride: int | None = None
                  ) -> tuple[list[int], list[int]]:
    """(valid scene indices, out-of-range ones).  ``stride``: every Nth, as the seed does."""
    if scenes is None:
        wanted = list(range(0, num_scenes, stride or 1))
    else:
        wanted = list(dict.fromkeys(int(s) for s in scenes))
    return [s for s in wanted if 0 <= s < num_scenes], [s for s in wanted if not 0 <= s < num_scenes]


def starts_past_end(dataset: L5Dataset, ids: Sequence[int], start_frame: int) -> list[tuple[int, int]]:
    """(scene, number of frames) of the scenes in ``ids`` that have no frame ``start_frame``."""
    interval = dataset.scenes["frame_index_interval"]
    lengths = [int(interval[s, 1] - interval[s, 0]) for s in ids]
    return [(s, n) for s, n in zip(ids, lengths) if start_frame >= n]


def unroll_scenes(dataset: L5Dataset, model: Callable, scenes: Sequence[int] | None = None, *,
                  start_frame: int = 0, steps: int | None = None, drift_threshold: float | None = 10.0,
                  freeze_on_collision: bool = True, kinematic: bool = False, history_frames: int = 10,
                  future_frames: int = 12, max_agents: int = 30, agents: ReplayedAgents | None = None,
                  perturbation: StartPerturbation | Sequence[StartPerturbation] | None = None,
                  reactive: ReactiveAgents | None = None, raster: Any = None, semantic_map: Any = None,
                  vector_map: Any = None, progress: Callable[[int, int], None] | None = None) -> Unroll:
    """Unroll ``model`` through the given scenes of an L5 dataset, all in one batch.

    ``agents`` says which logged agents replay (default: all of them);
    ``reactive``: None, they replay the log; else their vehicles brake by IDM
    for what is in their way (sim.logreplay.reactive.ReactiveAgents);
    ``perturbation`` moves every scene's start off the log (one for all, or
    one per scene; see :mod:`pytest_driveeval.strategies`).  ``raster``
    (raster.RasterParams): the policy also gets ``image``, l5kit's raster of
    its driven history; ``py_semantic`` needs ``semantic_map``
    (io.l5_semantic_map.SemanticMap, e.g. from raster_inputs.load_semantic_map); an L5 dataset's scenes
    also score on it (its lanes are the drivable area), and without it the score's map terms are not
    available.  ``vector_map`` (sim.logreplay.map_inputs.MapLimits): the policy also gets l5kit's
    vectorised map keys from ``semantic_map``, the route and the goal (closed_loop.map_inputs).
    ``progress(done, total)``: the steps unrolled, as they go.
    """
    ids, out_of_range = select_scenes(dataset.num_scenes, scenes)
    if out_of_range:
        raise DataError(f"{dataset.path}: scene index {out_of_range[0]} out of range; "
                        f"the dataset has scenes 0..{dataset.num_scenes - 1}")
    for scene, length in starts_past_end(dataset, ids, start_frame):
        raise DataError(f"{dataset.path}: start_frame {start_frame} is past the end of scene {scene} "
                        f"({length} frames, 0..{length - 1})")
    scenes = kept_scenes(dataset, ids, start_frame, agents)
    log = stack_log(dataset, ids, start_frame, agents, scenes=scenes)
    extra = None
    if raster is not None:
        if perturbation is not None:
            raise ValueError("unroll_scenes: raster inputs with a start perturbation are not supported yet")
        from pytest_driveeval.usecases.closed_loop.raster_inputs import raster_inputs

        extra = raster_inputs(raster, log, scenes, semantic_map)
    from pytest_driveeval.usecases.closed_loop.score import SceneMaps

    maps = SceneMaps(dataset, semantic_map)
    if vector_map is not None:
        from pytest_driveeval.usecases.closed_loop.map_inputs import map_inputs, places

        own, place = places(dataset, ids, semantic_map)
        if own[0] is None:
            raise DataError(f"{dataset.path}: map inputs need the dataset's semantic map")
        extra = _both(extra, map_inputs(vector_map, log, scenes, own, place, [maps.get(s) for s in ids]))
    config = unroll_config(start_frame=start_frame, steps=steps, drift_threshold=drift_threshold,
                           freeze_on_collision=freeze_on_collision, kinematic=kinematic,
                           history_frames=history_frames, future_frames=future_frames, max_agents=max_agents,
                           reactive=reactive)
    if perturbation is not None and not isinstance(perturbation, Sequence):
        perturbation = [perturbation] * len(ids)
    unrolled = unroll_log(log, model, config, perturbation, extra_inputs=extra, progress=progress, dataset=dataset,
                          maps=maps)
    from pytest_driveeval.usecases.closed_loop.names import scene_identity

    unrolled.maps = maps
    unrolled.identities = {s: scene_identity(dataset, s) for s in ids}
    return unrolled


def _both(first: Any, second: Callable) -> Callable:
    """Two ``extra_inputs`` as one (the raster's, the map's, a planner's observations), or ``second`` alone."""
    if first is None:
        return second

    def both(*args: Any) -> dict:
        return {**first(*args), **second(*args)}

    return both


def kept_scenes(dataset: L5Dataset, ids: Sequence[int], start_frame: int, agents: ReplayedAgents | None = None
                ) -> list:
    """The given scenes with only the agents that replay."""
    from pytest_driveeval.sim.logreplay import ReplayedAgents, keep_agents

    agents = agents or ReplayedAgents()
    return [keep_agents(dataset.scene(i), agents, start_frame) for i in ids]


def stack_log(dataset: L5Dataset, ids: Sequence[int], start_frame: int, agents: ReplayedAgents | None = None, *,
              scenes: Sequence[Any] | None = None):
    """The replayed side of the given scenes, stacked (sim.logreplay.LogArrays); ``scenes``:
    their :func:`kept_scenes` when the caller has them."""
    from pytest_driveeval.sim.logreplay import stack_scenes

    return stack_scenes(scenes if scenes is not None else kept_scenes(dataset, ids, start_frame, agents),
                        scene_ids=ids)


def unroll_config(*, start_frame: int, steps: int | None, drift_threshold: float | None, freeze_on_collision: bool,
                  kinematic: bool, history_frames: int, future_frames: int, max_agents: int,
                  reactive: ReactiveAgents | None = None):
    from pytest_driveeval.sim.logreplay import UnrollConfig

    return UnrollConfig(start_frame=start_frame, num_steps=steps, drift_threshold=drift_threshold,
                        freeze_on_collision=freeze_on_collision, kinematic=kinematic,
                        history_frames=history_frames, future_frames=future_frames, max_agents=max_agents,
                        reactive_agents=reactive)


def unroll_log(log: Any, model: Callable, config: Any,
               perturbations: Sequence[StartPerturbation] | None = None, cells: Any = None,
               candidates: Any = None, extra_inputs: Any = None, progress: Any = None, dataset: Any = None,
               maps: Any = None) -> Unroll:
    """Unroll a stacked log, row ``i`` perturbed by ``perturbations[i]`` when given.

    ``cells``, ``candidates``: the log's packed cells and window columns
    (sim.logreplay), when the caller has them; unused when agents are
    replayed at another speed (the log changes).  A ``model`` with ``initialize`` and ``plan``
    (policies.planner_api) is told each row's map from ``maps`` (a SceneMaps), its route and goal, and
    its traffic lights from ``dataset`` where it has them.
    """
    from pytest_driveeval.sim.logreplay import scale_agent_time, unroll

    start = None
    if perturbations is not None:
        if len(perturbations) != log.ego_xy.shape[0]:
            raise ValueError(f"{len(perturbations)} perturbations for {log.ego_xy.shape[0]} scenes")
        start = np.array([[p.lateral, p.longitudinal, p.heading, p.speed_scale] for p in perturbations])
        scaled = scale_agent_time(log, config.start_frame, np.array([p.agents_speed_scale for p in perturbations]))
        if scaled is not log:
            cells = candidates = None
        log = scaled
    from pytest_driveeval.policies.planner_api import is_planner

    if is_planner(model):
        from pytest_driveeval.usecases.closed_loop.planner_inputs import planner_policy

        model, observations = planner_policy(model, log, config, dataset, maps)
        extra_inputs = _both(extra_inputs, observations)
    result = unroll(log, model, config, start_perturbation=start, cells=cells, candidates=candidates,
                    extra_inputs=extra_inputs, progress=progress)
    # Drawn and judged where the agents were: the log, or where reactive agents went.
    return Unroll(result, result.agents, config.drift_threshold, config.step_time)


@dataclass
class SceneVerdict:
    scene: int
    passed: bool
    figures: dict[str, float | int]
    findings: list[Finding] = field(default_factory=list)
    #: nuPlan's score terms as the reports show them (usecases.closed_loop.score.terms_json), and
    #: where the GIF marks the failed ones
    score_terms: dict = field(default_factory=dict)
    markers: list = field(default_factory=list)
    #: the ego as driven (driven_json): what an outside scorer (benchmarks/nuplan_oracle) rescores
    driven: dict = field(default_factory=dict)
    #: which scene in the data (usecases.closed_loop.names.scene_identity), filled in where the
    #: dataset is open: the item's process names every verdict, however it was unrolled
    identity: dict = field(default_factory=dict)


def collision_events(unroll: Unroll, row: int, kinds: Sequence[str] = KINDS, at_fault_only: bool = False
                     ) -> list[dict]:
    """One entry per frame with a collision of the given kinds in scene ``row``."""
    r = unroll.result
    codes = [KIND_CODE[k] for k in kinds]
    hit = r.valid[row] & np.isin(r.collision_kind[row], codes)
    if at_fault_only:
        hit &= r.collision_at_fault[row]
    names = {v: k for k, v in KIND_CODE.items()}
    return [{"frame": int(t), "kind": names[int(r.collision_kind[row, t])],
             "track_id": int(r.collision_track_id[row, t]), "at_fault": bool(r.collision_at_fault[row, t])}
            for t in np.flatnonzero(hit)]


#: said where a condition counts an agent on several frames: the score's collision term counts it once
COUNTED_BY_FRAME = ("; every frame in contact counts here, by the engine's blame (the score's "
                    "no_ego_at_fault_collisions counts each agent once, by nuPlan's rules)")


def collision_detail(event: dict) -> str:
    """Who the ego hit, as failures say it: " with agent N", and whether it was not the ego's fault."""
    return f" with agent {event['track_id']}" + ("" if event["at_fault"] else " (not at fault)")


def reference_distance(unroll: Unroll, row: int, measure: str = "polyline") -> np.ndarray:
    """(T,) distance of scene ``row``'s ego to its logged trajectory, NaN where
    not measured: ``polyline`` to the logged path on every unrolled frame,
    ``l5kit`` as l5kit's DistanceToRefTrajectoryMetric (see
    :func:`~pytest_driveeval.metrics.drift.distance_to_reference_l5kit`)."""
    r = unroll.result
    if measure == "polyline":
        return r.distance_to_reference[row]
    if measure == "l5kit":
        return distance_to_reference_l5kit(r.driven_xy[row], r.logged_xy[row], r.valid[row])
    raise ValueError(f"measure must be 'polyline' or 'l5kit', not {measure!r}")


def scene_figures(unroll: Unroll, row: int, reference: str = "polyline", *,
                  distances: np.ndarray | None = None) -> dict[str, float | int]:
    """The figures of scene ``row``; ``reference``: the measure of the distance to it
    (``distances``: that measure's :func:`reference_distance`, when the caller has it)."""
    r = unroll.result
    valid = r.valid[row]
    kinds = r.collision_kind[row][valid]
    at_fault = r.collision_at_fault[row][valid]
    disp = r.displacement_error[row][valid]
    ref = (reference_distance(unroll, row, reference) if distances is None else distances)[valid]
    ref = ref[~np.isnan(ref)]
    figures: dict[str, float | int] = {f: int((kinds == KIND_CODE[f]).sum()) for f in KINDS}
    figures["at_fault"] = int((at_fault & (kinds > 0)).sum())
    figures["drift_resets"] = int(r.reset[row][valid].sum()) if unroll.drift_threshold is not None else 0
    figures["steps"] = int(valid.sum())
    figures["max_displacement"] = float(np.nanmax(disp)) if disp.size else 0.0
    figures["mean_displacement"] = float(np.nanmean(disp)) if disp.size else 0.0
    figures["max_distance_to_reference"] = float(ref.max()) if ref.size else 0.0
    figures["mean_distance_to_reference"] = float(ref.mean()) if ref.size else 0.0
    return figures


def judge_scene(unroll: Unroll, row: int, conditions: Any, *, score: bool = True) -> SceneVerdict:
    """Per-scene verdict against ``ClosedLoopConditions`` (see usecases.closed_loop.config);
    ``score=False`` leaves nuPlan's score out (a search's example, whose conditions do not ask for it)."""
    r = unroll.result
    scene = int(r.scene_ids[row])
    to_reference = conditions.DistanceToReference
    measure = to_reference.Measure if to_reference is not None else "polyline"
    distances = reference_distance(unroll, row, measure)  # l5kit's measure costs a search per frame: once
    figures = scene_figures(unroll, row, measure, distances=distances)
    findings: list[Finding | None] = []  # a rule that holds adds None
    if r.errors[row]:  # the engine's messages already name the scene(s) and frame
        findings.append(Finding(r.errors[row], scene=scene))
    limits = conditions.Collisions
    for kind in KINDS:
        events = collision_events(unroll, row, (kind,), limits.AtFaultOnly)
        detail = collision_detail(events[0]) if events else ""
        if len(events) > len({e["track_id"] for e in events}):
            detail += COUNTED_BY_FRAME
        blame = "at-fault " if limits.AtFaultOnly else ""
        findings.append(violations([e["frame"] for e in events], getattr(limits, kind.capitalize()),
                                   what=f"{blame}{kind} collision frame(s)", figure=kind, scene=scene,
                                   keypath=("Evaluation", "Conditions", "Collisions", kind.capitalize()),
                                   first_detail=detail))
    for key, values, unit in (("Displacement", r.displacement_error[row], " m"),
                              ("DistanceToReference", None, " m"),
                              ("SpeedDifference", r.speed_difference[row], " m/s")):
        limit = getattr(conditions, key)
        if limit is None:
            continue
        measured = r.valid[row]
        if values is None:  # l5kit's measure leaves the last 20 % of the frames out (NaN)
            values = distances
            measured = measured & ~np.isnan(values)
        frames = np.flatnonzero(measured)
        findings.append(within(np.abs(values[frames]), figure=key, max=limit.Max, frames=frames, unit=unit,
                               scene=scene, keypath=("Evaluation", "Conditions", key),
                               tolerated_frames=int(round(limit.Duration / unroll.step_time))))
    if conditions.MaxResets is not None:
        findings.append(violations(np.flatnonzero(r.reset[row]), conditions.MaxResets, what="reset(s) on drift",
                                   figure="drift_resets", scene=scene, keypath=("Evaluation", "Conditions", "MaxResets")))
    from pytest_driveeval.usecases.closed_loop.score import markers, scene_score, score_findings, terms_json

    rules = conditions.Score.Blame if conditions.Score is not None else "nuplan"
    score = scene_score(unroll, row, rules) if score else None
    terms, marks = {}, []
    if score is not None:
        frame_numbers = np.flatnonzero(r.valid[row])
        figures.update(score.figures_of_terms())
        findings.extend(score_findings(score, conditions.Score, scene, frame_numbers))
        terms, marks = terms_json(score, frame_numbers), markers(score, frame_numbers)
    found = [f for f in findings if f is not None]
    return SceneVerdict(scene, not found, figures, found, terms, marks, driven_json(unroll, row))


def driven_json(unroll: Unroll, row: int) -> dict:
    """Scene ``row``'s ego as driven, for closed_loop.json: the unrolled frames (the log's numbers),
    their times (s, frame x step, as the score takes them), the ego box's centre pose per frame
    (x, y, heading: the engine's pose, in the log's world frame) and the box's length and width.
    Enough to score the drive again from the scene's own file, without this package."""
    from pytest_driveeval.sim.logreplay import EGO_EXTENT

    r = unroll.result
    frames = np.flatnonzero(r.valid[row])
    xy, yaw = r.driven_xy[row][frames], r.driven_yaw[row][frames]
    return {"frames": frames.tolist(), "times": (frames * unroll.step_time).tolist(),
            "center": np.concatenate([xy, yaw[:, None]], axis=1).tolist(),
            "length": float(EGO_EXTENT[0]), "width": float(EGO_EXTENT[1])}
