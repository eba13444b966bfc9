"""The ``Perturbation`` section of a scenario, common to every use case that searches.

    Perturbation:
      Lateral: [-3.0, 3.0]      # ranges: the use case's own keys, each containing its no-change value
      Heading: [-0.2, 0.2]
      Examples: 200             # examples to try (--driveeval-search-examples wins)
      Batch: 32                 # examples evaluated together
      Tolerance: 0.01           # the reported perturbation is this close to the edge of failure,
                                # as a fraction of each range
      Replay: {Scene: 0, Lateral: 1.734}   # evaluate exactly this case instead of searching

A use case subclasses :class:`SearchSpec` with its range keys; their
CamelCase names map to the perturbation's fields (``SpeedScale`` ->
``speed_scale``).
"""
from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

from pydantic import BaseModel, ConfigDict, Field, PositiveInt, model_validator

__all__ = ["SearchOptions", "SearchSpec", "field_name", "key_name", "parse_replay"]


def field_name(key: str) -> str:
    """``AgentsSpeedScale`` -> ``agents_speed_scale``."""
    return re.sub(r"(?<!^)(?=[A-Z])", "_", key).lower()


def key_name(field: str) -> str:
    """``agents_speed_scale`` -> ``AgentsSpeedScale``."""
    return "".join(part.capitalize() for part in field.split("_"))


@dataclass(frozen=True)
class SearchOptions:
    """What the person running pytest set for every search of the session."""

    examples: int | None = None      # --driveeval-search-examples
    replay: str | None = None        # --driveeval-replay 'scene=0,lateral=1.73'
    profile: str = "default"         # "ci": derandomised, no example database
    database: Path | None = None     # folder of the example database
    seed: int = 0                    # the session's --driveeval-seed, which a replay must repeat


class SearchSpec(BaseModel):
    model_config = ConfigDict(extra="forbid")

    #: keys of the subclass that are ranges, with their no-change value
    NEUTRAL: ClassVar[dict[str, float]] = {}

    Examples: PositiveInt = 100
    Batch: PositiveInt = Field(32, le=4096)
    Tolerance: float = Field(0.01, gt=0.0, lt=0.5)
    Replay: dict[str, float] | None = None

    @model_validator(mode="before")
    @classmethod
    def _ranges_hold_no_change(cls, data: Any):
        if not isinstance(data, dict):
            return data
        for key, neutral in cls.NEUTRAL.items():
            bounds = data.get(key)
            if bounds is None:
                continue
            if isinstance(bounds, (int, float)) and not isinstance(bounds, bool):
                bounds = [bounds, bounds]
            if not isinstance(bounds, (list, tuple)) or len(bounds) != 2 or not all(
                    isinstance(b, (int, float)) and not isinstance(b, bool) for b in bounds):
                raise ValueError(f"{key}: a range [low, high] is needed, got {bounds!r}")
            low, high = sorted(float(b) for b in bounds)
            if not low <= neutral <= high:
                raise ValueError(f"{key}: the range [{low:g}, {high:g}] must contain {neutral:g} (no change), "
                                 "which is what a failure shrinks towards")
        return data

    def ranges(self) -> dict[str, tuple[float, float]]:
        """{field name: (low, high)} of the ranges given."""
        out = {}
        for key in self.NEUTRAL:
            bounds = getattr(self, key, None)
            if bounds is not None:
                low, high = sorted(float(b) for b in bounds)
                out[field_name(key)] = (low, high)
        return out

    def widths(self) -> dict[str, float]:
        return {name: high - low for name, (low, high) in self.ranges().items()}


def parse_replay(text: str) -> dict[str, float]:
    """``scene=0,lateral=1.734`` (the option's form) -> {"scene": 0.0, "lateral": 1.734}."""
    out: dict[str, float] = {}
    for part in filter(None, (p.strip() for p in text.split(","))):
        name, sep, value = part.partition("=")
        if not sep:
            raise ValueError(f"'{part}' is not name=value")
        try:
            out[field_name(name.strip()) if name.strip()[:1].isupper() else name.strip()] = float(value)
        except ValueError:
            raise ValueError(f"'{part}': {value!r} is not a number") from None
    return out
