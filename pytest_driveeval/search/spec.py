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

import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

from pydantic import BaseModel, ConfigDict, Field, PositiveInt, model_validator

from pytest_driveeval.core.usecase import located_error

__all__ = ["SearchOptions", "SearchSpec", "StartSearchSpec", "field_name", "key_name", "parse_replay"]


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
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    #: keys of the subclass that are ranges, with their no-change value
    NEUTRAL: ClassVar[dict[str, float]] = {}
    #: keys whose values are bounded: (lowest, highest, what to say when a range leaves them)
    BOUNDS: ClassVar[dict[str, tuple[float, float, str]]] = {}
    #: keys whose values are whole numbers (a count of points, say)
    WHOLE: ClassVar[frozenset[str]] = frozenset()

    Examples: PositiveInt = Field(100, description="examples the search tries (--driveeval-search-examples wins)")
    Batch: PositiveInt = Field(32, le=4096, description=(
        "examples evaluated together: one unroll of that many scenes, or one batch of episodes or clouds"))
    Tolerance: float = Field(0.01, gt=0.0, lt=0.5, description=(
        "the reported perturbation is within this fraction of each range of the edge of failure"))
    Replay: dict[str, float] | None = Field(None, description=(
        "evaluate exactly this case instead of searching, e.g. {Scene: 0, Lateral: 1.734} (as --driveeval-replay "
        "does)"))

    @model_validator(mode="before")
    @classmethod
    def _ranges_hold_no_change(cls, data: Any):
        """Each range is a [low, high] pair within the key's bounds holding its no-change value;
        a bad one is reported at its own key, so at its own YAML line."""
        if not isinstance(data, dict):
            return data
        for key, neutral in cls.NEUTRAL.items():
            given = data.get(key)
            if given is None:
                continue
            bounds = [given, given] if _number(given) else given
            if not isinstance(bounds, (list, tuple)) or len(bounds) != 2 or not all(map(_number, bounds)):
                raise located_error(key, given, f"a range [low, high] is needed, got {given!r}")
            if not all(math.isfinite(b) for b in bounds):
                raise located_error(key, given, f"a range of finite numbers is needed, got {given!r}: the "
                                                "search draws from it and the simulator takes what it draws")
            low, high = sorted(float(b) for b in bounds)
            if not low <= neutral <= high:
                raise located_error(key, given, f"the range [{low:g}, {high:g}] must contain {neutral:g} (no change), "
                                           "which is what a failure shrinks towards")
            lowest, highest, what = cls.BOUNDS.get(key, (-math.inf, math.inf, ""))
            if low < lowest or high > highest:
                raise located_error(key, given, f"{what}, got [{low:g}, {high:g}]")
        return data

    @model_validator(mode="after")
    def _replay_within_the_ranges(self):
        for key, value in (self.Replay or {}).items():
            problem = self.replay_problem(field_name(key), value)
            if problem:
                raise located_error(("Replay", key), value, f"{problem}; got {value!r}")
        return self

    def replay_problem(self, field: str, value: float) -> str | None:
        """Why ``value`` of perturbation ``field`` cannot be replayed, or None.  The rules of a range:
        finite, within the scenario's range for a key it searches, else (a what-if the search
        did not try) within the key's bounds."""
        key = key_name(field)
        if key not in self.NEUTRAL:
            return None  # a case label (scene, seed) or a field the use case itself checks
        if not math.isfinite(value):
            return "a finite number is needed"
        if key in self.WHOLE and value != int(value):
            return "a whole number is needed"
        searched = self.ranges().get(field)
        if searched is not None:
            low, high = searched
            # A drawn value is neutral + offset in floats, so an edge can come out an ulp past the range.
            slack = 1e-9 * max(1.0, abs(low), abs(high))
            if not low - slack <= value <= high + slack:
                return f"outside the scenario's range {key}: [{low:g}, {high:g}]"
            return None
        lowest, highest, what = self.BOUNDS.get(key, (-math.inf, math.inf, ""))
        if not lowest <= value <= highest:
            return what
        return None

    @model_validator(mode="after")
    def _something_to_search(self):
        if not self.ranges() and self.Replay is None:
            raise ValueError(f"give at least one range to search ({', '.join(self.NEUTRAL)})")
        return self

    def ranges(self) -> dict[str, tuple[float, float]]:
        """{field name: (low, high)} of the ranges given."""
        out = {}
        for key in self.NEUTRAL:
            bounds = getattr(self, key, None)
            if bounds is not None:
                low, high = sorted(float(b) for b in bounds)
                out[field_name(key)] = (low, high)
        return out


Range = tuple[float, float] | None
_POSITIVE_SCALE = (1e-3, math.inf, "a speed scale must stay above 0")


class StartSearchSpec(SearchSpec):
    """Ranges of a start moved off its log or lane (strategies.StartPerturbation):
    ``Lateral``, ``Longitudinal`` (m, in the ego's frame), ``Heading`` (rad),
    ``SpeedScale`` (the ego's), ``AgentsSpeedScale`` (the others')."""

    NEUTRAL: ClassVar[dict[str, float]] = {"Lateral": 0.0, "Longitudinal": 0.0, "Heading": 0.0, "SpeedScale": 1.0,
                                           "AgentsSpeedScale": 1.0}
    BOUNDS: ClassVar[dict[str, tuple[float, float, str]]] = {"SpeedScale": _POSITIVE_SCALE,
                                                             "AgentsSpeedScale": _POSITIVE_SCALE}

    Lateral: Range = Field(None, description=(
        "[low, high] m: the start moved sideways, in the ego's frame; the range holds 0"))
    Longitudinal: Range = Field(None, description=(
        "[low, high] m: the start moved along the ego's heading; the range holds 0"))
    Heading: Range = Field(None, description="[low, high] rad: the start's heading turned; the range holds 0")
    SpeedScale: Range = Field(None, description=(
        "[low, high]: the ego's past speeds, so its initial speed, scaled; the range holds 1"))
    AgentsSpeedScale: Range = Field(None, description=(
        "[low, high]: the other agents replayed (or started) faster or slower; the range holds 1"))


def _number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def parse_replay(text: str) -> dict[str, float]:
    """``scene=0,lateral=1.734`` (the option's form) -> {"scene": 0.0, "lateral": 1.734}."""
    out: dict[str, float] = {}
    for part in filter(None, (p.strip() for p in text.split(","))):
        name, sep, value = part.partition("=")
        if not sep:
            raise ValueError(f"'{part}' is not name=value")
        try:
            number = float(value)
        except ValueError:
            raise ValueError(f"'{part}': {value!r} is not a number") from None
        if not math.isfinite(number):
            raise ValueError(f"'{part}': a finite number is needed")
        out[field_name(name.strip()) if name.strip()[:1].isupper() else name.strip()] = number
    return out
