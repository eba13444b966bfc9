"""Use case ``policy_benchmark``: control policies (a GNN over a graph of the
traffic, say) drive seeded highway / merging / intersection episodes and are
judged on goal, collision and off-road rates and against baselines, with
confidence intervals (seed 002).

:mod:`.evaluate` runs a policy's episodes, :mod:`.judge` decides the
conditions, :mod:`.config` is the YAML.  One item per policy of a scenario.
With a ``Perturbation`` section the item is a robustness search instead
(:mod:`.robustness`).
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

from pytest_driveeval.core.errors import display_path
from pytest_driveeval.core.outcome import FAILED, PASSED, Outcome
from pytest_driveeval.core.usecase import MODEL_OPTION_NOTE, Case, RunContext, UseCase, register_usecase
from pytest_driveeval.usecases.policy_benchmark.baselines import baseline
from pytest_driveeval.usecases.policy_benchmark import regression
from pytest_driveeval.usecases.policy_benchmark.config import BASELINES, BenchmarkConditions, PolicyBenchmarkConfig
from pytest_driveeval.usecases.policy_benchmark.scene_names import gif_part, name_outcome, scene_identity

__all__ = ["PolicyBenchmark", "baseline", "load_policy"]


def vet_policy_spec(ctx: RunContext, name: str, spec: str, from_option: bool = False) -> None:
    """Refuse a scenario's policy spec that would run code unless the user opted in; wherever the
    policy is then loaded (here, or on a Ray worker from its spec), it passed this."""
    from pytest_driveeval.policies.loading import refuse_code_from_data, runs_code

    if spec not in BASELINES and not from_option and not ctx.allow_code and runs_code(spec):
        line = ctx.scenario.line_of("Evaluation", "Policies", name)
        refuse_code_from_data(spec, f"{display_path(ctx.scenario.path)}:{line}")


def load_policy(ctx: RunContext, name: str, spec: str, from_option: bool = False) -> Any:
    """A policy by its spec: a baseline's name, or a model file / factory (code only with opt-in)."""
    from pytest_driveeval.policies.loading import load_model

    if spec in BASELINES:
        return baseline(spec)
    vet_policy_spec(ctx, name, spec, from_option)
    return load_model(spec, base=None if from_option else ctx.scenario.folder)


@register_usecase
class PolicyBenchmark(UseCase):
    name = "policy_benchmark"
    format_versions = ("0.1.0",)
    config_model = PolicyBenchmarkConfig
    fixtures = ("driveeval_model",)
    baselines = BASELINES
    model_noun = "policy"
    regression_figures = regression.FIGURES

    def regression_units(self, outcome: Outcome):
        return regression.episode_units(outcome)

    def cases(self, scenario) -> list[Case]:
        from pytest_driveeval.usecases.policy_benchmark.commonroad import planning_problems

        problems = planning_problems(scenario)
        if problems is None:
            return [Case(f"{self.name}[{policy}]", params={"policy": policy}) for policy in scenario.config.Policies]
        return [Case(f"{self.name}[{policy}-problem{problem}]", params={"policy": policy, "problem": problem})
                for problem in problems for policy in scenario.config.Policies]

    def load_model(self, ctx: RunContext, spec: str | None) -> Any:
        from pytest_driveeval.usecases.policy_benchmark.chunked import PolicySource

        policy = ctx.case.params["policy"]
        ctx.notes["policy"] = policy
        own = ctx.scenario.config.Policies[policy]
        # --driveeval-model replaces the policy under test, never a baseline.
        if spec is not None and own not in BASELINES:
            self.vet_model_option(ctx, spec, own)
            model = load_policy(ctx, policy, spec, from_option=True)
            source = PolicySource(spec, str(Path.cwd()))
        else:
            ctx.notes.pop(MODEL_OPTION_NOTE, None)
            model = load_policy(ctx, policy, own)
            source = PolicySource(own, str(ctx.scenario.folder))
        # How a Ray worker loads the same policy; kept with the object, so that run() can tell
        # this model from one a conftest.py fixture built (which has no spec to send).
        ctx.notes["policy_source"] = (source, model)
        return model

    def run(self, config: PolicyBenchmarkConfig, ctx: RunContext) -> Outcome:
        from pytest_driveeval.sim.blueprints import make_blueprint
        from pytest_driveeval.usecases.policy_benchmark.artefacts import EpisodeRecorder, write_artefacts
        from pytest_driveeval.usecases.policy_benchmark.evaluate import run_policy, seeds_for
        from pytest_driveeval.usecases.policy_benchmark.judge import RATES, judge, rate_intervals

        policy = ctx.case.params["policy"]
        params = config.blueprint_params()
        if config.Blueprint.CommonRoad is None:
            blueprint = make_blueprint(config.Blueprint.Name, **params)
        else:
            from pytest_driveeval.usecases.policy_benchmark.commonroad import check_expert_routes, scene_for

            blueprint = scene_for(config, ctx, params)
            check_expert_routes(config, ctx, blueprint, [policy])
        identity = scene_identity(blueprint)
        seeds, strata = seeds_for(config.FirstSeed, config.Episodes, config.Strata)
        model = ctx.fixtures["driveeval_model"]
        executor, source, stays_local = self._executor(config, ctx, model)
        if config.Perturbation is not None:
            from pytest_driveeval.search.item import run_item
            from pytest_driveeval.usecases.policy_benchmark.robustness import policy_searchable

            from pytest_driveeval.usecases.executor import ChunkLedger

            ledger = ChunkLedger()
            searchable = policy_searchable(config, blueprint, seeds, model, policy, ctx, executor=executor,
                                           source=source, ledger=ledger, gif_part=gif_part(identity))
            outcome = name_outcome(run_item(self.name, searchable, config.Perturbation, ctx), identity)
            if ledger.runs:
                outcome.details["executor"] = ledger.details()
            elif stays_local:
                outcome.details["executor"] = stays_local
            return outcome

        def run(name: str, model: Any, on_step=None):
            return run_policy(blueprint, seeds, model, name, strata=strata, agent_limit=config.AgentLimit,
                              on_step=on_step, progress=ctx.progress_of(f"{name}: episodes"))

        judged = policy in config.judged()
        # Only a judged policy's item decides the conditions; the others report their intervals.
        conditions = config.Conditions if judged else BenchmarkConditions(Confidence=config.Conditions.Confidence)
        animated = config.Artefacts.Animations != "none"
        compared = [name for name in config.Compare if name != policy] if judged else []
        baselines = list(dict.fromkeys([spec.Baseline for spec in conditions.Beats if spec.Baseline != policy]
                                       + compared))
        if config.Blueprint.CommonRoad is not None:
            from pytest_driveeval.usecases.policy_benchmark.commonroad import check_expert_routes

            check_expert_routes(config, ctx, blueprint, baselines)
        where: dict | None = stays_local or None
        replay = recorder = None
        if executor is None:
            recorder = EpisodeRecorder() if animated else None
            runs = {policy: run(policy, model, recorder)}
            for name in baselines:
                if name not in runs:
                    runs[name] = run(name, load_policy(ctx, name, config.Policies[name]))
        else:
            from pytest_driveeval.usecases.executor import executor_details
            from pytest_driveeval.usecases.policy_benchmark.chunked import PolicySource, run_policies_chunked

            for name in baselines:  # loaded on the workers: the same check as load_policy here
                vet_policy_spec(ctx, name, config.Policies[name])
            sources = {policy: source, **{name: PolicySource(config.Policies[name], str(ctx.scenario.folder))
                                          for name in baselines}}
            runs, chunk_run, described = run_policies_chunked(ctx, executor, blueprint, params, seeds, strata,
                                                              sources, config.AgentLimit)
            where = executor_details(chunk_run, described.__getitem__)
            if animated:
                replay = self._replayer(blueprint, runs[policy], model, policy, config.AgentLimit)
        judgement = judge(runs[policy], runs, conditions, seed=config.FirstSeed, compare=compared)
        mine = runs[policy]
        # This item's rates are in its judgement already; the baselines' are for the comparison plot.
        keys = [f"{outcome}_rate" for _, outcome in RATES.values()]
        rates = {name: {k: judgement.intervals[k] for k in keys} if name == policy
                 else rate_intervals(r, conditions.Confidence, config.FirstSeed) for name, r in runs.items()}
        artefacts = write_artefacts(ctx, mine, recorder, rates, config, replay=replay, scene=identity)
        figures = mine.figures()
        summary = (f"'{policy}' on {blueprint.name}: goal {figures['goal_rate']:.1f} %, collision "
                   f"{figures['collision_rate']:.1f} %, off road {figures['off_road_rate']:.1f} % of "
                   f"{figures['episodes']} episodes")
        details = {"policy": policy, "judged": judged, "blueprint": blueprint.name,
                   "intervals": judgement.intervals,
                   "compared": {name: r.figures() for name, r in runs.items() if name != policy},
                   "episode_outcomes": regression.episode_outcomes(mine.seeds, mine.outcome_names())}
        if where:
            details["executor"] = where
        return name_outcome(Outcome(self.name, PASSED if judgement.passed else FAILED, summary, figures=figures,
                                    findings=judgement.findings, details=details, artefacts=artefacts), identity)

    @staticmethod
    def _executor(config: PolicyBenchmarkConfig, ctx: RunContext, model: Any) -> tuple[Any, Any, dict]:
        """(the Ray executor or None, how a worker loads the policy, why the item stays local
        although an executor was asked for: usecases.executor.item_executor)."""
        from pytest_driveeval.usecases.executor import item_executor

        source, loaded = ctx.notes.get("policy_source", (None, None))
        executor, where = item_executor(ctx, config.Executor, loaded, model, "policy")
        return executor, source if executor is not None else None, where

    @staticmethod
    def _replayer(blueprint: Any, run: Any, model: Any, name: str, agent_limit: int):
        from pytest_driveeval.usecases.policy_benchmark.artefacts import EpisodeRecorder
        from pytest_driveeval.usecases.policy_benchmark.evaluate import run_policy

        def replay(row: int) -> EpisodeRecorder:
            recorder = EpisodeRecorder()
            run_policy(blueprint, run.seeds[row:row + 1], model, name, agent_limit=agent_limit, on_step=recorder)
            return recorder

        return replay
