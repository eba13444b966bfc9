"""A scenario file once loaded: what the pytest side and the use cases read of it.

Plain data (the use case it names is ``usecase.usecase_of(scenario)``), so that the use-case API can
name these types without importing the loader, which imports the use-case registry.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .envelope import XFailSpec
from .source import SourceMap

__all__ = ["DatasetRef", "Scenario"]


@dataclass(frozen=True)
class DatasetRef:
    name: str
    path: Path
    options: dict[str, Any]
    line: int | None


@dataclass
class Scenario:
    path: Path
    name: str
    description: str
    use_case: str
    format_version: str
    datasets: list[DatasetRef]
    config: Any
    raw: dict
    source: SourceMap
    marks: list[str] = field(default_factory=list)
    skip: str | None = None
    xfail: XFailSpec | None = None
    time_limit: float | None = None
    regression: Any = None  # baseline.rules.RegressionSpec

    @property
    def folder(self) -> Path:
        return self.path.parent

    def line_of(self, *keypath: Any) -> int | None:
        return self.source.line_of(keypath)

    def resolve(self, relative: str | os.PathLike) -> Path:
        """A path written in the scenario, relative to the scenario's folder."""
        return (self.folder / os.path.expandvars(os.path.expanduser(str(relative)))).resolve()
