"""The policy benchmark's robustness search: which perturbed episode does a policy not finish?

An example is one of the scenario's episode seeds with its start perturbed
(:class:`~pytest_driveeval.strategies.EpisodePerturbation`); it fails when
that episode ends in one of the section's ``FailOn`` outcomes.  A generation
of examples is one batch of episodes: one ``reset`` with each example's seed
and perturbation row, one policy call per step for all of them, so the cost
of a generation is close to that of its longest episode (and torch runs on
one thread: see :func:`~pytest_driveeval.sim.torch_threads.one_torch_thread`).
"""
from __future__ import annotations

from typing import Any, Callable, Sequence

import numpy as np

from pytest_driveeval.metrics.episode_outcomes import OUTCOME_NAMES
from pytest_driveeval.core.outcome import FAILED, PASSED, Finding, Outcome
from pytest_driveeval.search.engine import Example, Verdict
from pytest_driveeval.search.item import Searchable
from pytest_driveeval.sim.episodes import PERTURBATION_COLUMNS
from pytest_driveeval.strategies import EpisodePerturbation, describe, episode_perturbations
from pytest_driveeval.usecases.policy_benchmark.config import PolicyBenchmarkConfig
from pytest_driveeval.usecases.policy_benchmark.evaluate import PolicyRun, run_policy

__all__ = ["episode_verdict", "perturbation_rows", "policy_searchable", "show_episode"]


def perturbation_rows(perturbations: Sequence[EpisodePerturbation]) -> np.ndarray:
    """The engine's (E, 6) rows of the perturbations, in :data:`PERTURBATION_COLUMNS` order."""
    return np.array([[float(getattr(p, column)) for column in PERTURBATION_COLUMNS] for p in perturbations],
                    dtype=np.float64).reshape(len(perturbations), len(PERTURBATION_COLUMNS))


def _reason(outcome: str, steps: int) -> str:
    if outcome == "collision":
        return f"collision at step {steps}"
    if outcome == "off_road":
        return f"left the road at step {steps}"
    if outcome == "step_limit":
        return f"no goal within {steps} steps"
    return f"{outcome} at step {steps}"


def episode_verdict(run: PolicyRun, row: int, fail_on: Sequence[str]) -> Verdict:
    """Episode ``row`` of ``run`` as the search sees it: failed when its outcome is one of ``fail_on``."""
    outcome, steps, seed = OUTCOME_NAMES[int(run.outcome[row])], int(run.steps[row]), int(run.seeds[row])
    return Verdict(outcome in fail_on, _reason(outcome, steps), {"seed": seed, "step": steps})


def policy_searchable(config: PolicyBenchmarkConfig, blueprint: Any, seeds: np.ndarray, policy: Callable,
                      name: str, ctx: Any, *, executor: Any = None, source: Any = None,
                      ledger: Any = None, gif_part: str = "") -> Searchable:
    """The search of ``policy`` (called ``name``) over the episodes of ``seeds``.

    With a Ray ``executor`` (and the policy's ``source``, chunked.PolicySource) each generation's
    episodes run as chunks of the Executor's ChunkSize on the cluster, the ``ledger``
    (executor.ChunkLedger) counting where; the picture of the case found is drawn here, ``gif_part``
    added to its name after the seed (a CommonRoad scene's, scene_names.gif_part)."""
    spec = config.Perturbation
    fail_on = tuple(spec.FailOn)
    if executor is not None and ledger is None:
        from pytest_driveeval.usecases.executor import ChunkLedger

        ledger = ChunkLedger()

    def run(case_seeds: np.ndarray, perturbations: Sequence[EpisodePerturbation], on_step=None) -> PolicyRun:
        return run_policy(blueprint, case_seeds, policy, name, agent_limit=config.AgentLimit, on_step=on_step,
                          perturbation=perturbation_rows(perturbations))

    def run_chunked(case_seeds: np.ndarray, perturbations: Sequence[EpisodePerturbation]) -> PolicyRun:
        from pytest_driveeval.usecases.policy_benchmark.chunked import (DEFAULT_CHUNK_SIZE, chunk_blueprint,
                                                                        episode_chunks, merged, run_episode_chunk)

        work = episode_chunks(name, source, *chunk_blueprint(blueprint, config.blueprint_params()), case_seeds,
                              config.AgentLimit, executor.ChunkSize or DEFAULT_CHUNK_SIZE,
                              perturbation_rows(perturbations))
        chunk_run = ledger.run(ctx, executor, work, run_episode_chunk)
        done = merged(chunk_run.results)
        return PolicyRun(name, blueprint.name, case_seeds, np.zeros(len(case_seeds), np.int64), done.outcome,
                         done.returns, done.steps)

    def evaluate_many(examples: list[Example]) -> list[Verdict]:
        case_seeds, perturbations = seeds[[e.case for e in examples]], [e.perturbation for e in examples]
        done = run(case_seeds, perturbations) if executor is None else run_chunked(case_seeds, perturbations)
        return [episode_verdict(done, i, fail_on) for i in range(len(examples))]

    def show(example: Example) -> Outcome:
        return show_episode(config, ctx, name, int(seeds[example.case]), example.perturbation, fail_on, run,
                            gif_part=gif_part)

    return Searchable(case_name="seed", case_labels=[int(s) for s in seeds], perturbation_type=EpisodePerturbation,
                      perturbations=episode_perturbations(**spec.ranges()), evaluate_many=evaluate_many, show=show)


def show_episode(config: PolicyBenchmarkConfig, ctx: Any, name: str, seed: int, perturbation: EpisodePerturbation,
                 fail_on: Sequence[str], run: Callable[..., PolicyRun], gif_part: str = "") -> Outcome:
    """One perturbed episode as an item's outcome, with its GIF unless the scenario's Animations are "none"
    (the case a search reports is worth its picture whatever the benchmark's own setting)."""
    from pytest_driveeval.usecases.policy_benchmark.artefacts import EpisodeRecorder, episode_gif

    recorder = EpisodeRecorder() if config.Artefacts.Animations != "none" else None
    done = run(np.array([seed], dtype=np.int64), [perturbation], recorder)
    verdict = episode_verdict(done, 0, fail_on)
    outcome, steps = done.outcome_names()[0], int(done.steps[0])
    changed = describe(perturbation)
    artefacts = {}
    if recorder is not None:
        artefacts[f"episode_{seed}_gif"] = episode_gif(
            ctx.artefact(f"episode_seed_{seed}{gif_part}_perturbed.gif"), recorder, 0, config.AgentLimit,
            f"{name} seed {seed}, {changed}: {outcome}")
    findings = [Finding(f"seed {seed} under {changed}: {verdict.reason}", frame=steps,
                        keypath=("Evaluation", "Perturbation", "FailOn"))] if verdict.failed else []
    summary = f"'{name}' on {config.Blueprint.label}, seed {seed} under {changed}: {outcome} after {steps} steps"
    details = {"policy": name, "blueprint": config.Blueprint.label, "seed": seed, "outcome": outcome, "steps": steps,
               "return": float(done.returns[0]), "perturbation": perturbation.to_json(), "fail_on": list(fail_on)}
    return Outcome("policy_benchmark", FAILED if verdict.failed else PASSED, summary,
                   figures={"episode_steps": steps, "episode_return": float(done.returns[0])}, findings=findings,
                   artefacts=artefacts, details=details)
