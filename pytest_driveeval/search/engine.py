"""The robustness search: hypothesis looks for a perturbed case that fails, in batches.

Hypothesis calls a property with one example at a time, but the engines
unroll many scenes or episodes for about the cost of one.  So one hypothesis
example here is a *generation*: a list of ``batch`` (case, perturbation)
examples, evaluated in one call, and the property is "some example of the
generation fails".  :func:`hypothesis.find` searches for such a generation
(replaying the example database first) and shrinks it; elements that do not
matter shrink to no change, whose verdict is remembered, so while shrinking
only the examples not seen before are evaluated.  The smallest failing
example of the shrunk generation is then moved to the edge of failure by
:func:`tighten_many`, again a batch per round.
"""
from __future__ import annotations

import hashlib
import math
import time
from dataclasses import asdict, dataclass, field, fields, replace
from contextlib import contextmanager
from typing import Any, Callable, Iterator, Sequence

from hypothesis import HealthCheck, Phase, given, settings as hypothesis_settings, strategies as st
from hypothesis.database import ExampleDatabase
from hypothesis.errors import Found

__all__ = ["Example", "SearchResult", "SearchSettings", "Verdict", "database_key", "search", "size_of",
           "tighten_many"]


@dataclass(frozen=True)
class Example:
    """One case (a scene, an episode, a frame: an index into the item's cases) under one perturbation."""

    case: int
    perturbation: Any


@dataclass
class Verdict:
    """Whether an example failed, why, and where (``{"scene": 0, "frame": 57}``, ...)."""

    failed: bool
    reason: str = ""
    where: dict[str, Any] = field(default_factory=dict)


EvaluateMany = Callable[[list[Example]], list[Verdict]]


@dataclass(frozen=True)
class SearchSettings:
    """``examples``: how many examples to try before giving up; ``batch``: how
    many go through the engine together; ``tolerance``: how close to the edge of
    failure the reported perturbation is, as a fraction of each field's range;
    ``derandomize``: the CI profile (a fixed search, no example database);
    ``max_shrink_evaluations``: a bound on hypothesis's one-at-a-time shrinking,
    after which the smallest failure seen so far is tightened."""

    examples: int = 100
    batch: int = 32
    tolerance: float = 0.01
    derandomize: bool = False
    seed: int = 0
    database: ExampleDatabase | None = None
    key: bytes = b""
    max_shrink_evaluations: int = 64


@dataclass
class SearchResult:
    examples: int = 0            # distinct examples evaluated in all
    failures: int = 0            # of which failed
    generations: int = 0         # batches hypothesis generated before the first failure (or in all)
    seconds: float = 0.0
    evaluations: dict[str, int] = field(default_factory=dict)   # distinct examples per phase
    replayed: int = 0            # entries of the example database tried first
    shrunk: Example | None = None    # hypothesis's smallest failing example
    minimal: Example | None = None   # shrunk, then moved to the edge of failure
    verdict: Verdict | None = None   # of ``minimal``
    edges: dict[str, float] = field(default_factory=dict)   # per tightened field: the passing value next to it

    @property
    def found(self) -> bool:
        return self.minimal is not None


class _StopShrinking(BaseException):
    """Raised from the property to end hypothesis's shrinking (a BaseException,
    so hypothesis does not take it for a failure of the property)."""


class _Aborted(BaseException):
    """An error of the evaluation itself (a broken model, a time limit): it ends
    the search at once, rather than being shrunk by hypothesis as if it were
    the failure searched for."""

    def __init__(self, error: Exception):
        self.error = error


def database_key(*parts: Any) -> bytes:
    """A database key from what identifies a search (scenario file, its name, the dataset ...)."""
    return hashlib.sha256("\x1f".join(map(str, ("pytest-driveeval search", *parts))).encode()).digest()


def size_of(perturbation: Any, widths: dict[str, float]) -> float:
    """How far ``perturbation`` is from no change: the sum of its fields'
    distances from their no-change value, each as a fraction of its range."""
    neutral = type(perturbation)()
    return sum(abs(getattr(perturbation, f.name) - getattr(neutral, f.name)) / (widths.get(f.name) or 1.0)
               for f in fields(perturbation))


def search(cases: st.SearchStrategy[int], perturbations: st.SearchStrategy[Any], evaluate_many: EvaluateMany,
           ranges: dict[str, tuple[float, float]], config: SearchSettings,
           progress: Callable[[int, int], None] | None = None) -> SearchResult:
    """Search for a failing example; see the module's docstring.

    ``ranges``: each perturbation field's (low, high), what ``tolerance`` and
    :func:`size_of` are relative to.  ``progress(done, total)``: examples evaluated of
    ``config.examples`` (shrinking a failure may evaluate more: the total grows with them).
    """
    widths = {name: high - low for name, (low, high) in ranges.items()}
    started = time.perf_counter()
    result = SearchResult()
    memo: dict[Example, Verdict] = {}
    phase = ["search"]
    smallest: list[Example] = []

    def evaluate(examples: Sequence[Example]) -> list[Verdict]:
        new = [e for e in dict.fromkeys(examples) if e not in memo]
        if new:
            if phase[0] == "shrink" and result.evaluations.get("shrink", 0) >= config.max_shrink_evaluations:
                raise _StopShrinking
            try:
                verdicts = evaluate_many(new)
                if len(verdicts) != len(new):
                    raise RuntimeError(f"evaluate_many returned {len(verdicts)} verdicts for {len(new)} examples")
            except Exception as exc:
                raise _Aborted(exc) from exc
            memo.update(zip(new, verdicts))
            if progress is not None:
                progress(len(memo), max(config.examples, len(memo)))
            result.evaluations[phase[0]] = result.evaluations.get(phase[0], 0) + len(new)
            for e, v in zip(new, verdicts):
                if v.failed and (not smallest or _rank(e, widths) < _rank(smallest[0], widths)):
                    smallest[:] = [e]
        return [memo[e] for e in examples]

    def generation_fails(generation: list[Example]) -> bool:
        if phase[0] == "search":
            result.generations += 1
        failed = any(v.failed for v in evaluate(generation))
        if failed:
            phase[0] = "shrink"
        return failed

    if config.database is not None and config.key:
        result.replayed = sum(1 for _ in config.database.fetch(config.key))
    generation = st.lists(st.builds(Example, cases, perturbations), min_size=config.batch, max_size=config.batch)
    # report_multiple_bugs=False: with it on, hypothesis keeps generating after the first
    # failure until 10 s of wall time have passed, so a loaded machine searched fewer examples
    # than a quiet one and reported a different result for the same seed.
    budget = hypothesis_settings(
        max_examples=max(1, math.ceil(config.examples / config.batch)), deadline=None,
        report_multiple_bugs=False,
        derandomize=config.derandomize, database=None if config.derandomize else config.database,
        phases=(Phase.explicit, Phase.reuse, Phase.generate, Phase.shrink),
        suppress_health_check=list(HealthCheck))
    try:
        shrunk_generation = _find(generation, generation_fails, budget, None if config.derandomize else config.seed,
                                  config.key or None)
        shrunk = None if shrunk_generation is None else min(
            (e for e in shrunk_generation if memo[e].failed), key=lambda e: _rank(e, widths))
    except _StopShrinking:
        shrunk = smallest[0]
    except _Aborted as aborted:
        raise aborted.error from None
    if shrunk is not None:
        phase[0] = "tighten"
        result.shrunk = shrunk
        try:
            result.minimal, result.edges = tighten_many(shrunk, evaluate, ranges, config.tolerance)
        except _Aborted as aborted:
            raise aborted.error from None
        result.verdict = memo[result.minimal]
    result.examples = len(memo)
    result.failures = sum(v.failed for v in memo.values())
    result.seconds = time.perf_counter() - started
    return result


def _find(strategy: st.SearchStrategy, condition: Callable[[Any], bool], settings: hypothesis_settings,
          seed: int | None, key: bytes | None) -> Any:
    """The smallest value of ``strategy`` that satisfies ``condition``, or None.

    :func:`hypothesis.find`, except that a seeded search keeps the example
    database: ``find(random=...)`` seeds through ``@seed``, which switches the
    database off, and a search must both be reproducible for the session's
    seed and replay the failures it stored before.
    """
    found: list[Any] = []

    @settings
    @given(strategy)
    def test(value):
        if condition(value):
            found[:] = [value]
            raise Found

    test._hypothesis_internal_database_key = key  # what find() sets: our key, not the closure's digest
    if seed is not None:
        test._hypothesis_internal_use_seed = seed  # what @seed sets, without its database=None
    with _without_local_constants():
        try:
            test()
        except Found:
            return found[0]
    return None


@contextmanager
def _without_local_constants() -> Iterator[None]:
    """Hypothesis mixes into its draws constants found in the source of the
    non-library modules imported so far, so the same seed draws different
    examples depending on which tests ran before in the process (serially,
    or on a pytest-xdist worker).  A search must not depend on that: its
    draws see no local constants (hypothesis's own pool stays).  If a
    hypothesis release moves these internals, nothing is patched, and the
    reproducibility tests say so."""
    try:
        from hypothesis.internal.conjecture import providers

        saved = providers._get_local_constants, providers.CONSTANTS_CACHE
        empty = providers.Constants()
    except (ImportError, AttributeError):
        yield
        return
    providers._get_local_constants, providers.CONSTANTS_CACHE = (lambda: empty), {}
    try:
        yield
    finally:
        providers._get_local_constants, providers.CONSTANTS_CACHE = saved


def _rank(example: Example, widths: dict[str, float]) -> tuple[float, int]:
    return size_of(example.perturbation, widths), example.case


def tighten_many(example: Example, evaluate: Callable[[Sequence[Example]], list[Verdict]],
                 ranges: dict[str, tuple[float, float]], tolerance: float = 0.01, points: int = 15
                 ) -> tuple[Example, dict[str, float]]:
    """``example`` (failing) with each changed field moved towards no change
    while it still fails, to within ``tolerance`` of that field's range width.

    Each round evaluates ``points`` values between the last passing and the
    first failing one as one batch, so a field costs about
    log(1 / tolerance) / log(points + 1) batches.  Where the range extends
    to the other side of no change (a lateral offset to the right as well as
    to the left), that side's end is tried too and, if it fails, bisected:
    hypothesis shrinks a float towards its positive side, which need not be
    the nearer edge.  A field whose no-change value still fails is reset to
    it.  Returns the tightened example and, per tightened field, the passing
    value next to the reported one.
    """
    neutral = type(example.perturbation)()
    current = example
    edges: dict[str, float] = {}
    for name, value in asdict(example.perturbation).items():
        base = getattr(neutral, name)
        if value == base:
            continue

        def at(v):
            return Example(current.case, replace(current.perturbation, **{name: v}))

        if evaluate([at(base)])[0].failed:
            current = at(base)
            continue
        low, high = ranges.get(name, (min(value, base), max(value, base)))
        other = low if value > base else high
        sides = [value] + ([other] if other != base and evaluate([at(other)])[0].failed else [])
        width = (high - low) or 1.0
        step_limit = 1 if isinstance(value, int) else tolerance * width
        found = [_bisect(base, side, lambda vs: [v.failed for v in evaluate([at(x) for x in vs])], points, step_limit)
                 for side in sides]
        failing, passing = min(found, key=lambda edge: abs(edge[0] - base))
        current = at(failing)
        edges[name] = passing
    return current, edges


def _bisect(passing: Any, failing: Any, fails_many: Callable[[list], list[bool]], points: int, step_limit: float
            ) -> tuple[Any, Any]:
    """(failing value nearest to ``passing``, the passing value next to it), ``points`` values a round."""
    integral = isinstance(failing, int)
    while abs(failing - passing) > step_limit:
        values = _between(passing, failing, points, integral)
        if not values:
            break
        failed = fails_many(values)
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
