"""Scenario files become pytest items.

Items are ``pytest.Function`` objects so they request fixtures like any test
(and a conftest.py can override them); their marks come from the YAML, and a
failure shows the scenario's lines and figures instead of a traceback.
"""
from __future__ import annotations

import fnmatch
from pathlib import Path
from typing import Iterable

import pytest

from .errors import DriveEvalError, ScenarioError, display_path
from .outcome import ScenarioFailed, format_figure
from .scenario import Scenario, load_scenario
from .settings import get_settings
from .usecase import Case


def is_scenario_file(path: Path, patterns: Iterable[str]) -> bool:
    return any(fnmatch.fnmatch(path.name, pattern) for pattern in patterns)


def _marks(scenario: Scenario) -> list[pytest.MarkDecorator]:
    marks = [getattr(pytest.mark, name) for name in scenario.marks]
    if scenario.skip:
        marks.append(pytest.mark.skip(reason=scenario.skip))
    if scenario.xfail is not None:
        marks.append(pytest.mark.xfail(reason=scenario.xfail.Reason, strict=scenario.xfail.Strict,
                                       raises=ScenarioFailed))
    return marks


def _scenario_function(scenario: Scenario) -> object:
    # A fresh function per item: pytest reads its marks from ``pytestmark`` and
    # its fixtures from the signature plus ``usefixtures``.
    def scenario_test(driveeval_run):
        __tracebackhide__ = True
        outcome = driveeval_run()
        if not outcome.passed:
            raise ScenarioFailed(outcome)

    scenario_test.pytestmark = [m.mark for m in _marks(scenario)]
    if scenario.usecase.fixtures:
        scenario_test.pytestmark.append(pytest.mark.usefixtures(*scenario.usecase.fixtures).mark)
    return scenario_test


def _source_line(path: Path, line: int | None) -> str:
    if not line:
        return ""
    try:
        text = path.read_text(encoding="utf-8").splitlines()[line - 1]
    except (OSError, IndexError, UnicodeDecodeError):
        return ""
    return f"    {line:4d} | {text}"


def render_failure(scenario: Scenario | None, case_name: str, exc: BaseException) -> str:
    if isinstance(exc, ScenarioError) or scenario is None:
        return str(exc)
    head = f"scenario '{scenario.name}' ({case_name}) in {display_path(scenario.path)}"
    lines = [head]
    outcome = getattr(exc, "outcome", None)
    if isinstance(exc, ScenarioFailed):
        lines.append(f"  {outcome.verdict.upper()}: {outcome.summary}")
    else:
        lines.append(f"  {type(exc).__name__}: {exc}")
    if outcome is not None:
        for finding in outcome.findings:
            where = ""
            if finding.keypath:
                line = scenario.source.line_of(finding.keypath)
                where = f" ({scenario.path.name}:{line})" if line else ""
            lines.append(f"  - {finding.message}{where}")
            shown = _source_line(scenario.path, scenario.source.line_of(finding.keypath)) if finding.keypath else ""
            if shown:
                lines.append(shown)
        if outcome.figures:
            figures = ", ".join(f"{k}={format_figure(v)}" for k, v in outcome.figures.items())
            lines.append(f"  figures: {figures}")
        for name, path in outcome.artefacts.items():
            lines.append(f"  artefact {name}: {path}")
    return "\n".join(lines)


def failure_message(item: pytest.Item, exc: BaseException) -> str:
    """The text a summary shows for a failed item: the located scenario failure
    for our errors, the exception's own line otherwise."""
    if isinstance(exc, DriveEvalError):
        scenario = getattr(item, "driveeval_scenario", None)
        return render_failure(scenario, item.name, exc)
    return f"{type(exc).__name__}: {exc}".strip()


class ScenarioItem(pytest.Function):
    def __init__(self, *, scenario: Scenario, case: Case, **kwargs):
        self.driveeval_scenario = scenario
        self.driveeval_case = case
        super().__init__(**kwargs)
        # -k matches the scenario's name and use case too, not only the id.
        self.extra_keyword_matches.update({scenario.name, scenario.use_case})

    def reportinfo(self):
        line = self.driveeval_scenario.line_of("Evaluation") or 1
        return self.path, line - 1, f"{self.driveeval_scenario.name} [{self.name}]"


class InvalidScenarioItem(pytest.Item):
    """Stands for a file that does not load: it fails with the located problems,
    so the rest of the session still runs and the summary lists it."""

    def __init__(self, *, error: ScenarioError, **kwargs):
        super().__init__(**kwargs)
        self.error = error

    def runtest(self) -> None:
        raise self.error

    def reportinfo(self):
        return self.path, (self.error.line or 1) - 1, "invalid scenario"


class ScenarioFile(pytest.File):
    def collect(self):
        settings = get_settings(self.config)
        try:
            scenario = load_scenario(self.path, data_root=settings.data_root)
            cases = scenario.cases()
        except ScenarioError as error:
            yield InvalidScenarioItem.from_parent(self, name="scenario", error=error)
            return
        seen: set[str] = set()
        for case in cases:
            if case.name in seen:  # ids must be unique for xdist and -k
                continue
            seen.add(case.name)
            yield ScenarioItem.from_parent(
                self, name=case.name, callobj=_scenario_function(scenario), scenario=scenario, case=case,
            )
