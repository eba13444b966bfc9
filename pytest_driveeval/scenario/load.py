"""Loading a scenario file: YAML with lines, the envelope, then the use case's own part.

Envelope and use-case part are validated in one pass, so a file with several
mistakes lists them all at once, each at its line.
"""
from __future__ import annotations

import os
import re
import typing
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from ..core.errors import Problem, ScenarioError
from ..core.usecase import UseCase, get_usecase, known_usecases
from .envelope import DatasetOptions, Envelope, EvaluationHead, XFailSpec
from .loaded import DatasetRef, Scenario
from .problems import did_you_mean, problems_from_validation
from .source import SourceMap, load_yaml_with_lines

SUPPORTED_SCENARIO_FORMATS = ("2", "3")  # major versions of ScenarioFormatVersion
COMMON_EVALUATION_KEYS = ("UseCaseName", "UseCaseFormatVersion", "Datasets")


def _dataset_refs(head: EvaluationHead, path: Path, source: SourceMap, data_root: Path | None) -> list[DatasetRef]:
    refs: list[DatasetRef] = []
    problems: list[Problem] = []
    for index, entry in enumerate(head.Datasets):
        keypath = ("Evaluation", "Datasets", index)
        if len(entry) != 1:
            problems.append(Problem(
                f"each dataset entry is a mapping with one key, the dataset's name; found {len(entry)} keys",
                source.line_of(keypath), keypath))
            continue
        (name, options), = entry.items()
        options = options or DatasetOptions()
        if any(ref.name == name for ref in refs):
            problems.append(Problem(f"dataset '{name}' is listed twice", source.line_of(keypath), keypath))
            continue
        if options.path:
            resolved = path.parent / os.path.expandvars(os.path.expanduser(options.path))
        elif data_root is not None:
            resolved = data_root / name
        else:
            resolved = path.parent / name
        try:
            resolved = resolved.resolve()
        except (RuntimeError, OSError) as exc:  # a symlink loop (RuntimeError before Python 3.13)
            problems.append(Problem(f"dataset '{name}': cannot resolve {resolved}: {exc}",
                                    source.line_of(keypath), keypath))
            continue
        refs.append(DatasetRef(str(name), resolved, options.model_dump(by_alias=True), source.line_of(keypath)))
    if problems:
        raise ScenarioError(path, problems)
    return refs


def _version_problems(data: dict, usecase: UseCase | None, source: SourceMap) -> list[Problem]:
    problems = []
    version = data.get("ScenarioFormatVersion")
    if isinstance(version, str) and version.split(".")[0] not in SUPPORTED_SCENARIO_FORMATS:
        keypath = ("ScenarioFormatVersion",)
        supported = ", ".join(f"{m}.x" for m in SUPPORTED_SCENARIO_FORMATS)
        problems.append(Problem(f"unsupported version '{version}'; supported: {supported}",
                                source.line_of(keypath), keypath))
    evaluation = data.get("Evaluation")
    if not isinstance(evaluation, dict):
        return problems
    name = evaluation.get("UseCaseName")
    use_version = evaluation.get("UseCaseFormatVersion")
    if isinstance(name, str) and usecase is None:
        keypath = ("Evaluation", "UseCaseName")
        problems.append(Problem(f"unknown use case '{name}'; {did_you_mean(name, known_usecases())}",
                                source.line_of(keypath), keypath))
    elif usecase is not None and isinstance(use_version, str) and use_version not in usecase.format_versions:
        keypath = ("Evaluation", "UseCaseFormatVersion")
        problems.append(Problem(
            f"unsupported version '{use_version}' of use case '{name}'; "
            f"supported: {', '.join(usecase.format_versions)}", source.line_of(keypath), keypath))
    return problems


def _regression_problems(figures: dict, usecase: UseCase, source: SourceMap) -> list[Problem]:
    known = sorted(getattr(usecase, "regression_figures", {}))
    problems = []
    for name in figures:
        if name not in known:
            hint = did_you_mean(name, known) if known else f"{usecase.name} compares no figure with a baseline"
            problems.append(Problem(f"'{name}' is not a figure {usecase.name} compares with a baseline; {hint}",
                                    source.line_of(("Regression", "Figures", name)), ("Regression", "Figures", name)))
    return problems


def searched_parameters(usecase: UseCase) -> list[str]:
    """The parameters a use case's robustness search reports (``minimal_<name>`` figures): its
    ``Perturbation`` section's ranges, as the perturbation's fields name them (``SpeedScale`` ->
    ``speed_scale``)."""
    field = usecase.config_model.model_fields.get("Perturbation")
    kinds = (field.annotation, *typing.get_args(field.annotation)) if field is not None else ()
    neutral = next((kind.NEUTRAL for kind in kinds if isinstance(getattr(kind, "NEUTRAL", None), dict)), {})
    return [re.sub(r"(?<!^)(?=[A-Z])", "_", key).lower() for key in neutral]


def _search_tolerance_problems(tolerance: object, usecase: UseCase, source: SourceMap) -> list[Problem]:
    """A per-parameter Regression.Search.Tolerance names parameters the search reports; any other
    name would never apply, and a comparison would use no tolerance for the one meant."""
    if not isinstance(tolerance, dict):
        return []
    known = searched_parameters(usecase)
    problems = []
    for name in tolerance:
        if name not in known:
            keypath = ("Regression", "Search", "Tolerance", name)
            hint = did_you_mean(name, known) if known else f"{usecase.name} has no robustness search"
            problems.append(Problem(f"'{name}' is not a parameter {usecase.name}'s robustness search reports; {hint}",
                                    source.line_of(keypath), keypath))
    return problems


class NotAScenario(Exception):
    """A YAML file without the scenario envelope, where one was optional."""


ENVELOPE_KEYS = ("ScenarioFormatVersion", "Evaluation")


def load_scenario(path: str | os.PathLike, data_root: str | os.PathLike | None = None,
                  envelope_optional: bool = False) -> Scenario:
    """Load and validate a scenario file; raise ScenarioError with every located
    problem.  With ``envelope_optional``, a YAML mapping that has none of the
    envelope's keys raises NotAScenario instead: some other tool's file."""
    given = Path(path)
    try:
        path = given.resolve()
    except (RuntimeError, OSError) as exc:  # a symlink loop (RuntimeError before Python 3.13)
        raise ScenarioError(given, [Problem(f"cannot open the file: {exc}")]) from None
    if given.is_symlink() and not path.exists():
        raise ScenarioError(given, [Problem(f"a symbolic link to {path}, which does not exist")])
    data, source = load_yaml_with_lines(path)
    if envelope_optional and not (isinstance(data, dict) and any(key in data for key in ENVELOPE_KEYS)):
        raise NotAScenario(path)
    if not isinstance(data, dict):
        found = "an empty file" if data is None else f"a {type(data).__name__}"
        raise ScenarioError(path, [Problem(f"expected a mapping at the top level; found {found}", 1)])
    # Envelope and use-case part are checked together, so one run lists every problem.
    problems: list[Problem] = []
    env = None
    try:
        env = Envelope.model_validate(data)
    except ValidationError as exc:
        problems += problems_from_validation(exc, Envelope, data, source)
    evaluation = data.get("Evaluation") if isinstance(data.get("Evaluation"), dict) else {}
    name = evaluation.get("UseCaseName")
    usecase = get_usecase(name) if isinstance(name, str) else None
    problems += _version_problems(data, usecase, source)
    config = None
    if usecase is not None:
        own_part = {k: v for k, v in evaluation.items() if k not in COMMON_EVALUATION_KEYS}
        try:
            config = usecase.config_model.model_validate(
                own_part, context={"version": evaluation.get("UseCaseFormatVersion"), "scenario_dir": path.parent})
        except ValidationError as exc:
            problems += problems_from_validation(exc, usecase.config_model, own_part, source, prefix=("Evaluation",))
    if env is not None and env.Regression is not None and usecase is not None:
        problems += _regression_problems(env.Regression.Figures, usecase, source)
        problems += _search_tolerance_problems(env.Regression.Search.Tolerance, usecase, source)
    if problems:
        raise ScenarioError(path, sorted(problems, key=lambda p: p.line or 0))
    assert env is not None and usecase is not None

    root = Path(data_root).resolve() if data_root else None
    xfail = env.XFail
    if isinstance(xfail, str):
        xfail = XFailSpec(Reason=xfail)
    return Scenario(
        path=path,
        name=env.ScenarioName,
        description=env.ScenarioDescription,
        use_case=env.Evaluation.UseCaseName,
        format_version=env.Evaluation.UseCaseFormatVersion,
        datasets=_dataset_refs(env.Evaluation, path, source, root),
        config=config,
        raw=data,
        source=source,
        marks=list(env.Marks),
        skip=env.Skip,
        xfail=xfail,
        time_limit=env.TimeLimit,
        regression=env.Regression,
    )
