"""``assert_pass_rate``: the use case's pass-rate check for tests written in Python."""
from __future__ import annotations

from typing import TYPE_CHECKING

from ...verdict import listing

if TYPE_CHECKING:
    from .result import ObstacleResult


def assert_pass_rate(result: ObstacleResult, detection: float | None = None, non_detection: float | None = None
                     ) -> None:
    """Fail unless each part's pass rate reaches its bound (default: the scenario's PassRate);
    the message names the frames (name, stamp) and UUIDs that did not pass."""
    __tracebackhide__ = True
    problems = []
    if result.frames == 0:
        problems.append(f"no frame was evaluated ({result.skipped} skipped: no ground truth within 75 ms or no "
                        "UUID in its BoundingBoxConfig window)")
    for part, bound in (("detection", detection), ("non_detection", non_detection)):
        bound = bound if bound is not None else result.required(part)
        c = result.counters[part]
        if bound is None or not c.total or c.meets(bound):
            continue
        texts, failing = result.failing_texts(part)
        problems.append(f"{part} pass rate {c.rate:.2f}% < {bound:g}%: {failing} of {c.total} frame(s) "
                        f"did not pass: {listing(texts, sep='; ', total=failing)}")
    if problems:
        raise AssertionError("\n".join(problems))
