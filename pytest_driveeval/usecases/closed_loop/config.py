"""The YAML of a ``closed_loop`` scenario (UseCaseFormatVersion 0.1.0).

    Evaluation:
      UseCaseName: closed_loop
      UseCaseFormatVersion: 0.1.0
      Datasets:
        - real_scene: {Path: ../fixtures/l5kit/single_scene.zarr}
      Model: ../fixtures/models/planning_mlp.pt   # or constant_velocity / log_replay
      ConstantVelocity: {FirstStep: logged_next}  # only with Model: constant_velocity
      Unroll:
        Scenes: [0]            # or SceneStride: 10 (every 10th, as the seed does); default all
        StartFrame: 10
        Steps: 100             # default: to the end of the scene
        DriftThreshold: 10.0   # reset the ego to the log when it drifts further (seed rule)
        FreezeOnCollision: true
        Kinematic: false
        Agents: {Labels: [CAR], LabelThreshold: 0.5, WithinAtStart: 50.0}   # default: every agent replays
        # Agents: reactive     # or {Mode: reactive, TimeHeadway: 1.5, ...}: vehicles brake by IDM (AgentsSpec)
        Inputs: {Kind: raster, MapType: py_semantic, RasterSize: [112, 112], PixelSize: [0.5, 0.5]}   # default vector
      Conditions:
        Collisions: {Front: 0, Side: 0, Rear: 0, AtFaultOnly: true}
        Displacement: {Max: 4.0, Duration: 0.5}   # metres; seconds above tolerated
        DistanceToReference: {Max: 2.0, Measure: polyline}   # or l5kit
        MaxResets: 0
        ScenePassRate: 100.0   # % of unrolled scenes that must pass
        Score: {AtLeast: 0.8, Terms: {drivable_area_compliance: 1}}   # nuPlan's closed-loop score, per scene
                               # (MeanAtLeast: over the scenes); every scene's score is reported regardless
      Artefacts: {Animations: all}   # all | failing | none
      Perturbation:            # optional: search for the smallest start perturbation that fails a scene
        Lateral: [-3.0, 3.0]   # m, in the ego's frame at the start; each range holds its no-change value
        Longitudinal: [-2.0, 2.0]
        Heading: [-0.2, 0.2]   # rad
        SpeedScale: [0.8, 1.2] # the ego's past speeds (so its initial speed) scaled
        AgentsSpeedScale: [0.8, 1.2]   # the other agents replayed faster or slower
        Examples: 200          # Batch, Tolerance, Replay: see pytest_driveeval.search.spec
      Executor: {Kind: ray, Address: auto, ChunkSize: 8}   # optional: scenes in chunks as Ray tasks
                               # (pytest_driveeval.execute; --driveeval-executor replaces each key it
                               # gives); a search's generations go too; default: local, one batch
"""
from __future__ import annotations

from typing import Any, Literal

from pydantic import (Field, NonNegativeFloat, NonNegativeInt, PositiveFloat, PositiveInt,
                      ValidationInfo, field_validator, model_validator)

from pytest_driveeval.execute import ExecutorSpec
from pytest_driveeval.search.spec import StartSearchSpec
from pytest_driveeval.sim.agents import TrafficModel
from pytest_driveeval.core.usecase import ConditionsModel, Section, check_fits


_IDM = TrafficModel()
# The YAML's IDM keys and the TrafficModel fields they set.
IDM_KEYS = {"TimeHeadway": "time_headway", "MinGap": "min_gap", "ComfortAccel": "max_accel",
            "ComfortDecel": "comfort_decel", "MaxBrake": "max_brake", "Delta": "delta"}


class AgentsSpec(Section):
    """Which logged agents replay (and can be hit); see sim.logreplay.selection.
    And how they move: ``Mode: log`` replays them (l5kit's closed loop),
    ``Mode: reactive`` lets vehicles brake by IDM for what is in their way
    (sim.logreplay.reactive); ``Agents: log`` / ``Agents: reactive`` say just
    that.  The IDM keys (reactive only) default to the policy benchmark's
    traffic model; ``Corridor`` (m) is how far sideways from an agent's path
    something is still in its way.

    l5kit's ``disable_new_agents`` set-up is ``{Labels: [CAR], WithinAtStart: 50.0}``
    (its notebook's ``distance_th_close``; the threshold is its 0.5).
    """

    Mode: Literal["log", "reactive"] = Field("log", description=(
        "log: every agent replays its log (l5kit's closed loop); reactive: vehicles brake by IDM for what is in "
        "their way. Agents: log / Agents: reactive say just that"))
    Labels: list[str] | None = Field(None, min_length=1, description=(
        "only agent rows whose probability of one of these labels (e.g. CAR) is above LabelThreshold replay and "
        "can be hit; default: every agent"))
    LabelThreshold: float = Field(0.5, ge=0.0, lt=1.0, description=(
        "the label probability an agent row must exceed (strictly; l5kit's filter_agents_threshold); needs Labels"))
    WithinAtStart: PositiveFloat | None = Field(None, description=(
        "m: only the tracks passing the label test within this distance of the ego at StartFrame replay, in every "
        "frame (l5kit's disable_new_agents with distance_th_close)"))
    TimeHeadway: PositiveFloat = Field(_IDM.time_headway, description="s, IDM's desired time gap (reactive only)")
    MinGap: PositiveFloat = Field(_IDM.min_gap, description="m, IDM's minimum gap (reactive only)")
    ComfortAccel: PositiveFloat = Field(_IDM.max_accel, description=(
        "m/s^2, IDM's comfortable acceleration (reactive only)"))
    ComfortDecel: PositiveFloat = Field(_IDM.comfort_decel, description=(
        "m/s^2, IDM's comfortable deceleration (reactive only)"))
    MaxBrake: PositiveFloat = Field(_IDM.max_brake, description=(
        "m/s^2, the hardest an agent brakes, at least ComfortDecel (reactive only)"))
    Delta: PositiveFloat = Field(_IDM.delta, description="IDM's acceleration exponent (reactive only)")
    Corridor: PositiveFloat = Field(1.75, description=(
        "m: how far sideways from an agent's path something is still in its way (reactive only)"))

    @model_validator(mode="before")
    @classmethod
    def _shorthand(cls, data: Any) -> Any:
        if isinstance(data, str):
            if data not in ("log", "reactive"):
                raise ValueError("expected log, reactive or a mapping")
            return {"Mode": data}
        return data

    @model_validator(mode="after")
    def _idm_needs_reactive(self):
        given = [k for k in (*IDM_KEYS, "Corridor") if k in self.model_fields_set]
        if given and self.Mode != "reactive":
            raise ValueError(f"{', '.join(given)} applies to Mode: reactive; give Mode: reactive too")
        if self.MaxBrake < self.ComfortDecel:
            raise ValueError(f"MaxBrake ({self.MaxBrake:g}) must be >= ComfortDecel ({self.ComfortDecel:g})")
        return self

    def reactive(self):
        """The engine's ReactiveAgents for ``Mode: reactive``, None for ``log``."""
        if self.Mode != "reactive":
            return None
        from pytest_driveeval.sim.logreplay.reactive import ReactiveAgents

        idm = TrafficModel(**{field: getattr(self, key) for key, field in IDM_KEYS.items()})
        return ReactiveAgents(idm=idm, corridor=self.Corridor)

    @field_validator("Labels")
    @classmethod
    def _known_labels(cls, labels):
        from pytest_driveeval.io.l5.l5kit_zarr import label_index

        for name in labels or ():
            label_index(name)  # ValueError listing the known labels
        return labels

    @model_validator(mode="after")
    def _threshold_needs_labels(self):
        if "LabelThreshold" in self.model_fields_set and self.Labels is None:
            raise ValueError("LabelThreshold applies to Labels; give Labels too")
        return self


def replayed_agents(spec: AgentsSpec):
    """The engine's ReplayedAgents from the YAML's ``Unroll.Agents``."""
    from pytest_driveeval.sim.logreplay import ReplayedAgents

    return ReplayedAgents(labels=spec.Labels, label_threshold=spec.LabelThreshold, within_at_start=spec.WithinAtStart)


class MapSpec(Section):
    """``Inputs.Map``: l5kit 1.5's vectorised map keys in the batch (``lanes``, ``lanes_mid``, ``crosswalks``,
    each with its availabilities, in the agent frame), plus ``lanes_mid_on_route``, ``goal_position`` and
    ``goal_yaw``; the limits are l5kit's ``lane_params``, with its Urban Driver values."""

    MaxLanes: PositiveInt = Field(30, description=(
        "lanes given, nearest first (l5kit's max_num_lanes): lanes_mid holds this many, lanes twice as many"))
    MaxPointsPerLane: int = Field(20, ge=2, description=(
        "points each boundary and centre line is resampled to, equally spaced (l5kit's max_points_per_lane)"))
    MaxCrosswalks: PositiveInt = Field(20, description="crosswalks given, in map order (l5kit's max_num_crosswalks)")
    MaxPointsPerCrosswalk: PositiveInt = Field(20, description=(
        "a crosswalk's first points given, as the map lists them (l5kit's max_points_per_crosswalk)"))
    MaxDistance: PositiveFloat = Field(35.0, description=(
        "m: lanes and crosswalks within this of the ego (by their boxes) are candidates, and lane points "
        "farther than this are not available (l5kit's max_retrieval_distance_m)"))

    def limits(self):
        from pytest_driveeval.sim.logreplay.map_inputs import MapLimits

        return MapLimits(max_lanes=self.MaxLanes, max_points_per_lane=self.MaxPointsPerLane,
                         max_crosswalks=self.MaxCrosswalks, max_points_per_crosswalk=self.MaxPointsPerCrosswalk,
                         max_distance=self.MaxDistance)


class InputsSpec(Section):
    """What the policy is given each step.  ``Kind: vector`` (the default): the
    l5kit-keyed agent and ego histories (sim.logreplay.inputs).  ``Kind:
    raster``: those plus ``image``, l5kit's bird's-eye raster drawn from the
    ego's driven history (pytest_driveeval.raster): ``MapType`` ``box_debug``
    (agent and ego boxes, one channel per history frame) or ``py_semantic``
    (those plus lanes coloured by traffic-light state and crosswalks, from
    ``SemanticMap``/``Meta``, by default ``semantic_map.pb`` and ``meta.json``
    beside the dataset).  The raster's history is ``Unroll.HistoryFrames``.
    ``Inputs: vector`` / ``Inputs: raster`` say just the kind.  ``Map`` (either kind) adds l5kit's
    vectorised map keys, the route and the goal (:class:`MapSpec`), from the same map files.
    """

    Kind: Literal["vector", "raster"] = Field("vector", description=(
        "vector: l5kit's agent and ego histories in the agent frame; raster: those plus image, l5kit's bird's-eye "
        "raster. Inputs: vector / Inputs: raster say just that"))
    MapType: Literal["box_debug", "py_semantic"] = Field("py_semantic", description=(
        "box_debug: the agents' and the ego's boxes, one channel per history frame; py_semantic: those plus lanes "
        "coloured by traffic-light state and crosswalks"))
    RasterSize: tuple[PositiveInt, PositiveInt] = Field((224, 224), description=(
        "[height, width] of the raster in pixels"))
    PixelSize: tuple[PositiveFloat, PositiveFloat] = Field((0.5, 0.5), description=(
        "[x, y] metres per pixel (square pixels)"))
    EgoCenter: tuple[float, float] = Field((0.25, 0.5), description=(
        "where the ego sits in the raster, as fractions of its width and height (l5kit's ego_center)"))
    FilterAgentsThreshold: float = Field(0.5, ge=0.0, lt=1.0, description=(
        "agents drawn are those whose label probability exceeds this (l5kit's filter_agents_threshold)"))
    SemanticMap: str | None = Field(None, description=(
        "the L5 semantic_map.pb (py_semantic rasters, Map), relative to the scenario file; default: beside the "
        "dataset"))
    Meta: str | None = Field(None, description=(
        "the L5 meta.json with the map's world-to-ECEF transform; default: beside the dataset"))
    Map: MapSpec | None = Field(None, description=(
        "l5kit's vectorised map keys (lanes, lanes_mid, crosswalks), the route and the goal in the batch; "
        "{} for l5kit's limits. An L5 dataset reads SemanticMap/Meta, a ScenarioNet scene its own map"))

    @model_validator(mode="before")
    @classmethod
    def _shorthand(cls, data: Any) -> Any:
        if isinstance(data, str):
            if data not in ("vector", "raster"):
                raise ValueError("expected vector, raster or a mapping")
            return {"Kind": data}
        return data

    @model_validator(mode="after")
    def _raster_keys_need_raster(self):
        given = sorted(self.model_fields_set - {"Kind", "Map", *(("SemanticMap", "Meta") if self.Map else ())})
        if given and self.Kind != "raster":
            raise ValueError(f"{', '.join(given)} applies to Kind: raster; give Kind: raster too")
        if self.Kind == "raster" and self.MapType != "py_semantic" and not self.Map \
                and {"SemanticMap", "Meta"} & self.model_fields_set:
            raise ValueError("SemanticMap and Meta apply to MapType: py_semantic or to Map")
        self.raster_params(1)  # the rasterizer's own checks (e.g. square pixels), at this line of the YAML
        return self

    def raster_params(self, history_frames: int):
        """The rasterizer's parameters, or None for vector inputs."""
        if self.Kind != "raster":
            return None
        from pytest_driveeval.raster import RasterParams

        return RasterParams(map_type=self.MapType, raster_size=self.RasterSize, pixel_size=self.PixelSize,
                            ego_center=self.EgoCenter, history_num_frames=history_frames,
                            filter_agents_threshold=self.FilterAgentsThreshold)


class UnrollSpec(Section):
    Scenes: list[NonNegativeInt] | None = Field(None, description=(
        "indices of the dataset's scenes to unroll; default: every scene"))
    SceneStride: PositiveInt | None = Field(None, description=(
        "unroll every N-th scene (as the seed does) instead of listing Scenes"))
    StartFrame: NonNegativeInt = Field(0, description=(
        "the frame each scene's unroll starts at; the policy sees the logged history before it"))
    Steps: PositiveInt | None = Field(None, description="steps to unroll; default: to the end of the scene")
    DriftThreshold: NonNegativeFloat | None = Field(10.0, description=(
        "m: when the next pose the policy asks for is farther than this from the logged one, the ego is put back "
        "on the log for that frame (counted as drift_resets); null: never"))
    FreezeOnCollision: bool = Field(True, description=(
        "true: in a frame where the ego overlaps an agent, the ego holds its pose for the next frame"))
    Kinematic: bool = Field(False, description=(
        "true: the ego moves as a unicycle within its limits instead of onto the pose the policy asks for"))
    HistoryFrames: PositiveInt = Field(10, description="past frames the policy is given (and the raster draws)")
    FutureFrames: PositiveInt = Field(12, description=(
        "future frames of the logged target the policy is given (target_positions, for reference)"))
    MaxAgents: PositiveInt = Field(30, description="the nearest surrounding agents the policy is given per step")
    Agents: AgentsSpec = Field(default_factory=AgentsSpec, description=(
        "which logged agents replay and how they move: log (default), reactive, or a mapping"))
    Inputs: InputsSpec = Field(default_factory=InputsSpec, description=(
        "what the policy is given each step: vector (default), raster, or a mapping"))

    def unroll_options(self) -> dict:
        """The keyword arguments of evaluate.unroll_scenes / unroll_config these keys set."""
        return dict(start_frame=self.StartFrame, steps=self.Steps, drift_threshold=self.DriftThreshold,
                    freeze_on_collision=self.FreezeOnCollision, kinematic=self.Kinematic,
                    history_frames=self.HistoryFrames, future_frames=self.FutureFrames, max_agents=self.MaxAgents,
                    reactive=self.Agents.reactive(), raster=self.Inputs.raster_params(self.HistoryFrames),
                    vector_map=self.Inputs.Map.limits() if self.Inputs.Map is not None else None)

    @model_validator(mode="after")
    def _one_selection(self):
        if self.Scenes is not None and self.SceneStride is not None:
            raise ValueError("give Scenes or SceneStride, not both")
        return self

    @model_validator(mode="after")
    def _inputs_fit_in_memory(self):
        # Each step builds every scene's inputs at once (sim.logreplay.inputs.build_batch): per history
        # frame of each agent its pose, extent and availability with their float64 working copies
        # (~128 bytes), and per frame of the ego's history and future ~128 bytes likewise.  One scene's
        # share, before the first step allocates it in one call no time limit can interrupt.
        frames, future, agents = self.HistoryFrames + 1, self.FutureFrames, self.MaxAgents
        needed = 128.0 * (frames + future) + 128.0 * agents * frames
        defaults = {key: type(self).model_fields[key].default for key in ("HistoryFrames", "FutureFrames", "MaxAgents")}
        key = max(defaults, key=lambda k: getattr(self, k) / defaults[k])  # the one furthest above its default
        check_fits(key, getattr(self, key), needed,
                   f"one scene's policy inputs per step ({self.HistoryFrames} history frames of {agents} agents, "
                   f"{future} future frames)")
        return self

    @model_validator(mode="after")
    def _raster_fits_in_memory(self):
        inputs = self.Inputs
        if inputs.Kind == "raster":
            height, width = inputs.RasterSize
            channels = inputs.raster_params(self.HistoryFrames).num_channels
            # float32, and the canvas it is drawn into besides the image the policy gets
            check_fits(("Inputs", "RasterSize"), list(inputs.RasterSize), 8.0 * height * width * channels,
                       f"one scene's {height} x {width} raster of {channels} channels")
        return self


class CollisionLimits(Section):
    Front: NonNegativeInt = Field(0, description="front collisions allowed per scene")
    Side: NonNegativeInt = Field(0, description="side collisions allowed per scene")
    Rear: NonNegativeInt = Field(0, description="rear collisions allowed per scene")
    AtFaultOnly: bool = Field(False, description="true: count only the collisions that are the ego's fault")


class RangeLimit(Section):
    """A per-frame figure must stay <= Max; up to Duration seconds above it are tolerated."""

    Max: NonNegativeFloat = Field(description="the bound the per-frame figure must stay at or below")
    Duration: NonNegativeFloat = Field(0.0, description="seconds above Max that are tolerated")


class ReferenceLimit(RangeLimit):
    """``Measure``: ``polyline``, the distance to the nearest point of the logged
    path; or ``l5kit``, l5kit's DistanceToRefTrajectoryMetric: the distance to
    the nearest logged position, on the first 80 % of the unrolled frames only.
    The scene figures report the same measure."""

    Measure: Literal["polyline", "l5kit"] = Field("polyline", description=(
        "polyline: distance to the nearest point of the logged path, every frame; l5kit: l5kit's "
        "DistanceToRefTrajectoryMetric, to the nearest logged position on the first 80 % of the frames"))


class ScoreConditions(Section):
    """nuPlan's closed-loop score (metrics.nuplan_score): ``AtLeast`` for each scene's score,
    ``MeanAtLeast`` for the item's (the mean over its scenes, nuPlan's final score), ``Terms`` a lower
    bound per term by nuPlan's metric name, e.g. ``{drivable_area_compliance: 1}``.  A term bounded
    here that a scene cannot compute (no map, no speed limit) fails that scene, saying why."""

    AtLeast: float | None = Field(None, ge=0.0, le=1.0, description=(
        "the lowest nuPlan closed-loop score each scene may have"))
    MeanAtLeast: float | None = Field(None, ge=0.0, le=1.0, description=(
        "the lowest mean score over the item's scenes (nuPlan's final score)"))
    Terms: dict[str, float] | None = Field(None, description=(
        "a lower bound per score term, by nuPlan's metric name, e.g. {drivable_area_compliance: 1}; a bounded "
        "term a scene cannot compute fails that scene"))
    Blame: Literal["nuplan", "engine"] = Field("nuplan", description=(
        "whose rules find and blame the collisions the score counts: nuplan (nuplan-devkit's collision types, "
        "each agent once) or engine (the engine's own collisions and blame, as the Collisions condition counts)"))

    @field_validator("Terms")
    @classmethod
    def _known_terms(cls, terms):
        import difflib

        from pytest_driveeval.metrics.nuplan_score import TERMS

        for name, limit in (terms or {}).items():
            if name not in TERMS:
                close = difflib.get_close_matches(name, TERMS, n=1)
                hint = f"; did you mean {close[0]}?" if close else f"; the terms: {', '.join(TERMS)}"
                raise ValueError(f"unknown score term {name!r}{hint}")
            if not 0.0 <= limit <= 1.0:
                raise ValueError(f"{name}: a term lies in [0, 1], not {limit:g}")
        return terms


class ClosedLoopConditions(Section):
    Collisions: CollisionLimits = Field(default_factory=CollisionLimits, description=(
        "collisions allowed per scene, by kind"))
    Displacement: RangeLimit | None = Field(None, description=(
        "the ego's distance from its logged position: Max (m) and Duration (s tolerated above it)"))
    DistanceToReference: ReferenceLimit | None = Field(None, description=(
        "the ego's distance to the logged path: Max (m), Duration (s) and Measure"))
    SpeedDifference: RangeLimit | None = Field(None, description=(
        "the ego's speed against the logged speed: Max (m/s) and Duration (s)"))
    MaxResets: NonNegativeInt | None = Field(None, description="drift resets allowed per scene")
    ScenePassRate: float = Field(100.0, ge=0.0, le=100.0, description=(
        "% of the unrolled scenes that must pass for the item to pass"))
    Score: ScoreConditions | None = Field(None, description=(
        "nuPlan's closed-loop score per scene and its mean; every scene's score is reported regardless"))


class ArtefactSpec(Section):
    Animations: Literal["all", "failing", "none"] = Field("failing", description=(
        "bird's-eye GIFs of all scenes, the failing ones, or none"))
    Charts: bool = Field(True, description="true: a bar chart of collision frames by kind and drift resets")


class ConstantVelocitySpec(Section):
    """``FirstStep``: where the constant_velocity baseline goes from a frame
    without a past: ``heading`` (its speed along the heading) or
    ``logged_next`` (to the logged next position, as in l5kit's closed loop)."""

    FirstStep: Literal["heading", "logged_next"] = Field("heading", description=(
        "where the constant_velocity baseline goes from a frame without a past: heading (its speed along the "
        "heading) or logged_next (the logged next position, as l5kit)"))


class ClosedLoopPerturbation(StartSearchSpec):
    """What a robustness search may change about a scene's start (strategies.StartPerturbation)."""


class ClosedLoopConfig(ConditionsModel):
    Model: str | None = Field(None, description=(
        "the planning model: a .pt2 (torch.export) or TorchScript file relative to the scenario file, "
        "constant_velocity, log_replay, pdm_closed (the shipped PDM-Closed planner, which reads the map), or "
        "(with --driveeval-allow-scenario-code) weights.pt=pkg.mod:factory, pkg.mod:factory (a model, or a "
        "planner with initialize and plan: docs/bring-your-planner.md) or pickle:file; --driveeval-model or a "
        "driveeval_model fixture replaces it"))
    ConstantVelocity: ConstantVelocitySpec | None = Field(None, description=(
        "options of the constant_velocity baseline (only with Model: constant_velocity)"))
    Unroll: UnrollSpec = Field(default_factory=UnrollSpec, description="which scenes and frames are driven, and how")
    Conditions: ClosedLoopConditions = Field(default_factory=ClosedLoopConditions, description=(
        "what each scene must meet to pass"))
    Artefacts: ArtefactSpec = Field(default_factory=ArtefactSpec, description="the pictures each item leaves")
    Perturbation: ClosedLoopPerturbation | None = Field(None, description=(
        "a robustness search for the smallest start perturbation that fails a scene, instead of one evaluation"))
    Executor: ExecutorSpec | None = Field(None, description=(
        "run the scenes in chunks, here or as Ray tasks; --driveeval-executor replaces each key it gives; "
        "default: local, one batch"))

    @field_validator("ConstantVelocity")
    @classmethod
    def _only_for_constant_velocity(cls, spec, info: ValidationInfo):
        model = info.data.get("Model")
        if spec is not None and model not in (None, "constant_velocity"):
            raise ValueError(f"applies to Model: constant_velocity, not {model!r}")
        return spec

    @field_validator("Perturbation")
    @classmethod
    def _search_needs_vector_inputs(cls, spec, info: ValidationInfo):
        unroll = info.data.get("Unroll")
        if spec is not None and unroll is not None and unroll.Inputs.Kind == "raster":
            raise ValueError("a robustness search with Inputs: raster is not supported yet (its generations "
                             "unroll copies of the scenes, which the rasterizer does not follow)")
        if spec is not None and unroll is not None and unroll.Inputs.Map is not None:
            raise ValueError("a robustness search with Inputs.Map is not supported yet (its generations unroll "
                             "copies of the scenes without the map)")
        return spec
