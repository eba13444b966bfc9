"""The YAML of a ``policy_benchmark`` scenario (UseCaseFormatVersion 0.1.0).

    Evaluation:
      UseCaseName: policy_benchmark
      UseCaseFormatVersion: 0.1.0
      Blueprint:
        Name: merging                 # highway | merging | intersection
        Params: {gap: [7, 17]}        # the blueprint's own parameters, as in make_blueprint()
        # or a CommonRoad scenario (sim.commonroad_scene), relative to this file:
        # CommonRoad: ../../fixtures/commonroad/ZAM_Tutorial-1_2_T-1.xml
        # PlanningProblem: 100        # default: one item per planning problem of the file
        # Traffic: replay             # the recorded obstacles; reactive: their recorded paths at IDM speed
        # Params: {start_lateral: [-0.3, 0.3]}   # CommonRoadParams: the ego's size, seeded start offsets
      Episodes: 128                   # seeds FirstSeed .. FirstSeed + Episodes - 1
      FirstSeed: 0
      Strata: 8                       # seed groups the bootstrap resamples within
      AgentLimit: 12
      Policies:                       # name: model spec (TorchScript, weights.pt=module:factory) or a baseline
        gnn: ../../fixtures/models/gnn_actor_merging.pt2
        idm: idm_expert               # random | constant | idm_expert
        random: random
      Judged: [gnn]                   # whose items the Conditions decide; default: every non-baseline policy
      Conditions:
        Confidence: 95                # % for every interval below
        GoalRate: {AtLeast: 60}       # % of episodes; decided on the interval's lower bound
        CollisionRate: {AtMost: 10}   # decided on the upper bound
        Beats: [{Baseline: random, Metric: goal_rate}]   # P(this policy > baseline) > 0.5 with confidence
      Artefacts: {Animations: failing, ComparisonPlot: true}
      Perturbation:                   # optional: a robustness search instead of the benchmark
        Lateral: [-1.0, 1.0]          # m, the ego's start in its own frame; each range holds its no-change value
        Longitudinal: [-5.0, 5.0]     # m
        Heading: [-0.1, 0.1]          # rad
        SpeedScale: [0.5, 1.5]        # the ego's initial speed scaled
        AgentsSpeedScale: [0.8, 1.2]  # the traffic's initial and desired speeds scaled
        GapScale: [0.5, 2.0]          # the blueprint's spawn gaps scaled: below 1 denser traffic
        FailOn: [collision, off_road, step_limit]   # episode outcomes that fail an example (default: all)
        Examples: 200                 # Batch, Tolerance, Replay: see pytest_driveeval.search.spec
      Executor: {Kind: ray, Address: auto, ChunkSize: 64}   # optional: episodes in chunks of seeds as
                                      # Ray tasks (pytest_driveeval.execute; --driveeval-executor
                                      # replaces each key it gives); default: local, one batch

One item per policy (and, for a CommonRoad file without PlanningProblem, per
planning problem: ``policy_benchmark[<policy>-problem<id>]``).  A judged
policy's item decides the conditions and runs the baselines it is compared
with on the same seeds; the other items report
their figures and intervals (the table of policies) and pass.  With a
``Perturbation`` section every item instead searches the episodes' seeds and
the perturbations within the ranges for an episode of its policy that ends in
one of ``FailOn``; the Conditions are not judged then.
"""
from __future__ import annotations

import dataclasses
import math

from typing import Any, ClassVar, Literal

from pydantic import Field, NonNegativeInt, PositiveInt, model_validator

from pytest_driveeval.execute import ExecutorSpec
from pytest_driveeval.search.spec import StartSearchSpec
from pytest_driveeval.core.usecase import ConditionsModel, Section, check_fits, located_error

BASELINES = ("random", "constant", "idm_expert")
METRICS = ("goal_rate", "collision_rate", "return")
# The episodes' seeds are one int64 array (numpy's generators take any seed >= 0, the array does not).
SEED_LIMIT = 2 ** 63


def episode_bytes(agents: int) -> float:
    """About the memory one episode takes while the policies step it: the graph observation's
    per-pair edge features and their encoding (~48 bytes a pair of agents), the agents' state
    (~400 bytes each) and the episode's own (~4 KiB); measured with tracemalloc and torch sizes,
    rounded up."""
    return 48.0 * agents * agents + 400.0 * agents + 4096.0


class BlueprintSpec(Section):
    """A blueprint by ``Name``, or a CommonRoad scenario file by ``CommonRoad`` (relative to the
    scenario file, as model paths are) with ``PlanningProblem`` (default: one item per planning
    problem of the file) and ``Traffic`` (``replay``: the recorded obstacles, the default; ``reactive``:
    the recorded cars on their recorded paths at the speed IDM gives them).  ``Params``: the
    blueprint's own parameters, or sim.commonroad_scene.CommonRoadParams for a CommonRoad scene."""

    Name: Literal["highway", "merging", "intersection"] | None = Field(None, description=(
        "a blueprint: highway, merging or intersection; give either Name or CommonRoad"))
    CommonRoad: str | None = Field(None, min_length=1, description=(
        "a CommonRoad scenario file (XML), relative to the scenario file: its lanelets, planning problem and "
        "recorded obstacles"))
    PlanningProblem: int | None = Field(None, description=(
        "the CommonRoad planning problem's id; default: one item per planning problem of the file (CommonRoad "
        "only)"))
    Traffic: Literal["replay", "reactive"] | None = Field(None, description=(
        "replay (default): the recorded obstacles; reactive: the recorded cars on their recorded paths at the "
        "speed IDM gives them (CommonRoad only)"))
    Params: dict[str, Any] = Field(default_factory=dict, description=(
        "the blueprint's own parameters (make_blueprint's), or a CommonRoad scene's (the ego's size, seeded start "
        "offsets): see the tables below"))

    @property
    def label(self) -> str:
        """How summaries name it: the blueprint, or the CommonRoad file's name."""
        if self.CommonRoad is None:
            return str(self.Name)
        return self.CommonRoad.replace("\\", "/").rsplit("/", 1)[-1].removesuffix(".xml")

    @model_validator(mode="after")
    def _params_fit_the_blueprint(self):
        from pytest_driveeval.sim.blueprints import ParameterError, make_blueprint

        if (self.Name is None) == (self.CommonRoad is None):
            raise located_error("Name", self.Name, "give either Name (a blueprint) or CommonRoad (a scenario file)")
        if self.CommonRoad is None:
            for key in ("PlanningProblem", "Traffic"):
                if getattr(self, key) is not None:
                    raise located_error(key, getattr(self, key), "only for a CommonRoad scenario")
        try:
            if self.CommonRoad is None:
                make_blueprint(self.Name, **self.Params)
            else:
                from pytest_driveeval.sim.commonroad_scene import check_params

                check_params(self.Params)
        except ParameterError as exc:
            # Point at the parameter's own line, not at the Blueprint mapping.
            message = str(exc).split(": ", 2)[-1]
            raise located_error(("Params", exc.parameter), self.Params.get(exc.parameter), message) from None
        return self


class RateLimit(Section):
    AtLeast: float | None = Field(None, ge=0.0, le=100.0, description=(
        "% the rate must reach, decided on its interval's lower bound"))
    AtMost: float | None = Field(None, ge=0.0, le=100.0, description=(
        "% the rate may reach at most, decided on its interval's upper bound"))

    @model_validator(mode="after")
    def _one_bound(self):
        if (self.AtLeast is None) == (self.AtMost is None):
            raise ValueError("give AtLeast or AtMost")
        return self


class BeatsSpec(Section):
    Baseline: str = Field(description="the policy (one of Policies, not judged) this one must beat")
    Metric: Literal["goal_rate", "collision_rate", "return"] = Field("goal_rate", description=(
        "the figure compared: goal_rate, collision_rate or return"))
    Rule: Literal["improvement", "difference"] = Field("improvement", description=(
        "improvement: P(this policy better than the baseline) > 0.5 with confidence; difference: the difference "
        "of means (IQMs) excludes 0"))


class BenchmarkConditions(Section):
    Confidence: float = Field(95.0, gt=50.0, lt=100.0, description="% level of every interval of the conditions")
    GoalRate: RateLimit | None = Field(None, description="% of episodes that reach the goal: AtLeast or AtMost")
    CollisionRate: RateLimit | None = Field(None, description=(
        "% of episodes that end in a collision: AtLeast or AtMost"))
    OffRoadRate: RateLimit | None = Field(None, description="% of episodes that leave the road: AtLeast or AtMost")
    Beats: list[BeatsSpec] = Field(default_factory=list, description=(
        "paired comparisons the judged policy must win, on the same seeded episodes"))


class BenchmarkArtefacts(Section):
    Animations: Literal["all", "failing", "none"] = Field("failing", description=(
        "GIFs of all episodes, of one that missed its goal (failing), or none"))
    ComparisonPlot: bool = Field(True, description="true: a plot of the policies' rates with their intervals")


FAILURES = ("collision", "off_road", "step_limit")


class PolicyPerturbation(StartSearchSpec):
    """What a robustness search may change about an episode's start (strategies.EpisodePerturbation):
    the start's ranges and ``GapScale``, the spawn gaps (below 1 denser traffic)."""

    NEUTRAL: ClassVar[dict[str, float]] = {**StartSearchSpec.NEUTRAL, "GapScale": 1.0}
    BOUNDS: ClassVar[dict[str, tuple[float, float, str]]] = {
        **StartSearchSpec.BOUNDS, "GapScale": (1e-3, math.inf, "a gap scale must stay above 0")}

    GapScale: tuple[float, float] | None = Field(None, description=(
        "[low, high]: the blueprint's spawn gaps scaled (below 1 denser traffic); the range holds 1"))
    FailOn: list[Literal["collision", "off_road", "step_limit"]] = Field(
        default_factory=lambda: list(FAILURES), min_length=1,
        description="episode outcomes that fail an example: collision, off_road, step_limit")

    @model_validator(mode="after")
    def _each_outcome_once(self):
        if len(set(self.FailOn)) != len(self.FailOn):
            raise located_error("FailOn", self.FailOn, "each outcome once")
        return self


class PolicyBenchmarkConfig(ConditionsModel):
    Blueprint: BlueprintSpec = Field(description="the road and traffic: a blueprint by Name or a CommonRoad file")
    Episodes: PositiveInt = Field(64, description="episodes per policy, seeds FirstSeed .. FirstSeed + Episodes - 1")
    FirstSeed: NonNegativeInt = Field(0, description="the first episode's seed")
    Strata: PositiveInt = Field(8, description="seed groups the stratified bootstrap resamples within")
    AgentLimit: int = Field(12, description=(
        "agents an episode holds, the ego counted; the graph observation's node count"))
    StepLimit: PositiveInt | None = Field(None, description=(
        "steps after which an episode ends as step_limit; default: the blueprint's max_steps"))
    Policies: dict[str, str] = Field(min_length=1, description=(
        "name: model spec (.pt2, TorchScript, or with --driveeval-allow-scenario-code weights.pt=module:factory) "
        "or a baseline (random, constant, idm_expert); one item per policy"))
    Judged: list[str] | None = Field(None, description=(
        "the policies whose items the Conditions decide; default: every policy that is not a baseline"))
    #: policies a judged item is compared with, paired on its episodes, reported and never decided
    Compare: list[str] = Field(default_factory=list, description=(
        "policies a judged item is compared with, paired on its episodes, reported and never decided"))
    Conditions: BenchmarkConditions = Field(default_factory=BenchmarkConditions, description=(
        "what a judged policy must meet, decided on intervals"))
    Artefacts: BenchmarkArtefacts = Field(default_factory=BenchmarkArtefacts, description=(
        "the pictures each item leaves"))
    Perturbation: PolicyPerturbation | None = Field(None, description=(
        "a robustness search for an episode start and traffic that breaks the policy, instead of the benchmark; "
        "the Conditions are not judged then"))
    Executor: ExecutorSpec | None = Field(None, description=(
        "run the episodes in chunks of seeds, here or as Ray tasks; --driveeval-executor replaces each key it "
        "gives; default: local, one batch"))

    @model_validator(mode="after")
    def _consistent(self):
        last = self.FirstSeed + self.Episodes - 1
        if last >= SEED_LIMIT:
            raise located_error("FirstSeed", self.FirstSeed,
                                f"the episodes' seeds (FirstSeed .. FirstSeed + Episodes - 1) must stay below 2**63 "
                                f"= {SEED_LIMIT}; the last would be {last}")
        if self.AgentLimit < 1:
            raise located_error("AgentLimit", self.AgentLimit,
                           "the agent limit counts the ego, so it is at least 1")
        self._fits_in_memory()
        if self.Blueprint.CommonRoad is not None:
            self._fits_commonroad()
        for index, name in enumerate(self.Judged or ()):
            if name not in self.Policies:
                raise located_error(("Judged", index), name, f"'{name}' is not one of this scenario's Policies "
                                                        f"({', '.join(self.Policies)})")
        for index, name in enumerate(self.Compare):
            if name not in self.Policies:
                raise located_error(("Compare", index), name, f"'{name}' is not one of this scenario's Policies "
                                                         f"({', '.join(self.Policies)})")
        judged = self.judged()
        for index, beats in enumerate(self.Conditions.Beats):
            if beats.Baseline not in self.Policies:
                raise located_error(("Conditions", "Beats", index, "Baseline"), beats.Baseline,
                               f"'{beats.Baseline}' is not one of this scenario's Policies "
                               f"({', '.join(self.Policies)})")
            if beats.Baseline in judged:
                why = "Judged lists it" if self.Judged is not None else \
                    "without Judged, every policy that is not a baseline is judged"
                raise located_error(("Conditions", "Beats", index, "Baseline"), beats.Baseline,
                                    f"'{beats.Baseline}' is judged ({why}), and a policy cannot be its own "
                                    "baseline: compare with another policy, or leave it out of Judged")
        return self

    def _fits_commonroad(self) -> None:
        """What a CommonRoad scene cannot do yet, refused at its key."""
        for key in ("AgentsSpeedScale", "GapScale"):
            if self.Perturbation is not None and getattr(self.Perturbation, key) is not None:
                raise located_error(("Perturbation", key), getattr(self.Perturbation, key),
                                    "a CommonRoad scene replays its recorded obstacles: only the ego's start "
                                    "(Lateral, Longitudinal, Heading, SpeedScale) can be perturbed")
        # The scene holds every step's recording from the start: bounded here, before the file is
        # read; with the file's obstacles counted again when the item builds its scene.
        from pytest_driveeval.sim.commonroad_scene import scene_bytes

        steps = self.blueprint_params().get("max_steps")
        if steps is not None:
            loc = "StepLimit" if self.StepLimit is not None else ("Blueprint", "Params", "max_steps")
            check_fits(loc, steps, scene_bytes(int(steps), 0),
                       f"a CommonRoad scene of {int(steps)} steps (its recording is held for every step)")

    def _fits_in_memory(self) -> None:
        agents, episodes = self.AgentLimit, self.Episodes
        one = episode_bytes(agents)
        if self.Perturbation is not None:  # a search steps one generation's episodes at a time
            episodes = min(episodes, self.Perturbation.Batch)
        check_fits("AgentLimit", agents, one, f"one episode of {agents} agents (its graph observation "
                                               "grows with the agents squared)")
        check_fits("Episodes", self.Episodes, episodes * one,
                   f"{episodes} episodes of {agents} agents stepped together")

    @classmethod
    def parameter_tables(cls) -> list[tuple[str, type, tuple[str, ...] | None]]:
        """The dataclasses ``Blueprint.Params`` is read into, for the scenario keys' page
        (scenario.reference): (title, dataclass, the fields that apply, None for all)."""
        from pytest_driveeval.sim.blueprints import BLUEPRINTS, BlueprintParams
        from pytest_driveeval.sim.commonroad_scene import CommonRoadParams

        tables: list[tuple[str, type, tuple[str, ...] | None]] = [
            (f"`Name: {name}`", params, None) for name, (params, _) in sorted(BLUEPRINTS.items())]
        # What check_params accepts: the blueprint fields that mean something there, and its own.
        base = {f.name for f in dataclasses.fields(BlueprintParams)}
        own = tuple(f.name for f in dataclasses.fields(CommonRoadParams) if f.name not in base)
        tables.append(("a `CommonRoad` scene", CommonRoadParams, (*CommonRoadParams.USED, *own)))
        return tables

    def blueprint_params(self) -> dict[str, Any]:
        """make_blueprint's keyword arguments: the blueprint's Params and the StepLimit."""
        params = dict(self.Blueprint.Params)
        if self.StepLimit is not None:
            params["max_steps"] = self.StepLimit
        return params

    def judged(self) -> list[str]:
        if self.Judged is not None:
            return self.Judged
        learnt = [name for name, spec in self.Policies.items() if spec not in BASELINES]
        return learnt or list(self.Policies)
