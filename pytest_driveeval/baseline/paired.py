"""The paired test of a rate between two runs of the same seeded episodes.

Both runs played the same episodes, so an episode that ended badly in both, or well in both, says
nothing about a difference: only the discordant ones do (McNemar).  Under "no difference" each of the
``d`` discordant episodes is as likely to have got worse as better, so the count that got worse is
binomial(d, 1/2): the exact test conditions on ``d``.  The interval of the difference in rates is
the Clopper-Pearson interval of that binomial's proportion, scaled by ``d / n``; it excludes zero
exactly when the two-sided exact test rejects at the same level, so the verdict and the interval
printed beside it never disagree.  That holds in exact arithmetic; the two are computed by different
routines, so where the p-value equals alpha (an interval's end at zero) rounding could put that end a
hair on either side: the p-value decides, and the end is put at zero on the side it says.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class PairedRate:
    episodes: int
    worse: int      # episodes bad now that were not before
    better: int     # episodes bad before that are not now
    p_value: float  # two-sided, exact
    low: float      # interval of (rate now - rate before), in percentage points
    high: float
    confidence: float  # percent

    @property
    def difference(self) -> float:
        return 100.0 * (self.worse - self.better) / self.episodes if self.episodes else 0.0

    def significant(self) -> bool:
        return self.p_value < 1.0 - self.confidence / 100.0


#: Up to this many discordant episodes the p-value is summed in whole numbers (under a millisecond)
EXACT_LIMIT = 2048


def two_sided_p(k: int, d: int) -> float:
    """P(X <= k or X >= d - k) for X ~ binomial(d, 1/2), k <= d / 2.  Exact (then rounded once) for
    the small ``d`` where a p-value can equal a confidence's alpha, as 1/16 = 93.75 % does: the
    verdict at that edge is the exact test's, not the rounding's."""
    if d > EXACT_LIMIT:
        from scipy import special  # here: importing scipy.special costs every pytest start a second

        return min(1.0, 2.0 * float(special.bdtr(k, d, 0.5)))
    term = total = 1
    for i in range(1, k + 1):
        term = term * (d - i + 1) // i
        total += term
    return min(1.0, total / 2 ** (d - 1))


def paired_rate(bad_before: np.ndarray, bad_now: np.ndarray, confidence: float) -> PairedRate:
    """McNemar's exact test and interval for the rate of a bad end over the same episodes."""
    before, now = np.asarray(bad_before, bool), np.asarray(bad_now, bool)
    if before.shape != now.shape:
        raise ValueError(f"paired episodes differ in number: {before.size} before, {now.size} now")
    worse, better = int(np.sum(now & ~before)), int(np.sum(before & ~now))
    n, d = before.size, worse + better
    alpha = 1.0 - confidence / 100.0
    if d == 0:
        return PairedRate(n, 0, 0, 1.0, 0.0, 0.0, confidence)
    from scipy import special  # here, as above

    p = two_sided_p(min(worse, better), d)
    lo = 0.0 if worse == 0 else float(special.betaincinv(worse, d - worse + 1, alpha / 2))
    hi = 1.0 if worse == d else float(special.betaincinv(worse + 1, d - worse, 1 - alpha / 2))
    scale = 100.0 * d / n
    low, high = scale * (2 * lo - 1), scale * (2 * hi - 1)
    if p >= alpha:
        low, high = min(low, 0.0), max(high, 0.0)
    elif worse > better:
        low = max(low, 0.0)
    else:
        high = min(high, 0.0)
    return PairedRate(n, worse, better, p, low, high, confidence)
