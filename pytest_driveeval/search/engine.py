"""The robustness search: hypothesis looks for a perturbed case that fails, in batches.

Hypothesis calls a property with one example at a time, but the engines
unroll many scenes or episodes for about the cost of one.  So one hypothesis
example here is a *generation*: a list of ``batch`` (case, perturbation)
examples, evaluated in one call, and the property is "some example of the
generation fails".  Hypothesis searches for such a generation (replaying the
example database first); verdicts are remembered, so an example seen before
is never evaluated again.  Hypothesis would shrink the failing generation one
example at a time, each an episode or a scene that costs about as much as a
batch of them, so the engine shrinks the smallest failing example itself, a
batch per round (:mod:`.shrink`: which changed fields matter, on which
case), and :func:`~.shrink.tighten_many` moves it to the edge of failure,
again a batch per round.
"""
from __future__ import annotations

import hashlib
import math
import time
from dataclasses import dataclass, field
from contextlib import contextmanager
from typing import Any, Callable, Iterator, Sequence

from hypothesis import HealthCheck, Phase, given, settings as hypothesis_settings, strategies as st
from hypothesis.database import ExampleDatabase
from hypothesis.errors import Found

from pytest_driveeval.core.errors import DriveEvalError

from pytest_driveeval.search.examples import EvaluateMany, Example, Verdict, rank, size_of
from pytest_driveeval.search.shrink import shrink_candidates, tighten_many

__all__ = ["EvaluateMany", "Example", "SearchResult", "SearchSettings", "Verdict", "database_key", "search",
           "size_of", "tighten_many"]


@dataclass(frozen=True)
class SearchSettings:
    """``examples``: how many examples to try before giving up; ``batch``: how
    many go through the engine together; ``tolerance``: how close to the edge of
    failure the reported perturbation is, as a fraction of each field's range;
    ``derandomize``: the CI profile (a fixed search, no example database);
    ``max_shrink_evaluations``: a bound on the examples shrinking evaluates,
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
    shrunk: Example | None = None    # the smallest failing example after shrinking
    minimal: Example | None = None   # shrunk, then moved to the edge of failure
    verdict: Verdict | None = None   # of ``minimal``
    edges: dict[str, float] = field(default_factory=dict)   # per tightened field: the passing value next to it

    @property
    def found(self) -> bool:
        return self.minimal is not None


class _Aborted(BaseException):
    """An error of the evaluation itself (a broken model, a time limit): it ends
    the search at once, rather than being shrunk by hypothesis as if it were
    the failure searched for."""

    def __init__(self, error: Exception):
        self.error = error


def database_key(*parts: Any) -> bytes:
    """A database key from what identifies a search (scenario file, its name, the dataset ...)."""
    return hashlib.sha256("\x1f".join(map(str, ("pytest-driveeval search", *parts))).encode()).digest()


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

    def evaluate_batch(batch: list[Example]) -> list[Verdict]:
        try:
            verdicts = evaluate_many(batch)
            if len(verdicts) != len(batch):
                raise RuntimeError(f"evaluate_many returned {len(verdicts)} verdicts for {len(batch)} examples")
        except Exception as exc:
            raise _Aborted(exc) from exc
        return verdicts

    def evaluate(examples: Sequence[Example]) -> list[Verdict]:
        """Verdicts of ``examples``, those not seen before evaluated in calls of at most ``batch``."""
        new = [e for e in dict.fromkeys(examples) if e not in memo]
        if new:
            verdicts = [v for start in range(0, len(new), config.batch)
                        for v in evaluate_batch(new[start:start + config.batch])]
            memo.update(zip(new, verdicts))
            if progress is not None:
                progress(len(memo), max(config.examples, len(memo)))
            result.evaluations[phase[0]] = result.evaluations.get(phase[0], 0) + len(new)
            for e, v in zip(new, verdicts):
                if v.failed and (not smallest or rank(e, widths) < rank(smallest[0], widths)):
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
        phases=(Phase.explicit, Phase.reuse, Phase.generate),
        suppress_health_check=list(HealthCheck))
    try:
        failing = _find(generation, generation_fails, budget, None if config.derandomize else config.seed,
                        config.key or None)
        shrunk = None if failing is None else _shrink(evaluate, memo, smallest, widths, config, result.evaluations)
    except _Aborted as aborted:
        raise aborted.error from None
    except BaseExceptionGroup as group:
        # A time limit's alarm can land in hypothesis's own code rather than in an evaluation;
        # hypothesis then replays the generation, which passes, and calls it flaky.
        ours = group.subgroup(lambda e: isinstance(e, DriveEvalError))
        if ours is None:
            raise
        while isinstance(ours, BaseExceptionGroup):
            ours = ours.exceptions[0]
        raise ours from None
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


def _shrink(evaluate: Callable[[Sequence[Example]], list[Verdict]], memo: dict[Example, Verdict],
            smallest: list[Example], widths: dict[str, float], config: SearchSettings,
            evaluations: dict[str, int]) -> Example:
    """The smallest failure so far, ``smallest[0]`` (``evaluate`` keeps it up to date),
    shrunk a batch at a time (:func:`~.shrink.shrink_candidates`, smallest first) until
    every candidate of it is known or ``max_shrink_evaluations`` are spent."""
    while True:
        left = min(config.batch, config.max_shrink_evaluations - evaluations.get("shrink", 0))
        asked = [e for e in shrink_candidates(smallest[0], widths) if e not in memo][:max(left, 0)]
        if not asked:
            return smallest[0]
        evaluate(asked)


def _find(strategy: st.SearchStrategy, condition: Callable[[Any], bool], settings: hypothesis_settings,
          seed: int | None, key: bytes | None) -> Any:
    """The first value of ``strategy`` found to satisfy ``condition`` (the settings
    leave shrinking out), or None.

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
