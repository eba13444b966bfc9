"""Assertion helpers for closed-loop tests written in Python, on an
:class:`~pytest_driveeval.usecases.closed_loop.evaluate.Unroll`.

Registered for assertion rewriting (see ``pytest_driveeval/__init__``); each
hides its own frame so a failure points at the test, and its message names
the scene, the frame and the agent or figure.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from pytest_driveeval.usecases.closed_loop.evaluate import Unroll, collision_detail, collision_events
from pytest_driveeval.verdict import within

__all__ = ["assert_collision_free", "assert_comfortable", "assert_drift_within", "assert_drivable_area_compliant",
           "assert_driving_direction_compliant", "assert_making_progress", "assert_score_at_least",
           "assert_speed_limit_compliant", "assert_term_at_least", "assert_time_to_collision_within_bound"]


def assert_collision_free(unroll: Unroll, kinds: Sequence[str] = ("front", "side", "rear"), *,
                          at_fault_only: bool = False) -> None:
    """No collision of the given kinds in any unrolled scene (optionally: none
    that is the ego's fault).  The message names scene, frame, agent and kind."""
    __tracebackhide__ = True
    lines = []
    for row, scene in enumerate(unroll.scene_ids):
        events = collision_events(unroll, row, kinds, at_fault_only)
        if events:
            first = events[0]
            lines.append(f"{unroll.scene_name(scene)}: {len(events)} collision frame(s); first at frame "
                         f"{first['frame']}: {first['kind']}{collision_detail(first)}")
    if lines:
        what = ("at-fault " if at_fault_only else "") + "/".join(kinds)
        raise AssertionError(f"{what} collisions in {len(lines)} scene(s):\n  " + "\n  ".join(lines))


def assert_drift_within(unroll: Unroll, meters: float, *, seconds: float = 0.0) -> None:
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
            messages.append(finding.message.replace(f"scene {scene}", unroll.scene_name(scene), 1))
    if messages:
        raise AssertionError("\n".join(messages))


def assert_score_at_least(unroll: Unroll, minimum: float) -> None:
    """nuPlan's closed-loop score is at least ``minimum`` in every unrolled scene; the message names
    each scene below it and what cost it the score, with frames."""
    __tracebackhide__ = True
    from pytest_driveeval.usecases.closed_loop.score import describe, score_unroll

    low = [f"{unroll.scene_name(scene)}: score {score.score:.3f}: {describe(score)}"
           for scene, score in score_unroll(unroll).items() if score.score < minimum]
    if low:
        raise AssertionError(f"nuPlan score below {minimum:g} in {len(low)} scene(s):\n  " + "\n  ".join(low))


def assert_term_at_least(unroll: Unroll, term: str, minimum: float = 1.0) -> None:
    """One of the score's terms (nuPlan's metric name, metrics.nuplan_score.TERMS) is at least
    ``minimum`` in every scene; a scene that cannot compute it fails, saying why."""
    __tracebackhide__ = True
    from pytest_driveeval.metrics.nuplan_score import TERMS
    from pytest_driveeval.usecases.closed_loop.score import score_unroll

    if term not in TERMS:
        raise ValueError(f"unknown score term {term!r}; the terms: {', '.join(TERMS)}")
    lines = []
    for scene, score in score_unroll(unroll).items():
        found = score.terms[term]
        if found.value is None:
            lines.append(f"{unroll.scene_name(scene)}: not available ({found.reason})")
        elif found.value < minimum:
            lines.append(f"{unroll.scene_name(scene)}: {found.value:.3f} ({found.message})")
    if lines:
        raise AssertionError(f"{term} below {minimum:g} in {len(lines)} scene(s):\n  " + "\n  ".join(lines))


def assert_drivable_area_compliant(unroll: Unroll) -> None:
    """No corner of the ego 0.3 m or more off the drivable area, in any scene."""
    __tracebackhide__ = True
    assert_term_at_least(unroll, "drivable_area_compliance")


def assert_driving_direction_compliant(unroll: Unroll) -> None:
    """Under 2 m against the lane's direction within any 1.1 s, in every scene."""
    __tracebackhide__ = True
    assert_term_at_least(unroll, "driving_direction_compliance")


def assert_time_to_collision_within_bound(unroll: Unroll) -> None:
    """Time to collision above 0.95 s on every frame, and no at-fault collision."""
    __tracebackhide__ = True
    assert_term_at_least(unroll, "time_to_collision_within_bound")


def assert_comfortable(unroll: Unroll) -> None:
    """nuPlan's six comfort signals strictly inside their bounds on every frame."""
    __tracebackhide__ = True
    assert_term_at_least(unroll, "ego_is_comfortable")


def assert_speed_limit_compliant(unroll: Unroll, minimum: float = 1.0) -> None:
    """nuPlan's speed-limit compliance at least ``minimum`` (1: never over a limit)."""
    __tracebackhide__ = True
    assert_term_at_least(unroll, "speed_limit_compliance", minimum)


def assert_making_progress(unroll: Unroll) -> None:
    """The ego's progress along the expert's route is at least 20 % of the expert's."""
    __tracebackhide__ = True
    assert_term_at_least(unroll, "ego_is_making_progress")
