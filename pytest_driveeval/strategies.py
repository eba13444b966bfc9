"""Hypothesis strategies for perturbations that may break a policy or a point-cloud filter.

Every strategy draws a frozen perturbation whose "no change" value is what
hypothesis shrinks towards: offsets towards 0, scale factors towards 1, a
dropout towards none.  So a failing example shrinks to the smallest
perturbation that still fails, which is what a developer needs to reproduce
it.  The same objects are what a scenario's ``Perturbation`` section draws
and what tests written with ``@given`` use:

    @given(start_perturbations(lateral=(-3.0, 3.0)))
    def test_planner_survives_a_shifted_start(perturbation): ...
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields, replace
from typing import Any, Callable, TypeVar

from hypothesis import strategies as st

__all__ = ["CloudPerturbation", "EpisodePerturbation", "StartPerturbation", "changed_fields", "cloud_perturbations",
           "describe",
           "episode_perturbations", "start_perturbations", "tighten"]

Range = tuple[float, float]
P = TypeVar("P")


@dataclass(frozen=True)
class StartPerturbation:
    """A closed-loop or benchmark start moved off the log: the ego's lateral and
    longitudinal offset (m, in its own frame), heading offset (rad), its initial
    speed scaled, and the other agents' speeds scaled."""

    lateral: float = 0.0
    longitudinal: float = 0.0
    heading: float = 0.0
    speed_scale: float = 1.0
    agents_speed_scale: float = 1.0

    def is_identity(self) -> bool:
        return self == type(self)()

    def to_json(self) -> dict[str, float]:
        return asdict(self)


@dataclass(frozen=True)
class EpisodePerturbation(StartPerturbation):
    """A policy-benchmark episode's start perturbed: the ego's start as in
    :class:`StartPerturbation`, and the blueprint's spawn gaps scaled by
    ``gap_scale``.  Traffic density is 1 / gap, so ``gap_scale < 1`` is denser
    traffic and ``gap_scale > 1`` sparser."""

    gap_scale: float = 1.0


@dataclass(frozen=True)
class CloudPerturbation:
    """A point cloud degraded: a fraction of its points dropped, range noise
    (m, standard deviation along each ray), a ghost cluster of points."""

    dropout: float = 0.0
    range_noise: float = 0.0
    ghost_points: int = 0

    def to_json(self) -> dict[str, float]:
        return asdict(self)


def _check(name: str, bounds: Range, neutral: float) -> Range:
    low, high = (float(bounds[0]), float(bounds[1]))
    if not (math.isfinite(low) and math.isfinite(high)):
        raise ValueError(f"{name}: a range of finite numbers is needed, got {bounds}")
    if not low <= neutral <= high:
        # Shrinking aims at the neutral value; a range without it has no "smallest" perturbation.
        raise ValueError(f"{name}: the range {bounds} must contain {neutral:g} (no change)")
    return low, high


def _around(name: str, bounds: Range, neutral: float) -> st.SearchStrategy[float]:
    """Floats in ``bounds`` that shrink towards ``neutral``."""
    low, high = _check(name, bounds, neutral)
    if low == high:
        return st.just(low)
    return st.floats(low - neutral, high - neutral, allow_nan=False, allow_infinity=False).map(
        lambda d: neutral + d)


def _within(kind: type, ranges: dict[str, Range]) -> st.SearchStrategy:
    """``kind`` drawn with each field in its range, shrinking towards the field's default (no change)."""
    return st.builds(kind, **{f.name: _around(f.name, ranges[f.name], f.default) for f in fields(kind)})


def start_perturbations(lateral: Range = (0.0, 0.0), longitudinal: Range = (0.0, 0.0), heading: Range = (0.0, 0.0),
                        speed_scale: Range = (1.0, 1.0), agents_speed_scale: Range = (1.0, 1.0)
                        ) -> st.SearchStrategy[StartPerturbation]:
    """Start perturbations within the ranges (each must contain its no-change value)."""
    return _within(StartPerturbation, dict(lateral=lateral, longitudinal=longitudinal, heading=heading,
                                           speed_scale=speed_scale, agents_speed_scale=agents_speed_scale))


def episode_perturbations(lateral: Range = (0.0, 0.0), longitudinal: Range = (0.0, 0.0),
                          heading: Range = (0.0, 0.0), speed_scale: Range = (1.0, 1.0),
                          agents_speed_scale: Range = (1.0, 1.0), gap_scale: Range = (1.0, 1.0)
                          ) -> st.SearchStrategy[EpisodePerturbation]:
    """Episode perturbations within the ranges (each must contain its no-change value)."""
    return _within(EpisodePerturbation, dict(lateral=lateral, longitudinal=longitudinal, heading=heading,
                                             speed_scale=speed_scale, agents_speed_scale=agents_speed_scale,
                                             gap_scale=gap_scale))


def cloud_perturbations(dropout: Range = (0.0, 0.0), range_noise: Range = (0.0, 0.0),
                        ghost_points: tuple[int, int] = (0, 0)) -> st.SearchStrategy[CloudPerturbation]:
    if not 0.0 <= dropout[0] <= dropout[1] <= 1.0:
        raise ValueError(f"dropout: a fraction range within [0, 1] is needed, got {dropout}")
    if range_noise[0] < 0 or ghost_points[0] < 0:
        raise ValueError("range_noise and ghost_points cannot be negative")
    return st.builds(CloudPerturbation, dropout=_around("dropout", dropout, 0.0),
                     range_noise=_around("range_noise", range_noise, 0.0),
                     ghost_points=st.integers(*_int_range("ghost_points", ghost_points)))


def _int_range(name: str, bounds: tuple[int, int]) -> tuple[int, int]:
    low, high = int(bounds[0]), int(bounds[1])
    _check(name, (low, high), 0)
    return low, high


def changed_fields(perturbation: Any) -> dict[str, Any]:
    """The fields of ``perturbation`` that differ from no change, in field order."""
    neutral = type(perturbation)()
    return {k: v for k, v in asdict(perturbation).items() if v != getattr(neutral, k)}


def describe(perturbation: Any) -> str:
    """``lateral=1.25, heading=-0.05``: the fields that differ from no change, for messages."""
    return ", ".join(f"{k}={v:.4g}" for k, v in changed_fields(perturbation).items()) or "no perturbation"


def tighten(perturbation: P, fails: Callable[[P], bool], tolerance: float = 1e-3) -> P:
    """The failing ``perturbation`` moved as close to no change as it still fails.

    Hypothesis shrinks a float to a simple value (2.0, 0.5), not to the edge of
    failure; bisecting each changed field towards its no-change value, one at a
    time, finds that edge to within ``tolerance`` at about log2(range /
    tolerance) evaluations per field.  A field whose no-change value still
    fails is reset to it.
    """
    neutral = type(perturbation)()
    current = perturbation
    for name, value in asdict(perturbation).items():
        base = getattr(neutral, name)
        if value == base:
            continue
        if fails(replace(current, **{name: base})):
            current = replace(current, **{name: base})
            continue
        integral = isinstance(value, int)
        passing, failing = base, value
        while abs(failing - passing) > (1 if integral else tolerance):
            middle = (passing + failing) // 2 if integral else (passing + failing) / 2
            if fails(replace(current, **{name: middle})):
                failing = middle
            else:
                passing = middle
        current = replace(current, **{name: failing})
    return current
