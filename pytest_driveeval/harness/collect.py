"""Scenario files become pytest items.

Items are ``pytest.Function`` objects so they request fixtures like any test
(and a conftest.py can override them); their marks come from the YAML, and a
failure shows the scenario's lines and figures instead of a traceback.
"""
from __future__ import annotations

import fnmatch
import warnings
from pathlib import Path
from typing import Iterable

import pytest

from ..core.errors import DriveEvalError, Problem, ScenarioError, display_path
from .failure import Failure, ScenarioFailed
from ..scenario import NotAScenario, Scenario, load_scenario
from .settings import DECLARED_SUFFIXES, get_settings
from ..core.usecase import Case, usecase_of


#: config.stash: scenario file -> the names of the items it collected in this process, so that the
#: session's end (baselines of items that no longer exist) need not load every file again
_COLLECTED = pytest.StashKey["dict[Path, set[str]]"]()


def is_scenario_file(path: Path, patterns: Iterable[str]) -> bool:
    return any(fnmatch.fnmatch(path.name, pattern) for pattern in patterns)


def broken_scenario_links(folder: Path, patterns: Iterable[str]) -> list[Path]:
    """Scenario-named symlinks that lead nowhere (dangling or a loop): pytest
    walks past them as neither file nor folder, so a scenario would vanish
    from the run without a word."""
    try:
        entries = sorted(folder.iterdir())
    except OSError:
        return []
    return [p for p in entries if p.is_symlink() and is_scenario_file(p, patterns) and not p.exists()]


def _marks(scenario: Scenario) -> list[pytest.MarkDecorator]:
    """The scenario's marks.  A mark the project did not register is pytest's warning (an error under
    --strict-markers) as ever, but located at its line of the YAML file, not in this module."""
    marks, unregistered = [], []
    for index, name in enumerate(scenario.marks):
        line = scenario.line_of("Marks", index)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", pytest.PytestUnknownMarkWarning)
            try:
                marks.append(getattr(pytest.mark, name))
            except pytest.fail.Exception:  # --strict-markers
                unregistered.append(Problem(f"mark '{name}' is not registered, and --strict-markers is on: "
                                            f"{_REGISTER}", line, ("Marks", index)))
        for warning in caught:
            if issubclass(warning.category, pytest.PytestUnknownMarkWarning):
                warnings.warn_explicit(pytest.PytestUnknownMarkWarning(
                    f"unknown mark '{name}' in Marks, a typo or not registered: {_REGISTER}"),
                    pytest.PytestUnknownMarkWarning, display_path(scenario.path), line or 1)
            else:
                warnings.warn_explicit(warning.message, warning.category, warning.filename, warning.lineno)
    if unregistered:
        raise ScenarioError(scenario.path, unregistered)
    if scenario.skip:
        marks.append(pytest.mark.skip(reason=scenario.skip))
    if scenario.xfail is not None:
        marks.append(pytest.mark.xfail(reason=scenario.xfail.Reason, strict=scenario.xfail.Strict,
                                       raises=ScenarioFailed))
    return marks


_REGISTER = ("register it under 'markers' in pytest.ini (or [tool.pytest.ini_options] in pyproject.toml), "
             "or remove it; https://docs.pytest.org/en/stable/how-to/mark.html")


def _scenario_function(scenario: Scenario, marks: list[pytest.MarkDecorator]) -> object:
    # A fresh function per item: pytest reads its marks from ``pytestmark`` and
    # its fixtures from the signature plus ``usefixtures``.
    def scenario_test(driveeval_run, driveeval_baseline):
        __tracebackhide__ = True
        outcome = driveeval_run()
        # A regression fails the item even where its own verdict was expected to fail (an XFail's
        # raises= names ScenarioFailed only); its verdict stays in the message beside it.
        driveeval_baseline.gate(outcome)
        if not outcome.passed:
            raise ScenarioFailed(outcome)

    scenario_test.pytestmark = [m.mark for m in marks]
    usecase = usecase_of(scenario)
    if usecase.fixtures:
        scenario_test.pytestmark.append(pytest.mark.usefixtures(*usecase.fixtures).mark)
    return scenario_test


def _match_the_cache(item: pytest.Item) -> None:
    """Give ``item`` the structured id pytest derives from its string id.

    pytest 9.2 keeps node ids structured and reads the ids it cached (--lf, --ff, --sw) back by
    parsing their strings, where ``speed_limit[fast.csv]`` is the name ``speed_limit`` with the
    parameters ``fast.csv``; a Function made without parametrize keeps the bracket in its name,
    so no cached id ever equalled a scenario item and --lf silently reran everything
    (pytest-dev/pytest#15045).  The string id does not change; older pytest has no structured id.
    """
    structured = getattr(item, "_id", None)
    parse = getattr(type(structured), "parse", None)
    if parse is not None:
        item._id = parse(item.nodeid)


class ScenarioItem(pytest.Function):
    def __init__(self, *, scenario: Scenario, case: Case, **kwargs):
        self.driveeval_scenario = scenario
        self.driveeval_case = case
        super().__init__(**kwargs)
        _match_the_cache(self)
        # -k selects by what the id shows (the folders, the file name, the use case and the dataset
        # or policy in brackets) and by the marks; not by the ScenarioName or description, free text
        # that names other items' policies or places ("highway-gnn-vs-mlp" would give -k gnn the mlp).
        self.extra_keyword_matches.add(scenario.use_case)

    def repr_failure(self, excinfo):  # pytest.Function's own takes no style
        # Our errors are reported as the located Failure (results.annotate_report puts it in the
        # report in every phase); pytest's traceback of them, which reads and parses the source of
        # every frame, would be rendered only to be replaced.
        if isinstance(excinfo.value, DriveEvalError):
            return Failure.of(self, excinfo.value)
        return super().repr_failure(excinfo)

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

    def repr_failure(self, excinfo, style=None):
        # As ScenarioItem.repr_failure: the located problems, not a traceback to be replaced.
        if isinstance(excinfo.value, DriveEvalError):
            return Failure.of(self, excinfo.value)
        return super().repr_failure(excinfo, style=style)

    def reportinfo(self):
        return self.path, (self.error.line or 1) - 1, "invalid scenario"


class ScenarioFile(pytest.File):
    def collect(self):
        settings = get_settings(self.config)
        try:
            scenario = load_scenario(self.path, data_root=settings.data_root,
                                     envelope_optional=not self.path.name.endswith(DECLARED_SUFFIXES))
            cases = usecase_of(scenario).cases(scenario)
            marks = _marks(scenario)
        except NotAScenario:
            return
        except (ScenarioError, MemoryError) as caught:
            # MemoryError: a size the checks at load time did not foresee; this file fails, the others
            # still collect.
            error = caught if isinstance(caught, ScenarioError) else ScenarioError(self.path, [Problem(
                "loading it ran out of memory (MemoryError): a size in it is too large for this machine")])
            yield InvalidScenarioItem.from_parent(self, name="scenario", error=error)
            return
        seen: set[str] = set()
        for case in cases:
            if case.name in seen:  # ids must be unique for xdist and -k
                continue
            seen.add(case.name)
            yield ScenarioItem.from_parent(
                self, name=case.name, callobj=_scenario_function(scenario, marks), scenario=scenario, case=case,
            )
        self.config.stash.setdefault(_COLLECTED, {})[self.path] = seen


def scenario_item_names(path: Path, config: pytest.Config) -> set[str] | None:
    """The names of the items ``path`` collects as now, or None when it is not a scenario file that
    loads (a baseline of such a file is kept: it may load again)."""
    settings = get_settings(config)
    if not is_scenario_file(path, settings.patterns):
        return None
    # Collected here before -k or -m deselected any (an xdist controller collects nothing: it loads)
    collected = config.stash.get(_COLLECTED, {}).get(path)
    if collected is not None:
        return set(collected)
    try:
        scenario = load_scenario(path, data_root=settings.data_root,
                                 envelope_optional=not path.name.endswith(DECLARED_SUFFIXES))
        return {case.name for case in usecase_of(scenario).cases(scenario)}
    except (NotAScenario, ScenarioError, MemoryError, LookupError):
        return None
