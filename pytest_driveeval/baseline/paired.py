"""The paired test of a rate between two runs of the same seeded episodes.

Both runs played the same episodes, so an episode that ended badly in both, or well in both, says
nothing about a difference: only the discordant ones do (McNemar).  Under "no difference" each of the
``d`` discordant episodes is as likely to have got worse as better, so the count that got worse is
binomial(d, 1/2): the exact test conditions on ``d``.  The interval of the difference in rates is
the Clopper-Pearson interval of that binomial's proportion, scaled by ``d / n``; it excludes zero
exactly when the two-sided exact test rejects at the same level, so the verdict and the interval
printed beside it never disagree.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import special


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
        return self.low > 0 or self.high < 0


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
    p = min(1.0, 2.0 * float(special.bdtr(min(worse, better), d, 0.5)))
    lo = 0.0 if worse == 0 else float(special.betaincinv(worse, d - worse + 1, alpha / 2))
    hi = 1.0 if worse == d else float(special.betaincinv(worse + 1, d - worse, 1 - alpha / 2))
    scale = 100.0 * d / n
    return PairedRate(n, worse, better, p, scale * (2 * lo - 1), scale * (2 * hi - 1), confidence)
