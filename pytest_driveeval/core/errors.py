"""Errors a user can act on.

Every error here is about the user's input (a scenario file, a dataset, a model),
not about our code, so pytest shows its message and no Python traceback.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence


def format_keypath(keypath: Sequence[Any]) -> str:
    out = ""
    for part in keypath:
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            out += f".{part}" if out else str(part)
    return out


def display_path(path: Path | str) -> str:
    """A path as people read it in a log: relative to the working directory when inside it."""
    path = Path(path)
    try:
        return path.absolute().relative_to(Path.cwd().resolve()).as_posix()
    except (ValueError, OSError):
        return str(path)


class DriveEvalError(Exception):
    """Base of the errors that are reported without a traceback.

    ``outcome`` may carry what was computed before the error, so it still
    reaches the reports.
    """

    outcome: Any = None


@dataclass(frozen=True)
class Problem:
    """One thing wrong in a scenario file, located by line and key path."""

    message: str
    line: int | None = None
    keypath: tuple = ()

    def render(self, path: Path | str) -> str:
        path = display_path(path)
        where = f"{path}:{self.line}" if self.line else f"{path}"
        key = format_keypath(self.keypath)
        return f"{where}: {key}: {self.message}" if key else f"{where}: {self.message}"


class ScenarioError(DriveEvalError):
    """A scenario file that cannot be loaded: one or more located problems."""

    def __init__(self, path: Path | str, problems: Sequence[Problem]):
        self.path = Path(path)
        self.problems = list(problems)
        super().__init__(self.render())

    @property
    def line(self) -> int | None:
        return self.problems[0].line if self.problems else None

    def render(self) -> str:
        head = f"invalid scenario file {display_path(self.path)}"
        if len(self.problems) > 1:
            head += f" ({len(self.problems)} problems)"
        return "\n".join([head + ":"] + ["  " + p.render(self.path) for p in self.problems])


class DataError(DriveEvalError):
    """A dataset that is missing, corrupt or inconsistent."""


class ModelError(DriveEvalError):
    """A model that cannot be loaded, raises, or returns something unusable."""
