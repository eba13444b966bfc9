"""McNemar's exact test and the Clopper-Pearson interval of a paired difference in rates
(pytest_driveeval/baseline/paired.py) are scipy's binomial test and interval of the discordant
episodes, mapped to a difference; the verdict and the printed interval never disagree."""
from __future__ import annotations

import itertools
from fractions import Fraction
from math import comb

import numpy as np
import pytest
from scipy.stats import binomtest

from pytest_driveeval.baseline.paired import EXACT_LIMIT, paired_rate, two_sided_p

CONFIDENCES = (50.5, 80.0, 90.0, 93.75, 95.0, 99.0, 99.9)


def episodes(worse: int, better: int, n: int, rng: np.random.Generator | None = None):
    """(bad before, bad now) over ``n`` episodes with ``worse`` turned bad, ``better`` turned good,
    and the rest concordant (some bad in both, some good in both), shuffled."""
    assert worse + better <= n
    before, now = np.zeros(n, bool), np.zeros(n, bool)
    now[:worse] = True
    before[worse:worse + better] = True
    both = (n - worse - better) // 3
    before[worse + better:worse + better + both] = now[worse + better:worse + better + both] = True
    if rng is not None:
        order = rng.permutation(n)
        before, now = before[order], now[order]
    return before, now


def scipy_figures(worse: int, better: int, n: int, confidence: float) -> tuple[float, float, float]:
    """(p, low, high) from scipy: the exact binomial test of the discordant counts and its
    Clopper-Pearson interval of theta = P(worse | discordant), mapped to (d / n) (2 theta - 1) 100."""
    d = worse + better
    test = binomtest(worse, d, 0.5)
    ci = test.proportion_ci(confidence_level=confidence / 100, method="exact")
    scale = 100.0 * d / n
    return test.pvalue, scale * (2 * ci.low - 1), scale * (2 * ci.high - 1)


def cases():
    rng = np.random.default_rng(22)
    fixed = [(1, 0, 1), (0, 1, 1), (1, 0, 5), (5, 0, 5), (0, 7, 7), (3, 3, 6), (10, 0, 256), (0, 10, 256),
             (12, 3, 64), (3, 12, 64), (40, 25, 256), (100, 90, 1000), (1500, 1400, 4000)]
    drawn = []
    for _ in range(150):
        n = int(rng.integers(1, 600))
        worse = int(rng.integers(0, n + 1))
        better = int(rng.integers(0, n - worse + 1))
        if worse + better:
            drawn.append((worse, better, n))
    return [(w, b, n, c) for (w, b, n) in fixed + drawn for c in CONFIDENCES]


@pytest.mark.parametrize("worse, better, n, confidence", cases())
def test_p_value_and_interval_are_scipys(worse, better, n, confidence):
    result = paired_rate(*episodes(worse, better, n, np.random.default_rng(n)), confidence)
    p, low, high = scipy_figures(worse, better, n, confidence)
    assert (result.episodes, result.worse, result.better) == (n, worse, better)
    assert result.p_value == pytest.approx(p, rel=1e-9, abs=1e-300)
    # Both ends come from the same beta quantiles; clamped to zero only at p == alpha.
    assert result.low == pytest.approx(low, abs=1e-9)
    assert result.high == pytest.approx(high, abs=1e-9)
    assert result.low <= result.difference <= result.high
    assert result.difference == pytest.approx(100.0 * (worse - better) / n)


def test_no_discordant_episode_is_no_evidence():
    for n in (1, 5, 300):
        before = np.arange(n) % 3 == 0  # some bad in both runs, the rest good in both
        result = paired_rate(before, before.copy(), 95)
        assert (result.worse, result.better, result.p_value, result.low, result.high) == (0, 0, 1.0, 0.0, 0.0)
        assert not result.significant()


def test_one_episode_can_never_be_significant():
    for before, now in ((False, True), (True, False)):
        result = paired_rate(np.array([before]), np.array([now]), 95)
        assert result.p_value == 1.0 and not result.significant()
        # theta's interval from one success is [0.025, 1]: the difference's [-95, 100]
        assert (result.low, result.high) == pytest.approx((-95.0, 100.0) if now else (-100.0, 95.0))


def test_all_discordant_one_way_is_significant_once_there_are_enough():
    # p = 2 / 2^d: significant at 95 % from d = 6 on (2/32 = 6.25 % is not, 2/64 is)
    for d in range(1, 12):
        result = paired_rate(np.zeros(d, bool), np.ones(d, bool), 95)
        assert result.p_value == pytest.approx(min(1.0, 2.0 / 2 ** d))
        assert result.significant() == (d >= 6)
        assert result.high == 100.0


def exact_p(worse: int, better: int) -> Fraction:
    """The two-sided exact test by enumeration: the probability, under 'no difference' (each
    discordant episode as likely worse as better), of every split of the discordant episodes whose
    probability is at most the observed one (scipy's definition: outcomes at least as extreme)."""
    d = worse + better
    splits = [Fraction(comb(d, k), 2 ** d) for k in range(d + 1)]
    return sum((q for q in splits if q <= splits[worse]), Fraction(0))


def exact_p_by_sequences(worse: int, better: int) -> Fraction:
    """The same by enumerating every assignment of worse / better to the discordant episodes."""
    d = worse + better
    observed = comb(d, worse)
    extreme = sum(1 for flips in itertools.product((0, 1), repeat=d) if comb(d, sum(flips)) <= observed)
    return Fraction(extreme, 2 ** d)


@pytest.mark.parametrize("d", range(1, 11))
def test_p_value_is_the_enumerated_probability_of_outcomes_at_least_as_extreme(d):
    for worse in range(d + 1):
        enumerated = exact_p_by_sequences(worse, d - worse)
        assert enumerated == exact_p(worse, d - worse)
        result = paired_rate(*episodes(worse, d - worse, d + 4), 95)
        # Summed in whole numbers and rounded once: the nearest float to the exact fraction.
        assert result.p_value == float(enumerated)


def test_the_exact_sum_and_scipys_agree_on_both_sides_of_the_limit():
    for d in (EXACT_LIMIT - 1, EXACT_LIMIT, EXACT_LIMIT + 1, 3 * EXACT_LIMIT):
        for k in (0, d // 2 - 3 * int(d ** 0.5), d // 2 - int(d ** 0.5), d // 2):
            assert two_sided_p(k, d) == pytest.approx(binomtest(k, d, 0.5).pvalue, rel=1e-9, abs=1e-300)


def knife_edges():
    """(worse, better, confidence) whose p-value is exactly alpha: confidence = 100 (1 - p), with p
    a dyadic fraction that a float holds exactly."""
    out = []
    for d in range(1, 41):
        for worse in range(d + 1):
            p = exact_p(worse, d - worse)
            confidence = float(100 * (1 - p))
            if 0 < p < 1 and Fraction(1.0 - confidence / 100.0) == p:
                out.append((worse, d - worse, confidence))
    return out


def test_significant_is_p_below_alpha_everywhere_and_the_interval_says_the_same():
    """The verdict is the p-value's; the interval excludes zero when it is significant and contains
    it otherwise, also where p equals alpha exactly (an end of the exact interval at zero, which
    rounding used to put a hair past it: 'significant' at 82.03125 % with p = 0.1796875)."""
    rng = np.random.default_rng(7)
    edges = knife_edges()
    assert len(edges) > 100 and (2, 7, 82.03125) in edges
    checked = [(w, b, c) for w, b, n, c in cases()] + edges
    for worse, better, confidence in checked:
        n = worse + better + int(rng.integers(0, 5))
        result = paired_rate(*episodes(worse, better, n, rng), confidence)
        significant = result.p_value < 1 - confidence / 100
        assert result.significant() == significant, (worse, better, confidence)
        if significant:
            assert result.low >= 0 or result.high <= 0
            assert (result.low >= 0) == (worse > better)
        else:
            assert result.low <= 0 <= result.high
    for worse, better, confidence in edges:
        result = paired_rate(*episodes(worse, better, worse + better), confidence)
        assert not result.significant() and result.p_value == 1 - confidence / 100
        assert result.low <= 0 <= result.high


def test_a_regression_at_the_knife_edge_is_not_one():
    """Through compare: at p == alpha the goal rate that dropped is not reported."""
    from pytest_driveeval.baseline.compare import compare
    from pytest_driveeval.baseline.rules import DEFAULT_CONFIDENCE, FigureRule, Rules, SearchTolerance

    def payload(goals: np.ndarray, confidence: float) -> dict:
        rules = Rules({"goal_rate": FigureRule("higher", paired=("outcome", "g"))}, confidence,
                      SearchTolerance(), True)
        return {"figures": {"goal_rate": 100.0 * goals.mean()}, "rules": rules.to_json(),
                "units": {"kind": "episode", "ids": {"from": 0, "count": goals.size},
                          "columns": {"outcome": ["".join("g" if g else "c" for g in goals)]},
                          "legend": {"g": "goal", "c": "collision"}, "good": {"outcome": "g"}}}

    before = np.ones(9, bool)
    now = before.copy()
    now[:7] = False
    now[7:] = True
    before[7:] = False  # 7 goals lost, 2 gained: p = 0.1796875 exactly
    assert compare(payload(before, 82.03125), payload(now, 82.03125)).status == "unchanged"
    assert compare(payload(before, 82.0), payload(now, 82.0)).status == "regressed"
    assert compare(payload(before, DEFAULT_CONFIDENCE), payload(now, DEFAULT_CONFIDENCE)).status == "unchanged"
