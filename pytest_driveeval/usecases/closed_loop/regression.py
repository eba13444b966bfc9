"""What counts as worse than a baseline in closed loop: more at-fault collision frames or drift
resets, a larger displacement, a lower nuPlan score (the item's mean), and any scene that passed
and fails now (named with the condition and frame that failed it).  Unrolls are deterministic, so figures compare with tolerances only
for float noise."""
from __future__ import annotations

from typing import Any

from pytest_driveeval.baseline.rules import FigureRule
from pytest_driveeval.baseline.units import Units
from pytest_driveeval.core.outcome import Outcome

FIGURES = {
    "at_fault": FigureRule("lower"),
    "drift_resets": FigureRule("lower"),
    "max_displacement": FigureRule("lower", atol=0.01, rtol=0.01, unit="m"),
    "scenes_passed": FigureRule("higher"),
    "score": FigureRule("higher", atol=0.005),
}


def scene_units(outcome: Outcome) -> Units | None:
    scenes: list[dict[str, Any]] = outcome.details.get("scenes") or []
    if not scenes or outcome.details.get("search"):
        return None
    ids = [str(s.get("scene")) for s in scenes]
    codes = "".join("e" if s.get("error") else "p" if s.get("passed") else "f" for s in scenes)
    reasons: dict[str, str] = {}
    for finding in outcome.findings:
        key = str(finding.scene) if finding.scene is not None else None
        if key in ids and key not in reasons:
            where = f" at frame {finding.frame}" if finding.frame is not None else ""
            reasons[key] = f"{finding.figure or 'condition'}{where} ({finding.message})"
    for s in scenes:
        if s.get("error"):
            reasons.setdefault(str(s.get("scene")), f"error: {s['error']}")
    return Units("scene", ids, {"scene": codes}, {"p": "passed", "f": "failed", "e": "error"}, {"scene": "p"},
                 reasons)
