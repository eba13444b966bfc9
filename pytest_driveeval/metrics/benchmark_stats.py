"""Confidence intervals and verdicts for the policy benchmark.

Policies run the same seeded episodes, each episode in a stratum (its seed group
or blueprint variant: Agarwal's "tasks").  Following Agarwal et al. 2021, "Deep RL
at the edge of the statistical precipice", a condition is decided on a stratified
bootstrap confidence interval, never on a point estimate:

* ``rate_interval``: a rate (goal reached, collision) with its interval;
* ``score_interval``: the interquartile mean (or mean) of a score such as the return;
* ``compare``: policy A against B on the same episodes: the probability of
  improvement P(A > B) and the difference of means or IQMs (paired resampling);
* ``at_least`` / ``at_most`` / ``beats``: verdicts with a one-line message that
  names the estimate, the interval, the confidence level and the episode count.

Every pooled statistic weighs each episode equally.  With equal-sized strata (the
usual design) that is Agarwal's average over tasks.  The stratified bootstrap
resamples episodes with replacement within each stratum, so every resample keeps
the stratum sizes of the run.  Intervals are percentile intervals (rliable's
default for the stratified bootstrap).  scipy.stats.bootstrap cannot stratify,
and BCa's jackknife costs O(n^2) for the IQM, so the resampling is done here.

Same inputs and seed give the same numbers bit for bit: one PCG64 stream, drawn
in fixed-size chunks, and only numpy reductions (no BLAS, whose summation order
can depend on the thread count).
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

import numpy as np

# With fewer successes or failures than this, the bootstrap interval of a rate is
# too narrow on the side of the rare outcome.  Checked by exact enumeration at
# n=20..1000: the lower bound of a 95 % interval misses p in up to 13 % of runs
# with 2 expected failures (nominal 2.5 %), and in at most 2.7 % with the Wilson
# fallback below 10.
MIN_OUTCOME_COUNT = 10
# Below this many episodes a score's interval gets a warning: simulated coverage
# of a 95 % interval of the mean of normal scores is 88 % at 8 episodes, 93 % at 12.
MIN_SCORE_EPISODES = 20
# Elements of one chunk of resamples (resamples x episodes): about 16 MB of
# float64, which keeps the gather and sort in cache and the memory flat.
_CHUNK_ELEMENTS = 1 << 21

Statistic = Literal["mean", "iqm"]


@dataclass(frozen=True)
class Estimate:
    """A point estimate with its confidence interval.

    ``method`` names how the interval was made (``"stratified bootstrap"``,
    ``"Wilson"``, ...); ``note`` says why a fallback was taken or why the interval
    deserves caution.  A rate has ``percent=True`` and is printed in percent.
    """

    point: float
    low: float
    high: float
    n: int
    confidence: float
    method: str
    percent: bool = False
    paired: bool = False
    note: str = ""

    def format(self, value: float) -> str:
        return f"{100 * value:.1f}" if self.percent else f"{value:.4g}"

    def __str__(self) -> str:
        unit = " %" if self.percent else ""
        episodes = "paired episodes" if self.paired else "episodes"
        return (
            f"{self.format(self.point)}{unit} [{self.format(self.low)}, {self.format(self.high)}]"
            f" ({100 * self.confidence:g} % {self.method} CI, {self.n} {episodes})"
        )


@dataclass(frozen=True)
class Comparison:
    """Policy A against policy B on the same episodes.

    ``improvement`` is P(A > B); ``difference`` is statistic(A) - statistic(B).
    """

    improvement: Estimate
    difference: Estimate
    statistic: Statistic


@dataclass(frozen=True)
class Decision:
    """A verdict: ``passed`` and one line that explains it."""

    passed: bool
    message: str
    estimate: Estimate
    threshold: float


def iqm(values: np.ndarray, axis: int = -1) -> np.ndarray | float:
    """Interquartile mean: the mean of the middle half after sorting.

    Drops floor(n/4) values at each end, exactly as ``scipy.stats.trim_mean(values,
    0.25)`` (Agarwal's definition); sorting is faster on the rows of resamples.
    """
    ordered = np.sort(np.asarray(values, dtype=np.float64), axis=axis)
    n = ordered.shape[axis]
    cut = n // 4
    return np.take(ordered, np.arange(cut, n - cut), axis=axis).mean(axis=axis)


def probability_of_improvement(a: np.ndarray, b: np.ndarray) -> float:
    """P(A > B) over paired episodes: the share of episodes where A scores higher,
    a tie counting half (Agarwal's S(x, y) applied to each pair)."""
    a, b = _paired(a, b)
    return float(_twice_pairwise_score(a, b).mean() / 2)


def stratified_indices(
    strata: np.ndarray, resamples: int, rng: np.random.Generator
) -> np.ndarray:
    """(resamples, n) episode indices: each row draws, for every stratum, as many
    episodes as it has, with replacement and from that stratum only."""
    codes = _codes(strata, len(strata))
    # Resampling the episode numbers (grouped by stratum) is what the bootstrap
    # does to every column, so this shows exactly which episodes it draws.
    order = np.argsort(codes, kind="stable")
    return _resample((order,), np.bincount(codes), resamples, rng)[0]


def rate_interval(
    successes: np.ndarray,
    strata: np.ndarray | None = None,
    *,
    confidence: float = 0.95,
    resamples: int = 10_000,
    seed: int = 0,
    fallback: Literal["wilson", "clopper-pearson"] = "wilson",
) -> Estimate:
    """The rate of successes (one bool per episode) with a confidence interval.

    A stratified bootstrap when both outcomes occur at least ``MIN_OUTCOME_COUNT``
    times.  Otherwise the bootstrap interval is too narrow (it collapses to a point
    when every episode has the same outcome), so the Wilson score interval (or
    Clopper-Pearson, which guarantees the coverage at the price of width) is used;
    both ignore the strata, which only makes them wider.
    """
    x = _episodes(successes, "successes")
    if not np.isin(x, (0, 1)).all():
        raise ValueError("successes must be booleans (or 0/1), one per episode")
    _check(confidence, resamples)
    x = x.astype(np.float64)
    n, k = len(x), int(x.sum())
    point = k / n
    if min(k, n - k) < MIN_OUTCOME_COUNT:
        method = {"wilson": "Wilson", "clopper-pearson": "Clopper-Pearson"}[fallback]
        from scipy import stats  # here: importing scipy.stats costs every pytest start a second

        ci = stats.binomtest(k, n).proportion_ci(
            confidence, method="exact" if fallback == "clopper-pearson" else "wilson"
        )
        why = (
            f"all {n} episodes have the same outcome" if k in (0, n)
            else f"only {min(k, n - k)} episodes have the rarer outcome"
        )
        note = f"{why}: a bootstrap interval would be too narrow"
        return Estimate(point, float(ci.low), float(ci.high), n, confidence, method,
                        percent=True, note=note)
    codes = _codes(strata, n)
    dist = _bootstrap_means((x,), codes, resamples, np.random.default_rng(seed))[:, 0]
    low, high = _percentile_interval(dist, confidence)
    return Estimate(point, low, high, n, confidence, _bootstrap_name(codes), percent=True)


def score_interval(
    scores: np.ndarray,
    strata: np.ndarray | None = None,
    *,
    statistic: Statistic = "iqm",
    confidence: float = 0.95,
    resamples: int = 10_000,
    seed: int = 0,
) -> Estimate:
    """The IQM (Agarwal's recommended aggregate: robust to outlier episodes, less
    noisy than the median) or the mean of a per-episode score, with a stratified
    bootstrap interval."""
    x = _episodes(scores, "scores")
    _check(confidence, resamples)
    codes = _codes(strata, len(x))
    rng = np.random.default_rng(seed)
    if statistic == "mean":
        point, dist = float(x.mean()), _bootstrap_means((x,), codes, resamples, rng)[:, 0]
    elif statistic == "iqm":
        point = float(iqm(x))
        dist = _bootstrap(_iqm_of_ranks(x), (_ranks(x),), codes, resamples, rng)
    else:
        raise ValueError(f"statistic must be 'mean' or 'iqm', not {statistic!r}")
    low, high = _percentile_interval(dist, confidence)
    return Estimate(point, low, high, len(x), confidence, _bootstrap_name(codes),
                    note=_small_sample_note(x))


def compare(
    a: np.ndarray,
    b: np.ndarray,
    strata: np.ndarray | None = None,
    *,
    statistic: Statistic = "mean",
    confidence: float = 0.95,
    resamples: int = 10_000,
    seed: int = 0,
) -> Comparison:
    """Policy A against B, ``a[i]`` and ``b[i]`` being the same episode.

    Paired resampling: each resample draws episode indices once (within strata)
    and applies them to both policies, so what the episodes share (an easy seed, a
    hard blueprint) cancels and the interval reflects only how the policies differ.
    For bools (goal reached), P(A > B) = 0.5 + (rate A - rate B) / 2 exactly.
    """
    a, b = _paired(a, b)
    _check(confidence, resamples)
    codes = _codes(strata, len(a))
    rng = np.random.default_rng(seed)
    method = "paired " + _bootstrap_name(codes)

    # Both estimates come from the same resamples, so they describe one bootstrap
    # world (and for bools the two rules of ``beats`` agree exactly).
    wins = _twice_pairwise_score(a, b)
    if statistic == "mean":
        # The difference of means is the mean of the per-episode differences.
        diff = a.astype(np.float64) - b.astype(np.float64)
        point = float(diff.mean())
        dist = _bootstrap_means((wins, diff), codes, resamples, rng)
    elif statistic == "iqm":
        point = float(iqm(a) - iqm(b))
        iqm_a, iqm_b = _iqm_of_ranks(a), _iqm_of_ranks(b)

        def both(w: np.ndarray, ra: np.ndarray, rb: np.ndarray) -> np.ndarray:
            return np.stack([w.mean(axis=-1), iqm_a(ra) - iqm_b(rb)], axis=-1)

        dist = _bootstrap(both, (wins, _ranks(a), _ranks(b)), codes, resamples, rng)
    else:
        raise ValueError(f"statistic must be 'mean' or 'iqm', not {statistic!r}")

    differing = int(np.count_nonzero(a != b))
    note = (
        f"only {differing} episodes differ between the policies: the interval may be too narrow"
        if differing < MIN_OUTCOME_COUNT else ""
    )
    low, high = _percentile_interval(dist[:, 0] / 2, confidence)
    improvement = Estimate(float(wins.mean() / 2), low, high, len(a), confidence, method,
                           paired=True, note=note)
    low, high = _percentile_interval(dist[:, 1], confidence)
    is_rate = a.dtype == bool  # _paired gave both the same dtype
    difference = Estimate(point, low, high, len(a), confidence, method, percent=is_rate,
                          paired=True, note=note)
    return Comparison(improvement, difference, statistic)


def at_least(estimate: Estimate, threshold: float, label: str = "estimate") -> Decision:
    """Passes when the interval's lower bound is >= threshold: the whole interval
    clears it, so a lucky point estimate on a few episodes does not pass."""
    return _decide(estimate, threshold, label, ">=", estimate.low >= threshold,
                   estimate.point >= threshold)


def at_most(estimate: Estimate, threshold: float, label: str = "estimate") -> Decision:
    """Passes when the interval's upper bound is <= threshold."""
    return _decide(estimate, threshold, label, "<=", estimate.high <= threshold,
                   estimate.point <= threshold)


def beats(
    comparison: Comparison,
    *,
    rule: Literal["improvement", "difference"] = "improvement",
    label: str | None = None,
) -> Decision:
    """Passes when A is better than B with confidence.

    ``rule="improvement"`` (default): the lower bound of P(A > B) is > 0.5.  It is
    Agarwal's recommendation: scale-free (a return and a rate are judged alike) and
    not swayed by a few extreme episodes.  ``rule="difference"``: the lower bound
    of statistic(A) - statistic(B) is > 0; it asks whether A is better on average,
    which a few large wins can decide.  For bools the two rules agree.
    """
    if rule == "improvement":
        estimate, threshold, label = comparison.improvement, 0.5, label or "P(A > B)"
    elif rule == "difference":
        estimate, threshold = comparison.difference, 0.0
        label = label or f"{comparison.statistic}(A) - {comparison.statistic}(B)"
    else:
        raise ValueError(f"rule must be 'improvement' or 'difference', not {rule!r}")
    return _decide(estimate, threshold, label, ">", estimate.low > threshold,
                   estimate.point > threshold)


def _decide(
    estimate: Estimate, threshold: float, label: str, op: str, passed: bool, point_passes: bool
) -> Decision:
    shown = f"{100 * threshold:.4g} %" if estimate.percent else f"{threshold:.4g}"
    message = f"{label} {estimate} is {'' if passed else 'not '}{op} {shown}"
    if point_passes and not passed:
        # The point estimate satisfies the condition: say why the verdict is no.
        message += f" (the interval includes {shown})"
    if estimate.note:
        message += f"; {estimate.note}"
    return Decision(passed, message, estimate, threshold)


def _bootstrap_means(
    columns: tuple[np.ndarray, ...], codes: np.ndarray, resamples: int, rng: np.random.Generator
) -> np.ndarray:
    """Bootstrap distribution of the pooled mean of each column, (resamples, m);
    the columns (one value per episode each) are resampled together.

    When the episodes take few distinct values (rates, win/tie/loss, discrete
    rewards), the counts of each (stratum, value) cell in a resample are
    multinomial: drawing those counts gives the same distribution as drawing
    episodes, at a cost of cells instead of episodes per resample.
    """
    n = len(codes)
    values, value_codes = np.unique(np.column_stack(columns), axis=0, return_inverse=True)
    n_strata = int(codes.max()) + 1
    if n_strata * len(values) >= n:
        def means(*rows: np.ndarray) -> np.ndarray:
            return np.stack([row.mean(axis=-1) for row in rows], axis=-1)
        return _bootstrap(means, columns, codes, resamples, rng)
    cells = np.zeros((n_strata, len(values)), dtype=np.int64)
    np.add.at(cells, (codes, value_codes.reshape(-1)), 1)
    sizes = cells.sum(axis=1)
    probabilities = cells / sizes[:, None]
    out = []
    for chunk in _chunk_sizes(resamples, cells.size):
        counts = rng.multinomial(sizes, probabilities, size=(chunk, n_strata))
        # (chunk, strata, cells, 1) * (cells, m) summed over strata and cells.
        out.append((counts[..., None] * values).sum(axis=(1, 2)) / n)
    return np.concatenate(out)


def _bootstrap(
    statistic: Callable[..., np.ndarray],
    columns: tuple[np.ndarray, ...],
    codes: np.ndarray,
    resamples: int,
    rng: np.random.Generator,
) -> np.ndarray:
    """Bootstrap distribution of ``statistic`` (rows of resampled episodes -> one
    value per row).  One set of draws serves every column: paired resampling."""
    order = np.argsort(codes, kind="stable")
    # Grouping the episodes by stratum once makes each stratum a contiguous slice.
    columns = tuple(column[order] for column in columns)
    sizes = np.bincount(codes)
    out = []
    for chunk in _chunk_sizes(resamples, len(codes)):
        out.append(statistic(*_resample(columns, sizes, chunk, rng)))
    return np.concatenate(out)


def _resample(
    columns: tuple[np.ndarray, ...], sizes: np.ndarray, resamples: int, rng: np.random.Generator
) -> list[np.ndarray]:
    """(resamples, n) rows per column; columns hold episodes grouped by stratum,
    ``sizes`` the stratum sizes in that order.  Row r of every column uses the
    same draws: within each stratum, as many episodes as it has, with replacement."""
    n = int(sizes.sum())
    dtype = np.int32 if n < 2**31 else np.int64  # int32 draws are twice as fast
    rows = [np.empty((resamples, n), dtype=column.dtype) for column in columns]
    start = 0
    for size in sizes:
        stop = start + size
        draws = rng.integers(0, size, size=(resamples, size), dtype=dtype)
        for column, row in zip(columns, rows, strict=True):
            # mode="clip" skips take's bounds-checking copy; draws are in range.
            np.take(column[start:stop], draws, out=row[:, start:stop], mode="clip")
        start = stop
    return rows


def _iqm_of_ranks(values: np.ndarray) -> Callable[[np.ndarray], np.ndarray]:
    """IQM per row of resampled ranks (indices into ``sorted(values)``).

    Resampling ranks instead of values lets numpy sort the rows with its radix sort
    (int16, kind="stable"), faster than sorting floats; the middle half of the
    sorted ranks picks the same values as sorting the values would.
    """
    ordered = np.sort(values)
    n = len(values)
    cut = n // 4

    def statistic(ranks: np.ndarray) -> np.ndarray:
        middle = np.sort(ranks, axis=-1, kind="stable")[..., cut:n - cut]
        return ordered[middle].mean(axis=-1)

    return statistic


def _ranks(values: np.ndarray) -> np.ndarray:
    dtype = np.int16 if len(values) <= np.iinfo(np.int16).max else np.int64
    ranks = np.empty(len(values), dtype=dtype)
    ranks[np.argsort(values, kind="stable")] = np.arange(len(values))
    return ranks


def _chunk_sizes(resamples: int, per_resample: int) -> list[int]:
    chunk = max(1, _CHUNK_ELEMENTS // max(1, per_resample))
    full, rest = divmod(resamples, chunk)
    return [chunk] * full + ([rest] if rest else [])


def _percentile_interval(dist: np.ndarray, confidence: float) -> tuple[float, float]:
    alpha = (1 - confidence) / 2
    low, high = np.quantile(dist, [alpha, 1 - alpha])
    return float(low), float(high)


def _twice_pairwise_score(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    # Twice Agarwal's S(x, y) (1 if x > y, 1/2 if equal, 0 otherwise): exact in
    # int8, which the bootstrap gathers faster than floats.
    return (2 * (a > b) + (a == b)).astype(np.int8)


def _small_sample_note(x: np.ndarray) -> str:
    if np.all(x == x[0]):
        return f"all {len(x)} episodes have the same score: the interval is a point"
    if len(x) < MIN_SCORE_EPISODES:
        return f"only {len(x)} episodes: a bootstrap interval is too narrow for so few"
    return ""


def _bootstrap_name(codes: np.ndarray) -> str:
    return "stratified bootstrap" if codes.max() > 0 else "bootstrap"


def _episodes(values: np.ndarray, name: str) -> np.ndarray:
    x = np.asarray(values)
    if x.ndim != 1:
        raise ValueError(f"{name} must be one value per episode (1-D), got shape {x.shape}")
    if len(x) == 0:
        raise ValueError(f"{name}: no episodes, so there is nothing to estimate")
    if x.dtype != bool:
        x = x.astype(np.float64)
        if not np.isfinite(x).all():
            raise ValueError(f"{name}: episode {int(np.argmin(np.isfinite(x)))} is not finite")
    return x


def _paired(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    a, b = _episodes(a, "a"), _episodes(b, "b")
    if len(a) != len(b):
        raise ValueError(
            f"paired comparison needs the same episodes for both policies: {len(a)} vs {len(b)}"
        )
    if a.dtype != b.dtype:  # a bool against a float score: compare as numbers
        a, b = a.astype(np.float64), b.astype(np.float64)
    return a, b


def _codes(strata: np.ndarray | None, n: int) -> np.ndarray:
    """Stratum labels (any sortable type) -> codes 0..K-1 in sorted label order."""
    if strata is None:
        return np.zeros(n, dtype=np.intp)
    labels = np.asarray(strata)
    if labels.shape != (n,):
        raise ValueError(f"strata must give one label per episode: shape {labels.shape}, {n} episodes")
    return np.unique(labels, return_inverse=True)[1].reshape(n)


def _check(confidence: float, resamples: int) -> None:
    if not 0 < confidence < 1:  # also refuses NaN
        raise ValueError(f"confidence must be between 0 and 1 (0.95 for 95 %), not {confidence}")
    if int(resamples) != resamples or resamples < 1:
        raise ValueError(f"resamples must be a positive integer, not {resamples}")
