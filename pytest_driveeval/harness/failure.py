"""How a failed scenario item speaks: one object for the terminal and for summary.json.

A scenario failure shows the scenario's own lines and the numbers that failed,
not a Python traceback (tavern's and pytest's YAML example's way).  The same
text is the ``message`` of the item's record, so a reader of ``summary.json``
sees what the terminal showed.
"""
from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

import pytest

from ..core.errors import DriveEvalError, ScenarioError, display_path
from ..core.outcome import Outcome, format_figure, replaced_model
from ..scenario import Scenario


class ScenarioFailed(DriveEvalError, AssertionError):
    """Raised by a scenario item whose evaluation did not pass.

    An AssertionError too: a scenario's conditions are its assertions, so
    reports that tell a failed check from a broken test (allure) say failed;
    bad input (DataError, ModelError) stays broken.
    """

    def __init__(self, outcome: Outcome, where: str = ""):
        self.outcome = outcome
        self.where = where
        super().__init__(outcome.summary)


def source_line(path: Path, line: int | None) -> str:
    """Line ``line`` of ``path`` as a listing shows it, or "" when it cannot be read."""
    if not line:
        return ""
    try:
        text = path.read_text(encoding="utf-8").splitlines()[line - 1]
    except (OSError, IndexError, UnicodeDecodeError):
        return ""
    return f"    {line:4d} | {text}"


class Crash(NamedTuple):
    """Where and what, as pytest's short summary and JUnit's failure message read it."""

    path: str
    lineno: int
    message: str


class Failure:
    """Why a scenario item failed, located in its scenario file: a report's
    ``longrepr`` (pytest asks it ``toterminal``; xdist and JUnit take ``str``).

    Our errors (:class:`~pytest_driveeval.core.errors.DriveEvalError`) render as
    the scenario, the verdict or error, each finding with the YAML line that
    set its limit, the figures and the artefacts; any other exception as its
    one-line message.
    """

    def __init__(self, scenario: Scenario | None, case_name: str, exc: BaseException):
        self.scenario = scenario
        self.case_name = case_name
        self.exc = exc

    @classmethod
    def of(cls, item: pytest.Item, exc: BaseException) -> "Failure":
        return cls(getattr(item, "driveeval_scenario", None), item.name, exc)

    def lines(self) -> list[str]:
        exc, scenario = self.exc, self.scenario
        if not isinstance(exc, DriveEvalError):
            return [f"{type(exc).__name__}: {exc}".strip()]
        if isinstance(exc, ScenarioError) or scenario is None:
            return str(exc).splitlines() or [""]
        lines = [f"scenario '{scenario.name}' ({self.case_name}) in {display_path(scenario.path)}"]
        outcome = getattr(exc, "outcome", None)
        if isinstance(exc, ScenarioFailed):
            lines.append(f"  {outcome.verdict.upper()}: {outcome.summary}")
        else:
            lines.append(f"  {type(exc).__name__}: {exc}")
        model = replaced_model(outcome.details) if outcome is not None else None
        if model:
            lines.append(f"  {model}")
        if outcome is not None:
            lines += self._outcome_lines(outcome)
        return lines

    def _outcome_lines(self, outcome: Outcome) -> list[str]:
        scenario = self.scenario
        lines = []
        for finding in outcome.findings:
            line = scenario.source.line_of(finding.keypath) if finding.keypath else None
            lines.append(f"  - {finding.message}" + (f" ({scenario.path.name}:{line})" if line else ""))
            shown = source_line(scenario.path, line)
            if shown:
                lines.append(shown)
        if outcome.figures:
            lines.append("  figures: " + ", ".join(f"{k}={format_figure(v)}" for k, v in outcome.figures.items()))
        lines += [f"  artefact {name}: {path}" for name, path in outcome.artefacts.items()]
        replay = (outcome.details.get("search") or {}).get("replay")
        if replay:
            # Last and alone on its line, so that it pastes into a shell as it is.
            lines += ["  replay this case:", f"    {replay}"]
        return lines

    def __str__(self) -> str:
        return "\n".join(self.lines())

    @property
    def reprcrash(self) -> Crash:
        # The whole text, as pytest takes a plain-text longrepr: the short summary
        # trims it to its first line, JUnit keeps it all.
        path = str(self.scenario.path) if self.scenario is not None else ""
        return Crash(path, 0, str(self))

    def toterminal(self, tw) -> None:
        for line in self.lines():
            tw.line(line)

    def to_json(self) -> dict:
        """The failure's part of the item's record in summary.json."""
        return {"message": str(self)}
