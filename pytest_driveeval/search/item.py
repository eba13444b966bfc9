"""A scenario item that searches: run the search, show the failing case, report both.

A use case that can search hands :func:`run_item` a :class:`Searchable`: its
cases (scenes, episode seeds, frames), a strategy for its perturbations, a
batched ``evaluate_many`` that only judges, and ``show`` that evaluates one
example the way the item normally does, with its pictures.  The item's
outcome is the search's: failed when a perturbation within the ranges breaks
it, with the shrunk and tightened perturbation, where it failed, the search's
statistics and the one-line command that replays exactly that case.
"""
from __future__ import annotations

import shlex
from dataclasses import asdict, dataclass
from typing import Any, Callable

from hypothesis import strategies as st
from hypothesis.database import DirectoryBasedExampleDatabase

from pytest_driveeval.core.errors import DataError
from pytest_driveeval.core.outcome import FAILED, PASSED, Finding, Outcome
from pytest_driveeval.search.engine import EvaluateMany, Example, SearchResult, SearchSettings, database_key, search
from pytest_driveeval.strategies import changed_fields
from pytest_driveeval.search.spec import SearchOptions, SearchSpec, key_name, parse_replay

__all__ = ["SearchOptions", "Searchable", "describe", "replay_text", "run_item"]

KEYPATH = ("Evaluation", "Perturbation")


@dataclass
class Searchable:
    case_name: str                       # "scene", "seed", "frame": what a case is called
    case_labels: list[int]               # each case's scene id / seed / frame number
    perturbation_type: type
    perturbations: st.SearchStrategy     # of perturbation_type, within the scenario's ranges
    evaluate_many: EvaluateMany
    show: Callable[[Example], Outcome]   # judge one example as the item does, with its pictures


def describe(perturbation: Any) -> str:
    """The fields that differ from no change, exactly (``lateral=1.734``)."""
    return ",".join(f"{k}={v!r}" for k, v in changed_fields(perturbation).items()) or "no change"


def replay_text(searchable: Searchable, example: Example) -> str:
    """The --driveeval-replay value of ``example``."""
    label = searchable.case_labels[example.case]
    changed = describe(example.perturbation)
    return f"{searchable.case_name}={label}" + ("" if changed == "no change" else f",{changed}")


def run_item(use_case: str, searchable: Searchable, spec: SearchSpec, ctx: Any) -> Outcome:
    options: SearchOptions = getattr(ctx, "search", None) or SearchOptions()
    replay = options.replay or _replay_from_spec(spec)
    if replay:
        return _replay(use_case, searchable, spec, replay, ctx, from_option=bool(options.replay))
    derandomize = options.profile == "ci"
    database = None
    if not derandomize and options.database is not None:
        database = DirectoryBasedExampleDatabase(str(options.database))
    scenario = ctx.scenario
    dataset = ctx.dataset.path if getattr(ctx, "dataset", None) is not None else ""
    config = SearchSettings(examples=options.examples or spec.Examples, batch=min(spec.Batch, options.examples or
                                                                                   spec.Examples),
                            tolerance=spec.Tolerance, derandomize=derandomize, seed=ctx.seed, database=database,
                            key=database_key(use_case, scenario.path, scenario.name, ctx.case.name, dataset))
    cases = st.integers(0, len(searchable.case_labels) - 1)
    progress_of = getattr(ctx, "progress_of", None)
    result = search(cases, searchable.perturbations, searchable.evaluate_many, spec.ranges(), config,
                    progress=progress_of("examples") if progress_of is not None else None)
    stats = _statistics(result, config, options.profile)
    if not result.found:
        summary = (f"no perturbation within the ranges broke it: {result.examples} examples over "
                   f"{len(searchable.case_labels)} {searchable.case_name}(s) in {result.seconds:.1f} s")
        return Outcome(use_case, PASSED, summary, figures=_figures(result), details={"search": stats})
    example, verdict = result.minimal, result.verdict
    shown = searchable.show(example)
    command = f"pytest {shlex.quote(getattr(ctx, 'nodeid', '') or str(scenario.path))} " \
              f"--driveeval-replay {shlex.quote(replay_text(searchable, example))}" + \
              (f" --driveeval-seed {options.seed}" if options.seed else "")  # random draws of a case use it
    where = ", ".join(f"{k} {v}" for k, v in verdict.where.items())
    message = (f"{describe(example.perturbation)} breaks it ({where}: {verdict.reason}); shrunk from "
               f"{describe(result.shrunk.perturbation)}; {result.examples} examples, {result.failures} failing, "
               f"{result.seconds:.1f} s")
    stats.update(replay=command, shown_verdict=shown.verdict, minimal_text=describe(example.perturbation),
                 shrunk_text=describe(result.shrunk.perturbation))
    findings = [Finding(message, scene=verdict.where.get("scene"), frame=verdict.where.get("frame"),
                        keypath=KEYPATH), *shown.findings]
    summary = f"robustness: {describe(example.perturbation)} breaks it at {where} ({verdict.reason})"
    return Outcome(use_case, FAILED, summary, figures={**_figures(result), **shown.figures}, findings=findings,
                   artefacts=shown.artefacts, details={"search": stats, "failing_case": shown.details})


def _replay_from_spec(spec: SearchSpec) -> str | None:
    if not spec.Replay:
        return None
    return ",".join(f"{k}={v!r}" for k, v in spec.Replay.items())


def _replay(use_case: str, searchable: Searchable, spec: SearchSpec, text: str, ctx: Any,
            from_option: bool) -> Outcome:
    where = "--driveeval-replay" if from_option else f"{ctx.scenario.path}: Evaluation.Perturbation.Replay"
    try:
        values = parse_replay(text)
    except ValueError as exc:
        raise DataError(f"{where}: {exc}") from None
    label = values.pop(searchable.case_name, None)
    if label is None:
        raise DataError(f"{where}: say which {searchable.case_name} to replay ({searchable.case_name}=N)")
    if label not in searchable.case_labels:
        raise DataError(f"{where}: {searchable.case_name} {label:g} is not one of this item's "
                        f"({', '.join(map(str, searchable.case_labels[:20]))})")
    known = set(searchable.perturbation_type.__dataclass_fields__)
    unknown = sorted(set(values) - known)
    if unknown:
        raise DataError(f"{where}: {', '.join(unknown)} not a perturbation of {use_case}; known: "
                        f"{', '.join(sorted(known))} (or as YAML keys: {', '.join(map(key_name, sorted(known)))})")
    for name, value in values.items():
        problem = spec.replay_problem(name, value)
        if problem:
            raise DataError(f"{where}: {name}={value!r}: {problem}")
    kinds = {name: type(getattr(searchable.perturbation_type(), name)) for name in values}
    perturbation = searchable.perturbation_type(**{k: kinds[k](v) for k, v in values.items()})
    example = Example(searchable.case_labels.index(label), perturbation)
    shown = searchable.show(example)
    shown.summary = f"replay of {replay_text(searchable, example)}: {shown.summary}"
    shown.details = {**shown.details, "replay": replay_text(searchable, example)}
    return shown


def _statistics(result: SearchResult, config: SearchSettings, profile: str) -> dict[str, Any]:
    def example_json(example: Example | None):
        return None if example is None else {"case": example.case, "perturbation": asdict(example.perturbation)}

    return {"profile": profile, "examples_asked": config.examples, "batch": config.batch, "examples": result.examples,
            "failures": result.failures, "generations": result.generations, "seconds": round(result.seconds, 3),
            "evaluations": result.evaluations, "replayed_from_database": result.replayed,
            "shrunk": example_json(result.shrunk), "minimal": example_json(result.minimal),
            "edge": result.edges, "reason": result.verdict.reason if result.verdict else None,
            "where": result.verdict.where if result.verdict else None}


def _figures(result: SearchResult) -> dict[str, Any]:
    figures: dict[str, Any] = {"search_examples": result.examples, "search_failures": result.failures,
                               "search_seconds": round(result.seconds, 2)}
    if result.minimal is not None:
        figures.update({f"minimal_{k}": v for k, v in changed_fields(result.minimal.perturbation).items()})
    return figures
