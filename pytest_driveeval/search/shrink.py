"""Shrinking a failing example in batches: which changes matter, on which case, and where each one's edge is.

Hypothesis shrinks one example at a time, and an episode or a scene alone
costs about as much as a batch of them, so once a generation fails the
engine shrinks on its own, a batch per round.  :func:`shrink_candidates` are
the example with every subset of its changed fields reset to no change, the
smallest first (:func:`~.examples.rank`): the fields that matter are found in
one batch where hypothesis would try them one by one.  :func:`tighten_many`
then moves each field left to the edge of failure, bisecting both sides of
no change together.
"""
from __future__ import annotations

from dataclasses import asdict, replace
from itertools import combinations
from typing import Any, Callable, Generator, Sequence

from pytest_driveeval.search.examples import Example, Verdict, changed_fields, rank

__all__ = ["shrink_candidates", "tighten_many"]

# Above this many changed fields the 2**k subsets stop paying: each field alone and all but each one.
ALL_SUBSETS_UP_TO = 6

Evaluate = Callable[[Sequence[Example]], list[Verdict]]
Bisection = Generator[list, list, tuple[Any, Any]]


def shrink_candidates(example: Example, widths: dict[str, float]) -> list[Example]:
    """``example`` with each non-empty subset of its changed fields reset to no change,
    the smallest first."""
    perturbation = example.perturbation
    neutral = type(perturbation)()
    changed = changed_fields(perturbation)
    if len(changed) <= ALL_SUBSETS_UP_TO:
        subsets = [s for n in range(1, len(changed) + 1) for s in combinations(changed, n)]
    else:
        subsets = [tuple(changed)] + [(k,) for k in changed] + [tuple(c for c in changed if c != k) for k in changed]
    reset = [Example(example.case, replace(perturbation, **{k: getattr(neutral, k) for k in s})) for s in subsets]
    # sorted() is stable: equal ranks keep the order above, so the round is the same every time.
    return sorted(reset, key=lambda e: rank(e, widths))


def tighten_many(example: Example, evaluate: Evaluate, ranges: dict[str, tuple[float, float]],
                 tolerance: float = 0.01, points: int = 15) -> tuple[Example, dict[str, float]]:
    """``example`` (failing) with each changed field moved towards no change
    while it still fails, to within ``tolerance`` of that field's range width.

    Each round evaluates ``points`` values between the last passing and the
    first failing one, so a field costs about log(1 / tolerance) / log(points + 1)
    rounds.  Where the range extends to the other side of no change (a lateral
    offset to the right as well as to the left), that side's end is tried too and,
    if it fails, bisected: hypothesis shrinks a float towards its positive side,
    which need not be the nearer edge.  A field whose no-change value still fails
    is reset to it.  The checks of no change and of the far end go in the field's
    first batch with both sides' first points, and the two sides are bisected in
    the same batches: the values and the result are those of asking each in turn.
    Returns the tightened example and, per tightened field, the passing value next
    to the reported one.
    """
    neutral = type(example.perturbation)()
    current = example
    edges: dict[str, float] = {}
    for name, value in asdict(example.perturbation).items():
        base = getattr(neutral, name)
        if value == base:
            continue

        def at(v, of=current, name=name):
            return Example(of.case, replace(of.perturbation, **{name: v}))

        low, high = ranges.get(name, (min(value, base), max(value, base)))
        other = low if value > base else high
        width = (high - low) or 1.0
        step_limit = 1 if isinstance(value, int) else tolerance * width
        sides = [_Side(_bisection(base, value, points, step_limit))]
        if other != base:
            sides.append(_Side(_bisection(base, other, points, step_limit)))
        checks = [at(base)] + ([at(other)] if other != base else [])
        verdicts = evaluate(checks + [at(v) for side in sides for v in side.request])
        if verdicts[0].failed:
            current = at(base)
            continue
        answers, asking = verdicts[len(checks):], list(sides)
        if other != base and not verdicts[1].failed:
            sides = sides[:1]  # the far end passes: that side's points were asked for nothing
        while True:
            for side in asking:
                n = len(side.request)
                if side in sides:
                    side.feed([v.failed for v in answers[:n]])
                answers = answers[n:]
            asking = [side for side in sides if side.request]
            if not asking:
                break
            answers = evaluate([at(v) for side in asking for v in side.request])
        failing, passing = min((side.result for side in sides), key=lambda edge: abs(edge[0] - base))
        current = at(failing)
        edges[name] = passing
    return current, edges


class _Side:
    """One side's bisection, stepped a batch at a time: ``request`` the values it asks
    next (empty when done), ``result`` its (failing, passing) once done."""

    def __init__(self, bisection: Bisection):
        self._bisection = bisection
        self.result: tuple[Any, Any] | None = None
        self.request: list = []
        self._send(None)

    def feed(self, failed: list[bool]) -> None:
        self._send(failed)

    def _send(self, value) -> None:
        try:
            self.request = self._bisection.send(value)
        except StopIteration as done:
            self.request, self.result = [], done.value


def _bisection(passing: Any, failing: Any, points: int, step_limit: float) -> Bisection:
    """Yields ``points`` values a round, is sent whether each failed; returns
    (failing value nearest to ``passing``, the passing value next to it)."""
    integral = isinstance(failing, int)
    while abs(failing - passing) > step_limit:
        values = _between(passing, failing, points, integral)
        if not values:
            break
        failed = yield values
        # The first failing value from the passing side; the one before it passed.
        first = next((i for i, f in enumerate(failed) if f), len(values))
        if first < len(values):
            failing = values[first]
        if first > 0:
            passing = values[first - 1]
    return failing, passing


def _between(passing: float, failing: float, points: int, integral: bool) -> list:
    """Up to ``points`` values strictly between, evenly spaced, from the passing side."""
    if integral:
        step = 1 if failing > passing else -1
        values = list(range(passing + step, failing, step))
        if len(values) > points:
            idx = [round((i + 1) * (len(values) + 1) / (points + 1)) - 1 for i in range(points)]
            values = [values[i] for i in sorted(set(idx))]
        return values
    return [passing + (failing - passing) * (i + 1) / (points + 1) for i in range(points)]
