"""Assertion helpers for scenario tests written in Python.

Registered for assertion rewriting (see ``__init__``); each hides its own frame
so a failure points at the test, and its message names the scenario, the
frame and the figure.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from .outcome import Outcome, format_figure
from .verdict import within


def _scenario_prefix(outcome_or_name: Outcome | str | None) -> str:
    name = outcome_or_name.scenario if isinstance(outcome_or_name, Outcome) else outcome_or_name
    return f"scenario '{name}': " if name else ""


def assert_passed(outcome: Outcome) -> None:
    """The evaluation's own verdict is 'passed'; otherwise list its findings."""
    __tracebackhide__ = True
    if not outcome.passed:
        reasons = "\n".join(f"  - {f.message}" for f in outcome.findings) or f"  {outcome.summary}"
        raise AssertionError(f"{_scenario_prefix(outcome)}{outcome.use_case} {outcome.verdict}: "
                             f"{outcome.summary}\n{reasons}")


def assert_figure_within(outcome: Outcome, figure: str, *, max: float | None = None,
                         min: float | None = None) -> None:
    """One key figure of an outcome lies in [min, max]."""
    __tracebackhide__ = True
    if figure not in outcome.figures:
        raise AssertionError(f"{_scenario_prefix(outcome)}no figure '{figure}'; "
                             f"it has {sorted(outcome.figures)}")
    finding = within([outcome.figures[figure]], figure=figure, max=max, min=min)
    if finding is not None:
        raise AssertionError(f"{_scenario_prefix(outcome)}{figure} = {format_figure(outcome.figures[figure])}, "
                             f"outside [{min}, {max}]")


def assert_values_within(values: Sequence[float] | np.ndarray, *, figure: str, max: float | None = None,
                         min: float | None = None, frames: Sequence[int] | None = None, unit: str = "",
                         scenario: str | None = None, scene: int | str | None = None) -> None:
    """Every per-frame value lies in [min, max]; the message names the frames that do not."""
    __tracebackhide__ = True
    finding = within(values, figure=figure, max=max, min=min, frames=frames, unit=unit, scene=scene)
    if finding is not None:
        raise AssertionError(_scenario_prefix(scenario) + finding.message)


def assert_collision_free(unroll, kinds: Sequence[str] = ("front", "side", "rear"), *,
                          at_fault_only: bool = False) -> None:
    """No collision of the given kinds in any unrolled scene (optionally: none
    that is the ego's fault).  The message names scene, frame, agent and kind."""
    __tracebackhide__ = True
    from .closed_loop import collision_events

    lines = []
    for row, scene in enumerate(unroll.scene_ids):
        events = collision_events(unroll, row, kinds, at_fault_only)
        if events:
            first = events[0]
            lines.append(f"scene {scene}: {len(events)} collision frame(s); first at frame {first['frame']}: "
                         f"{first['kind']} with agent {first['track_id']}"
                         f"{'' if first['at_fault'] else ' (not at fault)'}")
    if lines:
        what = ("at-fault " if at_fault_only else "") + "/".join(kinds)
        raise AssertionError(f"{what} collisions in {len(lines)} scene(s):\n  " + "\n  ".join(lines))


def assert_drift_within(unroll, meters: float, *, seconds: float = 0.0) -> None:
    """The driven ego stays within ``meters`` of the logged one in every scene
    (excursions up to ``seconds`` long are tolerated)."""
    __tracebackhide__ = True
    result = unroll.result
    tolerated = int(round(seconds / unroll.step_time))
    messages = []
    for row, scene in enumerate(unroll.scene_ids):
        frames = np.flatnonzero(result.valid[row])
        finding = within(result.displacement_error[row][frames], figure="displacement", max=meters,
                         frames=frames, unit=" m", scene=scene, tolerated_frames=tolerated)
        if finding is not None:
            messages.append(finding.message)
    if messages:
        raise AssertionError("\n".join(messages))
