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

from typing import Any

from pytest_driveeval.errors import display_path
from pytest_driveeval.outcome import FAILED, PASSED, Outcome
from pytest_driveeval.usecase import Case, RunContext, UseCase, register_usecase
from pytest_driveeval.usecases.policy_benchmark.config import BASELINES, BenchmarkConditions, PolicyBenchmarkConfig

__all__ = ["PolicyBenchmark", "baseline", "load_policy"]


def baseline(name: str) -> Any:
    from pytest_driveeval.policies.control_baselines import ConstantAction, RandomAction

    if name == "random":
        return RandomAction()
    if name == "constant":
        return ConstantAction()
    from pytest_driveeval.policies.idm_expert import IDMExpert  # reads the simulator's lanes

    return IDMExpert()


def load_policy(ctx: RunContext, name: str, spec: str, from_option: bool = False) -> Any:
    """A policy by its spec: a baseline's name, or a model file / factory (code only with opt-in)."""
    from pytest_driveeval.policies.loading import load_model, refuse_code_from_data, runs_code

    if spec in BASELINES:
        return baseline(spec)
    if not from_option and not ctx.allow_code and runs_code(spec):
        line = ctx.scenario.line_of("Evaluation", "Policies", name)
        refuse_code_from_data(spec, f"{display_path(ctx.scenario.path)}:{line}")
    return load_model(spec, base=None if from_option else ctx.scenario.folder)


@register_usecase
class PolicyBenchmark(UseCase):
    name = "policy_benchmark"
    format_versions = ("0.1.0",)
    config_model = PolicyBenchmarkConfig
    fixtures = ("driveeval_model",)

    def cases(self, scenario) -> list[Case]:
        return [Case(f"{self.name}[{policy}]", params={"policy": policy}) for policy in scenario.config.Policies]

    def load_model(self, ctx: RunContext, spec: str | None) -> Any:
        policy = ctx.case.params["policy"]
        ctx.notes["policy"] = policy
        own = ctx.scenario.config.Policies[policy]
        # --driveeval-model replaces the policy under test, never a baseline.
        if spec is not None and own not in BASELINES:
            return load_policy(ctx, policy, spec, from_option=True)
        return load_policy(ctx, policy, own)

    def run(self, config: PolicyBenchmarkConfig, ctx: RunContext) -> Outcome:
        from pytest_driveeval.sim.blueprints import make_blueprint
        from pytest_driveeval.usecases.policy_benchmark.artefacts import EpisodeRecorder, write_artefacts
        from pytest_driveeval.usecases.policy_benchmark.evaluate import run_policy, seeds_for
        from pytest_driveeval.usecases.policy_benchmark.judge import RATES, judge, rate_intervals

        policy = ctx.case.params["policy"]
        params = dict(config.Blueprint.Params)
        if config.StepLimit is not None:
            params["max_steps"] = config.StepLimit
        blueprint = make_blueprint(config.Blueprint.Name, **params)
        seeds, strata = seeds_for(config.FirstSeed, config.Episodes, config.Strata)
        if config.Perturbation is not None:
            from pytest_driveeval.search.item import run_item
            from pytest_driveeval.usecases.policy_benchmark.robustness import policy_searchable

            searchable = policy_searchable(config, blueprint, seeds, ctx.fixtures["driveeval_model"], policy, ctx)
            return run_item(self.name, searchable, config.Perturbation, ctx)

        def run(name: str, model: Any, on_step=None):
            return run_policy(blueprint, seeds, model, name, strata=strata, agent_limit=config.AgentLimit,
                              on_step=on_step)

        judged = policy in config.judged()
        # Only a judged policy's item decides the conditions; the others report their intervals.
        conditions = config.Conditions if judged else BenchmarkConditions(Confidence=config.Conditions.Confidence)
        recorder = EpisodeRecorder() if config.Artefacts.Animations != "none" else None
        runs = {policy: run(policy, ctx.fixtures["driveeval_model"], recorder)}
        for spec in conditions.Beats:
            if spec.Baseline not in runs:
                runs[spec.Baseline] = run(spec.Baseline, load_policy(ctx, spec.Baseline,
                                                                     config.Policies[spec.Baseline]))
        judgement = judge(runs[policy], runs, conditions, seed=config.FirstSeed)
        mine = runs[policy]
        # This item's rates are in its judgement already; the baselines' are for the comparison plot.
        keys = [f"{outcome}_rate" for _, outcome in RATES.values()]
        rates = {name: {k: judgement.intervals[k] for k in keys} if name == policy
                 else rate_intervals(r, conditions.Confidence, config.FirstSeed) for name, r in runs.items()}
        artefacts = write_artefacts(ctx, mine, recorder, rates, config)
        figures = mine.figures()
        summary = (f"'{policy}' on {config.Blueprint.Name}: goal {figures['goal_rate']:.1f} %, collision "
                   f"{figures['collision_rate']:.1f} %, off road {figures['off_road_rate']:.1f} % of "
                   f"{figures['episodes']} episodes")
        details = {"policy": policy, "judged": judged, "blueprint": config.Blueprint.Name,
                   "intervals": judgement.intervals,
                   "compared": {name: r.figures() for name, r in runs.items() if name != policy}}
        return Outcome(self.name, PASSED if judgement.passed else FAILED, summary, figures=figures,
                       findings=judgement.findings, details=details, artefacts=artefacts)
