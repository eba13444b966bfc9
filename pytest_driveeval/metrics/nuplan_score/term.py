"""One term of nuPlan's score as the harness reports it."""
from __future__ import annotations

from dataclasses import dataclass, field

#: the score's multipliers and its weighted terms with their weights (nuplan-devkit's aggregator config)
MULTIPLIERS = ("no_ego_at_fault_collisions", "drivable_area_compliance", "ego_is_making_progress",
               "driving_direction_compliance")
WEIGHTS = {"ego_progress_along_expert_route": 5.0, "time_to_collision_within_bound": 5.0,
           "speed_limit_compliance": 4.0, "ego_is_comfortable": 2.0}
TERMS = MULTIPLIERS + tuple(WEIGHTS)


@dataclass
class Term:
    """``value``: the term's own figure, None where the scene lacks what it needs (``reason`` says what);
    ``used``: what the score multiplies or weighs (None: left out, as nuPlan leaves out a metric it has
    no value for; a value where nuPlan's own rule for the missing data gives one, and ``reason`` says so).
    ``frames``: rows of the scene's frames where it failed, ``places`` (x, y) there, ``message`` why."""

    name: str
    value: float | None
    used: float | None = None
    reason: str | None = None
    frames: list[int] = field(default_factory=list)
    places: list[tuple[float, float]] = field(default_factory=list)
    message: str | None = None
    detail: dict = field(default_factory=dict)
    #: per-frame measures behind it (e.g. each frame's time to collision), for drawing and checking
    series: dict = field(default_factory=dict)

    def __post_init__(self):
        if self.used is None and self.value is not None:
            self.used = self.value

    @property
    def available(self) -> bool:
        return self.value is not None

    @classmethod
    def not_available(cls, name: str, reason: str, used: float | None = None) -> "Term":
        return cls(name, None, used, reason)
