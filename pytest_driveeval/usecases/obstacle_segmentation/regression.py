"""What counts as worse than a baseline for obstacle segmentation: a lower detection or
non-detection pass rate, more points in the non-detection area, and any frame whose verdict went
from Success (or Warn) to Fail, named with its stamp."""
from __future__ import annotations

from pytest_driveeval.baseline.rules import FigureRule
from pytest_driveeval.baseline.units import Units
from pytest_driveeval.core.outcome import Outcome

FIGURES = {
    "detection_rate": FigureRule("higher", atol=1e-9, unit="%"),
    "non_detection_rate": FigureRule("higher", atol=1e-9, unit="%"),
    "max_area_points": FigureRule("lower"),
}
_CODE = {"Success": "S", "Warn": "W", "Fail": "F", None: "-"}
LEGEND = {"S": "Success", "W": "Warn", "F": "Fail", "-": "not judged", "E": "error"}


def frame_units(outcome: Outcome) -> Units | None:
    frames = outcome.details.get("frames") or []
    if not frames or outcome.details.get("search"):
        return None
    ids = [str(f.get("frame")) for f in frames]
    columns = {part: "".join("E" if f.get("error") else _CODE.get(f.get(part), "-") for f in frames)
               for part in ("detection", "non_detection")}
    reasons = {str(f.get("frame")): f"stamp_ns {f.get('stamp_ns')}" + (f", error: {f['error']}" if f.get("error")
                                                                        else "")
               for f in frames if f.get("error") or "Fail" in (f.get("detection"), f.get("non_detection"))}
    return Units("frame", ids, columns, LEGEND, {"detection": "SW-", "non_detection": "S-"}, reasons)
