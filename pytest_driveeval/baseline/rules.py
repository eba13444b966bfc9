"""What counts as worse: each use case's defaults, and a scenario's ``Regression`` section.

    Regression:                      # optional, beside Evaluation
      Figures:                       # per key figure of the use case
        max_displacement: {Atol: 0.5, Rtol: 0.05}
        drift_resets: {Ignore: true}
      Confidence: 95                 # % of the paired test of episode rates (default: the
                                     # scenario's Conditions.Confidence, else 95)
      Search: {Tolerance: 0.1, RelativeTolerance: 0.1}
      Units: true                    # a scene or frame that passed and fails now is a regression

A deterministic figure is worse when it moved the wrong way by more than ``Atol + Rtol * |baseline|``;
a rate over seeded episodes when the paired interval of its difference excludes zero; a robustness
search's smallest breaking perturbation when it moved towards zero by more than its tolerance.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Annotated, Literal

from pydantic import Field

from ..core.section import Section

DEFAULT_CONFIDENCE = 95.0
DEFAULT_SEARCH_RELATIVE = 0.1
NonNegative = Annotated[float, Field(ge=0)]


@dataclass(frozen=True)
class FigureRule:
    better: Literal["lower", "higher"]
    atol: float = 0.0
    rtol: float = 0.0
    #: a rate over episodes, tested paired: (units column, the codes that count as the bad end)
    paired: tuple[str, str] | None = None
    unit: str = ""

    def worse_by(self, before: float, after: float) -> float:
        """How far ``after`` is on the worse side of ``before`` (negative: the better side)."""
        return after - before if self.better == "lower" else before - after

    def tolerance(self, before: float) -> float:
        return self.atol + self.rtol * abs(before)


class FigureOverride(Section):
    Atol: float | None = Field(None, ge=0, description=(
        "absolute tolerance: the figure is worse only when it moved the wrong way by more than Atol + Rtol x "
        "|baseline|"))
    Rtol: float | None = Field(None, ge=0, description="relative tolerance (a fraction of the baseline's value)")
    Ignore: bool = Field(False, description="true: this figure is never compared")


class SearchTolerance(Section):
    #: how far (in the perturbation's own unit) the smallest breaking value may move towards zero;
    #: one number for every parameter, or one per parameter
    Tolerance: NonNegative | dict[str, NonNegative] = Field(0.0, description=(
        "how far (in the perturbation's own unit) the smallest breaking value may move towards zero; one number "
        "for every parameter, or one per parameter"))
    RelativeTolerance: float = Field(DEFAULT_SEARCH_RELATIVE, ge=0, description=(
        "the part of the baseline's breaking value it may also move towards zero"))

    def allowed(self, parameter: str, before: float) -> float:
        absolute = self.Tolerance.get(parameter, 0.0) if isinstance(self.Tolerance, dict) else self.Tolerance
        return absolute + self.RelativeTolerance * abs(before)


class RegressionSpec(Section):
    Figures: dict[str, FigureOverride] = Field(default_factory=dict, description=(
        "per key figure of the use case (by its name in the summary), its tolerances or Ignore; a name that is "
        "not one of the use case's figures is an error at its line"))
    Confidence: float | None = Field(None, gt=50, lt=100, description=(
        "% level of the paired test of episode rates; default: the scenario's Conditions.Confidence, else 95"))
    Search: SearchTolerance = Field(default_factory=SearchTolerance, description=(
        "how far a robustness search's smallest breaking perturbation may move towards zero before it is a "
        "regression"))
    Units: bool = Field(True, description=(
        "true: a scene or frame that passed in the baseline and fails now is a regression; false: only the "
        "figures are compared"))


@dataclass(frozen=True)
class Rules:
    figures: dict[str, FigureRule]
    confidence: float
    search: SearchTolerance
    units: bool

    def to_json(self) -> dict:
        return {"figures": {k: {"better": r.better, "atol": r.atol, "rtol": r.rtol,
                                **({"paired": list(r.paired)} if r.paired else {}),
                                **({"unit": r.unit} if r.unit else {})} for k, r in self.figures.items()},
                "confidence": self.confidence, "search": self.search.model_dump(), "units": self.units}

    @classmethod
    def from_json(cls, data: dict) -> "Rules":
        figures = {k: FigureRule(v["better"], float(v.get("atol", 0)), float(v.get("rtol", 0)),
                                 tuple(v["paired"]) if v.get("paired") else None, str(v.get("unit", "")))
                   for k, v in (data.get("figures") or {}).items()}
        return cls(figures, float(data.get("confidence", DEFAULT_CONFIDENCE)),
                   SearchTolerance.model_validate(data.get("search") or {}), bool(data.get("units", True)))


def effective_rules(defaults: dict[str, FigureRule], spec: RegressionSpec | None,
                    confidence: float | None = None) -> Rules:
    """The use case's rules with the scenario's overrides; ``confidence`` is the scenario's own
    Conditions.Confidence, which the Regression section's wins over."""
    spec = spec or RegressionSpec()
    figures = {}
    for name, rule in defaults.items():
        override = spec.Figures.get(name)
        if override is not None and override.Ignore:
            continue
        if override is not None:
            rule = replace(rule, atol=rule.atol if override.Atol is None else override.Atol,
                           rtol=rule.rtol if override.Rtol is None else override.Rtol)
        figures[name] = rule
    return Rules(figures, spec.Confidence or confidence or DEFAULT_CONFIDENCE, spec.Search, spec.Units)
