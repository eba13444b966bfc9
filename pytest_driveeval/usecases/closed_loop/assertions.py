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

__all__ = ["assert_collision_free", "assert_drift_within"]


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
            lines.append(f"scene {scene}: {len(events)} collision frame(s); first at frame {first['frame']}: "
                         f"{first['kind']}{collision_detail(first)}")
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
            messages.append(finding.message)
    if messages:
        raise AssertionError("\n".join(messages))
