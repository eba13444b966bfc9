"""What a search evaluates and how it compares examples: shared by the engine and its batched shrinking."""
from __future__ import annotations

from dataclasses import dataclass, field, fields
from typing import Any, Callable

__all__ = ["EvaluateMany", "Example", "Verdict", "changed_fields", "rank", "size_of"]


@dataclass(frozen=True)
class Example:
    """One case (a scene, an episode, a frame: an index into the item's cases) under one perturbation."""

    case: int
    perturbation: Any

    def _repr_pretty_(self, printer: Any, cycle: bool) -> None:
        # Hypothesis prints the failing generation as the calls that built it, inlining the source
        # of every lambda of the strategies: seconds for a batch of 32, where the repr takes micro ones.
        printer.text(repr(self))


@dataclass
class Verdict:
    """Whether an example failed, why, and where (``{"scene": 0, "frame": 57}``, ...)."""

    failed: bool
    reason: str = ""
    where: dict[str, Any] = field(default_factory=dict)


EvaluateMany = Callable[[list[Example]], list[Verdict]]


def size_of(perturbation: Any, widths: dict[str, float]) -> float:
    """How far ``perturbation`` is from no change: the sum of its fields'
    distances from their no-change value, each as a fraction of its range."""
    neutral = type(perturbation)()
    return sum(abs(getattr(perturbation, f.name) - getattr(neutral, f.name)) / (widths.get(f.name) or 1.0)
               for f in fields(perturbation))


def changed_fields(perturbation: Any) -> list[str]:
    """The names of ``perturbation``'s fields that differ from no change, in field order."""
    neutral = type(perturbation)()
    return [f.name for f in fields(perturbation) if getattr(perturbation, f.name) != getattr(neutral, f.name)]


def rank(example: Example, widths: dict[str, float]) -> tuple[float, int, int]:
    """The order in which failures are preferred: the smaller perturbation, then the fewer fields
    changed (hypothesis draws offsets of 1e-105, which add nothing to a size), then the lower case."""
    return size_of(example.perturbation, widths), len(changed_fields(example.perturbation)), example.case
