"""What an evaluation produces: a verdict, a one-line summary, figures, artefacts."""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any


PASSED = "passed"
FAILED = "failed"
#: attribute of a pytest item holding the Outcome of its evaluation
OUTCOME_ATTR = "driveeval_outcome"


@dataclass
class Finding:
    """Why a verdict is what it is, located as precisely as the evaluation can."""

    message: str
    figure: str | None = None
    value: float | None = None
    limit: float | None = None
    frame: int | None = None
    scene: int | str | None = None
    keypath: tuple = ()  # the scenario key that set the limit, for its line

    def to_json(self) -> dict:
        out = {"message": self.message}
        for key in ("figure", "value", "limit", "frame", "scene"):
            value = getattr(self, key)
            if value is not None:
                out[key] = jsonable(value)
        if self.keypath:
            out["keypath"] = list(self.keypath)
        return out


@dataclass
class Outcome:
    use_case: str
    verdict: str
    summary: str
    figures: dict[str, Any] = field(default_factory=dict)
    findings: list[Finding] = field(default_factory=list)
    artefacts: dict[str, Path] = field(default_factory=dict)
    details: dict[str, Any] = field(default_factory=dict)
    scenario: str | None = None  # filled in by the harness: "<ScenarioName> [<item>]"

    @property
    def passed(self) -> bool:
        return self.verdict == PASSED

    def to_json(self, relative_to: Path | None = None) -> dict:
        def rel(path: Path) -> str:
            if relative_to is not None:
                try:
                    return Path(path).resolve().relative_to(relative_to.resolve()).as_posix()
                except ValueError:
                    pass
            return str(path)

        return {
            "use_case": self.use_case,
            "verdict": self.verdict,
            "summary": self.summary,
            "figures": {k: jsonable(v) for k, v in self.figures.items()},
            "findings": [f.to_json() for f in self.findings],
            "artefacts": {k: rel(v) for k, v in self.artefacts.items()},
            "details": jsonable(self.details),
        }


def replaced_model(details: dict[str, Any]) -> str | None:
    """How every report says that another model than the scenario's own ran (``details["model"]``:
    --driveeval-model, a conftest.py fixture), or None."""
    origin = details.get("model")
    return f"model: {origin}, not the scenario's own" if origin else None


def jsonable(value: Any) -> Any:
    """Plain JSON values; numpy scalars and arrays included, NaN as null."""
    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [jsonable(v) for v in value]
    if hasattr(value, "tolist"):
        return jsonable(value.tolist())
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, Path):
        return str(value)
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    return str(value)


def is_number(value: Any) -> bool:
    """A finite int or float (not a bool): a figure that can be compared or plotted."""
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def plain(value: Any) -> Any:
    """A numpy scalar as the Python scalar it holds (np.float64(100.0) -> 100.0), anything else as it is:
    reports that show a value's repr (allure's parameters) would print the numpy type."""
    if getattr(value, "ndim", None) == 0 and hasattr(value, "item"):
        return value.item()
    return value


def format_figure(value: Any) -> str:
    value = plain(value)
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, float):
        return f"{value:.4g}"
    return str(value)
