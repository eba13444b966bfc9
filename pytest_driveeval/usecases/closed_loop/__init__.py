"""Use case ``closed_loop``: a planning policy drives the ego through logged
L5 scenes (seed 000), judged on collisions, drift and resets per scene.

:mod:`.evaluate` is the Python API behind it (unroll, judge), :mod:`.config`
the YAML it reads, :mod:`.assertions` the helpers for tests written in Python,
:mod:`.artefacts` what it leaves next to the summary.  Importing the package
registers the use case; it stays light (no torch, no zarr reader) because
``import pytest_driveeval`` imports its assertions.
"""
from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable

from pytest_driveeval.core.errors import ModelError, display_path
from pytest_driveeval.metrics.nuplan_score.score import item_figures
from pytest_driveeval.core.outcome import FAILED, PASSED, Finding, Outcome
from pytest_driveeval.core.usecase import RunContext, UseCase, register_usecase
from pytest_driveeval.usecases.closed_loop import regression
from pytest_driveeval.usecases.closed_loop.artefacts import write_artefacts
from pytest_driveeval.usecases.closed_loop.baselines import BASELINES, baseline
from pytest_driveeval.usecases.closed_loop.config import ClosedLoopConfig, replayed_agents
from pytest_driveeval.usecases.closed_loop.names import gif_name, name_verdicts, named_text, scene_label
from pytest_driveeval.usecases.closed_loop.evaluate import (
    KINDS,
    judge_scene,
    select_scenes,
    starts_past_end,
    unroll_scenes,
)

if TYPE_CHECKING:
    from pytest_driveeval.io.l5.l5kit_zarr import L5Dataset
    from pytest_driveeval.strategies import StartPerturbation


@register_usecase
class ClosedLoop(UseCase):
    name = "closed_loop"
    format_versions = ("0.1.0",)
    config_model = ClosedLoopConfig
    fixtures = ("driveeval_dataset", "driveeval_model")
    baselines = BASELINES
    regression_figures = regression.FIGURES

    def regression_units(self, outcome: Outcome):
        return regression.scene_units(outcome)

    def load_dataset(self, ctx: RunContext) -> L5Dataset:
        from pytest_driveeval.usecases.closed_loop.datasets import open_dataset

        declared = (ctx.dataset.options or {}).get("Format") if ctx.dataset is not None else None
        return open_dataset(super().load_dataset(ctx), declared)

    def load_model(self, ctx: RunContext, spec: str | None):
        from pytest_driveeval.policies.loading import (
            load_model,
            refuse_code_from_data,
            runs_code,
        )

        from_option = spec is not None
        spec = spec or ctx.scenario.config.Model
        if not spec:
            raise ModelError(f"{ctx.scenario.path}: no Model given (Evaluation.Model, --driveeval-model, "
                             "or a driveeval_model fixture)")
        if from_option:
            self.vet_model_option(ctx, spec, ctx.scenario.config.Model)
        ctx.notes["policy"] = Path(spec).name if spec not in BASELINES and ":" not in spec else spec
        if spec in BASELINES:
            model = baseline(spec, ctx.scenario.config)
        else:
            if not from_option and not ctx.allow_code and runs_code(spec):
                where = f"{display_path(ctx.scenario.path)}:{ctx.scenario.line_of('Evaluation', 'Model')}"
                refuse_code_from_data(spec, where)
            model = load_model(spec, base=None if from_option else ctx.scenario.folder)
        # How a Ray worker loads the same model, kept with the object so that run() can tell it
        # from one a conftest.py fixture built (which has no spec to send).
        ctx.notes["model_source"] = (spec, str(Path.cwd() if from_option else ctx.scenario.folder), model)
        return model

    def run(self, config: ClosedLoopConfig, ctx: RunContext) -> Outcome:
        dataset: L5Dataset = ctx.fixtures["driveeval_dataset"]
        ids, problems = self._scenes(config, dataset)
        if config.Perturbation is not None and ids:
            from pytest_driveeval.search.item import run_item
            from pytest_driveeval.sim.torch_threads import one_torch_thread
            from pytest_driveeval.usecases.closed_loop.robustness import closed_loop_searchable

            executor, where = self._executor(config, ctx)
            distribute, ledger = self._distributed_search(config, ctx, ids, executor) if executor else (None, None)
            searchable = closed_loop_searchable(
                config, dataset, ctx.fixtures["driveeval_model"], ids, replayed_agents(config.Unroll.Agents),
                show=lambda scene, perturbation: self._evaluate(config, ctx, [scene], [], perturbation),
                distribute=distribute)
            with one_torch_thread():
                outcome = run_item(self.name, searchable, config.Perturbation, ctx)
            if ledger is not None and ledger.runs:
                outcome.details["executor"] = ledger.details()
            elif where:
                outcome.details["executor"] = where
            if problems:
                outcome.verdict, outcome.findings = FAILED, problems + outcome.findings
            return outcome
        return self._evaluate(config, ctx, ids, problems)

    @staticmethod
    def _scenes(config: ClosedLoopConfig, dataset: L5Dataset) -> tuple[list[int], list[Finding]]:
        """The scenes to unroll, and findings about those asked for that cannot be."""
        spec = config.Unroll
        ids, out_of_range = select_scenes(dataset.num_scenes, spec.Scenes, spec.SceneStride)
        findings = [Finding(f"scene {s} is out of range: {dataset.path} has scenes 0..{dataset.num_scenes - 1}",
                            scene=s, keypath=("Evaluation", "Unroll", "Scenes")) for s in out_of_range]
        # A dataset of one file per scene (ScenarioNet) can have one broken file: it fails alone.
        problem = getattr(dataset, "problem", None)
        broken = {s: problem(s) for s in ids} if problem is not None else {}
        findings += [Finding(f"scene {s} cannot be read: {why}", scene=s, keypath=("Evaluation", "Datasets"))
                     for s, why in broken.items() if why is not None]
        ids = [s for s in ids if broken.get(s) is None]
        past_end = starts_past_end(dataset, ids, spec.StartFrame)
        findings += [Finding(f"StartFrame {spec.StartFrame} is past the end of scene {s} of {dataset.path} "
                             f"({n} frames, 0..{n - 1})", scene=s, keypath=("Evaluation", "Unroll", "StartFrame"))
                     for s, n in past_end]
        unreachable = {s for s, _ in past_end}
        return [s for s in ids if s not in unreachable], findings

    def _evaluate(self, config: ClosedLoopConfig, ctx: RunContext, ids: list[int], problems: list[Finding],
                  perturbation: StartPerturbation | None = None) -> Outcome:
        """Unroll and judge the scenes ``ids`` (each under ``perturbation`` if given)."""
        dataset: L5Dataset = ctx.fixtures["driveeval_dataset"]
        spec = config.Unroll
        executor, where = (None, {}) if perturbation is not None or not ids else self._executor(config, ctx)
        if executor is not None:
            return self._evaluate_chunks(config, ctx, ids, problems, executor)
        from pytest_driveeval.usecases.closed_loop.raster_inputs import semantic_map_for

        semantic_map = semantic_map_for(spec.Inputs, dataset.path, ctx.scenario.folder, dataset, ids) \
            if ids else None
        unroll = unroll_scenes(dataset, ctx.fixtures["driveeval_model"], ids, **spec.unroll_options(),
                               agents=replayed_agents(spec.Agents), perturbation=perturbation,
                               semantic_map=semantic_map,
                               # a search's examples show their own count (search.item), not each unroll's steps
                               progress=ctx.progress_of("steps") if perturbation is None else None) if ids else None
        verdicts = [judge_scene(unroll, row, config.Conditions) for row in range(len(ids))]
        outcome = self._outcome(config, ctx, verdicts, problems, dataset,
                                lambda figures: write_artefacts(ctx, config, unroll, verdicts, figures, dataset)
                                if unroll is not None else {},
                                [unroll.result.errors[row] for row in range(len(ids))] if unroll is not None else [])
        if perturbation is not None:
            outcome.details["perturbation"] = perturbation.to_json()
        if where:
            outcome.details["executor"] = where
        return outcome

    def _outcome(self, config: ClosedLoopConfig, ctx: RunContext, verdicts: list, problems: list[Finding],
                 dataset: L5Dataset, artefacts_for: Callable[[dict], dict], errors: list[str]) -> Outcome:
        """The item's outcome from its scenes' verdicts, however they were unrolled."""
        identities = name_verdicts(dataset, verdicts, problems)
        for row, verdict in enumerate(verdicts):
            verdict.identity = identities.get(verdict.scene, {"index": verdict.scene})
            if row < len(errors):
                errors[row] = named_text(errors[row], verdict.scene, identities)
        findings = list(problems)
        for verdict in verdicts:
            findings.extend(verdict.findings)
        passed = sum(v.passed for v in verdicts)
        rate = 100.0 * passed / len(verdicts) if verdicts else 0.0
        figures = {k: sum(v.figures[k] for v in verdicts) for k in (*KINDS, "at_fault", "drift_resets")}
        figures.update(scenes=len(verdicts), scenes_passed=passed, steps=sum(v.figures["steps"] for v in verdicts))
        if verdicts:
            figures["max_displacement"] = max(v.figures["max_displacement"] for v in verdicts)
        figures.update(item_figures([v.figures for v in verdicts]))
        score_limit = config.Conditions.Score.MeanAtLeast if config.Conditions.Score is not None else None
        scored = sum("score" in v.figures for v in verdicts)
        score_low = score_limit is not None and (not scored or figures["score"] < score_limit)
        if score_low and scored:
            findings.insert(0, Finding(
                f"mean nuPlan score {figures['score']:.3f} over {scored} scene(s) < {score_limit:g}",
                figure="score", value=figures["score"], limit=score_limit,
                keypath=("Evaluation", "Conditions", "Score", "MeanAtLeast")))
        elif score_low:  # a mean of nothing is no score: say so rather than print 0.000
            why = (f"none of the {len(verdicts)} unrolled scene(s) has a frame or a log to score it by" if verdicts
                   else "every scene asked for was refused (the reasons follow)" if problems
                   else f"{dataset.path} has no scene to unroll")
            findings.insert(0, Finding(f"no nuPlan score: no scene was scored; {why}",
                                       keypath=("Evaluation", "Conditions", "Score", "MeanAtLeast")))
        ok = bool(verdicts) and not problems and rate >= config.Conditions.ScenePassRate and not score_low
        if not verdicts and not findings:
            findings.append(Finding(f"{dataset.path} has no scene to unroll", keypath=("Evaluation", "Datasets")))
        if verdicts and rate < config.Conditions.ScenePassRate:  # with none unrolled the reason is said above
            findings.insert(0, Finding(
                f"{passed} of {len(verdicts)} scene(s) passed ({rate:.1f}%), {config.Conditions.ScenePassRate:g}% "
                "required", figure="scene_pass_rate", value=rate, limit=config.Conditions.ScenePassRate,
                keypath=("Evaluation", "Conditions", "ScenePassRate")))
        summary = (f"{passed}/{len(verdicts)} scenes passed; collisions front {figures['front']}, side "
                   f"{figures['side']}, rear {figures['rear']} ({figures['at_fault']} at fault); "
                   f"{figures['drift_resets']} drift reset(s)"
                   + (f"; nuPlan score {figures['score']:.3f}" if "score" in figures else ""))
        artefacts = artefacts_for(figures)
        details = {"policy": ctx.notes.get("policy", "driveeval_model fixture"),
                   "scenes": [{"scene": v.scene, "name": scene_label(v.identity), "identity": v.identity,
                               "passed": v.passed, **v.figures, "score_terms": v.score_terms, "error": errors[row]}
                              for row, v in enumerate(verdicts)]}
        # what the reader skipped or read other than as written (ScenarioNet: degenerate map features, jitter)
        read_notes = getattr(dataset, "read_notes", None)
        notes = {v.scene: read_notes(v.scene) for v in verdicts} if read_notes is not None else {}
        if any(notes.values()):
            details["read"] = [{"scene": scene, **note} for scene, note in notes.items() if note]
        return Outcome(self.name, PASSED if ok else FAILED, summary, figures=figures, findings=findings,
                       artefacts=artefacts, details=details)

    @staticmethod
    def _distributed_search(config: ClosedLoopConfig, ctx: RunContext, ids: list[int], executor: Any):
        """(the search's ``distribute``: a generation's examples as chunks on the executor, each
        judged on a worker by the same search code; the ledger of where they ran)."""
        from pytest_driveeval.usecases.closed_loop.chunked import SceneChunk, run_search_chunk, search_chunks
        from pytest_driveeval.usecases.executor import ChunkLedger

        dataset: L5Dataset = ctx.fixtures["driveeval_dataset"]
        model, base, _ = ctx.notes["model_source"]
        scenes = SceneChunk(str(Path(dataset.path).resolve()), tuple(int(i) for i in ids), config, model, base,
                            str(ctx.scenario.folder))
        ledger = ChunkLedger()

        def distribute(examples: list) -> list:
            run = ledger.run(ctx, executor, search_chunks(scenes, examples, executor), run_search_chunk)
            return [verdict for part in run.results for verdict in part]

        return distribute, ledger

    @staticmethod
    def _executor(config: ClosedLoopConfig, ctx: RunContext) -> tuple[Any, dict]:
        """(the executor of the item's chunks or None, why it stays local: usecases.executor.item_executor)."""
        from pytest_driveeval.usecases.executor import item_executor

        _, _, loaded = ctx.notes.get("model_source", (None, None, None))
        return item_executor(ctx, config.Executor, loaded, ctx.fixtures["driveeval_model"], "model")

    def _evaluate_chunks(self, config: ClosedLoopConfig, ctx: RunContext, ids: list[int], problems: list[Finding],
                         executor: Any) -> Outcome:
        """The scenes as chunks on the executor: each worker opens the dataset by its path, loads
        the model by its spec, and returns its scenes' verdicts, collisions and GIFs."""
        from pytest_driveeval.core.atomic import write_bytes_atomic
        from pytest_driveeval.usecases.closed_loop.artefacts import write_scene_artefacts
        from pytest_driveeval.usecases.closed_loop.chunked import merged, run_scene_chunk, scene_chunks
        from pytest_driveeval.usecases.executor import executor_details, run_item_chunks

        dataset: L5Dataset = ctx.fixtures["driveeval_dataset"]
        model, base, _ = ctx.notes["model_source"]
        work = scene_chunks(str(Path(dataset.path).resolve()), ids, config, model, base, str(ctx.scenario.folder),
                            executor)
        run = run_item_chunks(ctx, executor, work, run_scene_chunk, "chunks")
        done = merged(run.results)
        events = {v.scene: e for v, e in zip(done.verdicts, done.events)}

        def draw(row: int, verdict: Any) -> Path | None:
            gif = done.gifs.get(verdict.scene)
            if gif is None:
                return None
            path = ctx.artefact(gif_name(verdict.scene, verdict.identity))
            write_bytes_atomic(path, gif)
            return path

        outcome = self._outcome(config, ctx, done.verdicts, problems, dataset,
                                lambda figures: write_scene_artefacts(ctx, config, done.verdicts, events, figures,
                                                                      draw), done.errors)
        outcome.details["executor"] = executor_details(run, lambda index: repr(work[index]))
        return outcome
