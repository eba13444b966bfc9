"""Confidence intervals and verdicts of the policy benchmark (Agarwal et al. 2021)."""
from __future__ import annotations

import sys

import numpy as np
import pytest
from scipy import stats

from pytest_driveeval.metrics.benchmark_stats import (
    Estimate,
    at_least,
    at_most,
    beats,
    compare,
    iqm,
    probability_of_improvement,
    rate_interval,
    score_interval,
    stratified_indices,
)


def percentile_interval(dist, confidence=0.95):
    return tuple(np.quantile(dist, [(1 - confidence) / 2, (1 + confidence) / 2]))


# --- hand-computed statistics ---------------------------------------------------

def test_iqm_of_known_arrays():
    # n=8: drop 2 at each end of 1..8 -> mean(3, 4, 5, 6).
    assert iqm(np.arange(1, 9)) == 4.5
    # n=10 drops floor(10/4)=2 at each end; the outliers are among them.
    assert iqm([-1000, 0, 1, 2, 3, 4, 5, 6, 7, 1000]) == pytest.approx(3.5)
    # Fewer than 4 episodes: nothing is dropped.
    assert iqm([1.0, 2.0, 6.0]) == 3.0


@pytest.mark.parametrize("n", [1, 2, 3, 4, 5, 7, 8, 9, 10, 11, 37, 100])
def test_iqm_is_scipy_trim_mean_quarter(n):
    # Agarwal's IQM (rliable) is scipy.stats.trim_mean(x, 0.25).
    x = np.random.default_rng(n).exponential(size=n)
    assert iqm(x) == pytest.approx(stats.trim_mean(x, 0.25), rel=1e-12)


def test_probability_of_improvement_counts_ties_half():
    # wins, tie, loss, tie -> (1 + 0.5 + 0 + 0.5) / 4
    assert probability_of_improvement([3, 2, 1, 5], [1, 2, 4, 5]) == 0.5
    assert probability_of_improvement([1, 1, 1], [0, 0, 1]) == pytest.approx(5 / 6)
    assert probability_of_improvement([0, 0], [1, 1]) == 0.0
    assert probability_of_improvement([2.0, 2.0], [2.0, 2.0]) == 0.5


def test_probability_of_improvement_of_bools_is_half_plus_half_the_rate_difference():
    rng = np.random.default_rng(3)
    a, b = rng.random(101) < 0.8, rng.random(101) < 0.6
    expected = 0.5 + (a.mean() - b.mean()) / 2
    assert probability_of_improvement(a, b) == pytest.approx(expected)


# --- coverage -------------------------------------------------------------------

def test_rate_interval_covers_p_in_about_95_percent_of_replications():
    p, n, replications = 0.7, 200, 400
    covered = 0
    for seed in range(replications):
        x = np.random.default_rng(seed).random(n) < p
        estimate = rate_interval(x, resamples=2000, seed=seed)
        assert estimate.method == "bootstrap"
        covered += estimate.low <= p <= estimate.high
    assert 0.93 <= covered / replications <= 0.97


def test_stratified_rate_interval_covers_and_is_narrower_than_pooled():
    # Two blueprint variants of very different difficulty, 100 episodes each: the
    # pooled rate is 0.7.  Resampling within strata removes the between-strata
    # variance (the sizes are fixed by design), so the interval is narrower.
    strata = np.repeat(["highway", "merge"], 100)
    p = np.repeat([0.95, 0.45], 100)
    covered, widths = 0, []
    for seed in range(400):
        x = np.random.default_rng(seed).random(200) < p
        stratified = rate_interval(x, strata, resamples=2000, seed=seed)
        pooled = rate_interval(x, resamples=2000, seed=seed)
        assert stratified.method == "stratified bootstrap"
        covered += stratified.low <= 0.7 <= stratified.high
        widths.append((stratified.high - stratified.low) / (pooled.high - pooled.low))
    assert 0.93 <= covered / 400 <= 0.97
    assert np.mean(widths) < 0.92


def test_iqm_interval_covers_the_population_iqm():
    # The IQM of a symmetric distribution is its centre, 0 here.
    covered = 0
    for seed in range(400):
        x = np.random.default_rng(seed).normal(size=80)
        estimate = score_interval(x, resamples=1000, seed=seed)
        covered += estimate.low <= 0 <= estimate.high
    # The percentile bootstrap undercovers a little at n=80 (about 93 %).
    assert 0.90 <= covered / 400 <= 0.98


def test_wilson_fallback_keeps_the_lower_bound_honest_with_few_failures():
    # Exact enumeration over every outcome count of 40 episodes at p=0.95 (about
    # 2 failures expected): the 95 % lower bound may exceed p in at most ~2.5 % of
    # runs.  A bootstrap here would say [100, 100] % whenever all 40 succeed,
    # which happens in 13 % of runs.
    n, p = 40, 0.95
    misses = sum(
        stats.binom.pmf(k, n, p)
        for k in range(n + 1)
        if rate_interval(np.arange(n) < k, resamples=500).low > p
    )
    assert misses <= 0.03


# --- resampling -----------------------------------------------------------------

def test_stratified_indices_keep_stratum_sizes_and_membership():
    strata = np.array(["b", "a", "c", "a", "b", "b", "c", "a", "a", "b"])
    idx = stratified_indices(strata, 500, np.random.default_rng(0))
    assert idx.shape == (500, len(strata))
    drawn = strata[idx]
    for label in np.unique(strata):
        assert ((drawn == label).sum(axis=1) == (strata == label).sum()).all()
    # Columns are grouped by stratum and draw from that stratum only.
    assert (drawn == np.sort(strata)).all()
    # With replacement, and every episode does get drawn.
    assert (np.array([len(set(row)) for row in idx]) < len(strata)).any()
    assert set(idx.ravel()) == set(range(len(strata)))


def test_fast_rate_path_matches_resampling_episodes():
    # A rate resamples (stratum, outcome) counts instead of episodes: the same
    # distribution, so the interval matches one made from drawn episode indices.
    rng = np.random.default_rng(5)
    strata = rng.integers(0, 4, 400)
    x = rng.random(400) < np.array([0.9, 0.7, 0.5, 0.3])[strata]
    fast = rate_interval(x, strata, resamples=20_000, seed=1)
    idx = stratified_indices(strata, 20_000, np.random.default_rng(2))
    low, high = percentile_interval(x[idx].mean(axis=1))
    assert fast.low == pytest.approx(low, abs=0.006)
    assert fast.high == pytest.approx(high, abs=0.006)


@pytest.mark.parametrize(("statistic", "aggregate"), [("mean", np.mean), ("iqm", iqm)])
def test_paired_interval_is_much_narrower_than_unpaired_for_correlated_episodes(
    statistic, aggregate
):
    # Episode difficulty dominates the return; B is 0.2 worse on every episode.
    rng = np.random.default_rng(11)
    strata = rng.integers(0, 3, 300)
    difficulty = rng.normal(0, 5, 300)
    a = difficulty + rng.normal(0, 0.3, 300)
    b = difficulty - 0.2 + rng.normal(0, 0.3, 300)
    paired = compare(a, b, strata, statistic=statistic, resamples=4000, seed=0).difference
    # Unpaired: A's and B's episodes drawn independently.
    ia = stratified_indices(strata, 4000, np.random.default_rng(1))
    ib = stratified_indices(strata, 4000, np.random.default_rng(2))
    low, high = percentile_interval(aggregate(a[ia], axis=1) - aggregate(b[ib], axis=1))
    assert (paired.high - paired.low) < 0.2 * (high - low)
    assert paired.low > 0 > low  # only pairing shows that A is better


@pytest.mark.parametrize("statistic", ["mean", "iqm"])
def test_comparison_point_estimates(statistic):
    a = np.array([5.0, 3, 8, 1, 9, 4, 7, 2])
    b = np.array([4.0, 3, 9, 0, 7, 4, 5, 1])
    cmp = compare(a, b, statistic=statistic, resamples=500)
    assert cmp.improvement.point == probability_of_improvement(a, b) == (5 + 2 * 0.5) / 8
    expected = a.mean() - b.mean() if statistic == "mean" else iqm(a) - iqm(b)
    assert cmp.difference.point == pytest.approx(expected)
    assert cmp.improvement.low <= cmp.improvement.point <= cmp.improvement.high


# --- decisions ------------------------------------------------------------------

def test_decision_uses_the_lower_bound_not_the_point_estimate():
    estimate = Estimate(0.72, 0.651, 0.783, 200, 0.95, "stratified bootstrap", percent=True)
    decision = at_least(estimate, 0.70, "goal rate")
    assert not decision.passed
    assert decision.message == (
        "goal rate 72.0 % [65.1, 78.3] (95 % stratified bootstrap CI, 200 episodes)"
        " is not >= 70 % (the interval includes 70 %)"
    )
    assert at_least(estimate, 0.65, "goal rate").passed
    assert at_least(estimate, 0.651).passed  # the bound itself is enough


def test_at_least_message_names_estimate_interval_confidence_and_episodes():
    estimate = Estimate(0.625, 0.541, 0.703, 128, 0.95, "stratified bootstrap", percent=True)
    decision = at_least(estimate, 0.70, "goal rate")
    assert not decision.passed
    assert decision.message == (
        "goal rate 62.5 % [54.1, 70.3] (95 % stratified bootstrap CI, 128 episodes) is not >= 70 %"
    )


def test_at_most_uses_the_upper_bound():
    # 12 collisions in 400 episodes: 3 %, but the interval reaches above 4 %.
    collided = np.arange(400) < 12
    estimate = rate_interval(collided, resamples=2000)
    assert estimate.point == 0.03 and estimate.high > 0.04
    decision = at_most(estimate, 0.04, "collision rate")
    assert not decision.passed
    assert decision.message.startswith("collision rate 3.0 % [")
    assert "400 episodes) is not <= 4 % (the interval includes 4 %)" in decision.message
    assert at_most(estimate, estimate.high, "collision rate").passed


def test_a_real_rate_decision_passes_and_fails_on_its_interval():
    goal = np.random.default_rng(0).random(300) < 0.8
    estimate = rate_interval(goal, np.arange(300) % 3, resamples=4000)
    assert at_least(estimate, estimate.low).passed
    assert not at_least(estimate, (estimate.low + estimate.point) / 2).passed
    assert estimate.point > (estimate.low + estimate.point) / 2


def test_beats_rules_can_disagree_and_the_rule_is_a_parameter():
    # A is a little better in 90 % of the episodes and much worse in the rest:
    # it usually wins (P(A > B) = 0.9) but is worse on average.
    rng = np.random.default_rng(2)
    b = rng.normal(0, 1, 400)
    a = np.where(np.arange(400) % 10 == 0, b - 5.0, b + 0.1)
    cmp = compare(a, b, np.arange(400) % 4, resamples=4000)
    by_improvement = beats(cmp, label="P(gnn > idm on return)")
    by_difference = beats(cmp, rule="difference")
    assert by_improvement.passed and not by_difference.passed
    assert by_improvement.message.startswith("P(gnn > idm on return) 0.9 [")
    assert "400 paired episodes) is > 0.5" in by_improvement.message
    assert by_difference.message.startswith("mean(A) - mean(B) -0.41 [")
    assert by_difference.message.endswith("is not > 0")
    with pytest.raises(ValueError, match="rule must be"):
        beats(cmp, rule="median")


def test_for_bools_both_beats_rules_agree_exactly():
    for seed in range(20):
        rng = np.random.default_rng(seed)
        a, b = rng.random(150) < 0.75, rng.random(150) < 0.65
        cmp = compare(a, b, rng.integers(0, 3, 150), resamples=2000, seed=seed)
        assert cmp.improvement.low == pytest.approx(0.5 + cmp.difference.low / 2)
        assert beats(cmp).passed == beats(cmp, rule="difference").passed
        assert cmp.difference.percent


def test_identical_policies_do_not_beat_each_other():
    x = np.random.default_rng(0).normal(size=200)
    for statistic in ("mean", "iqm"):
        cmp = compare(x, x.copy(), statistic=statistic, resamples=1000)
        assert cmp.improvement.point == cmp.improvement.low == cmp.improvement.high == 0.5
        assert not beats(cmp).passed and not beats(cmp, rule="difference").passed
        assert "only 0 episodes differ" in beats(cmp).message


# --- determinism and speed ------------------------------------------------------

def test_same_inputs_and_seed_give_the_same_numbers_bit_for_bit():
    rng = np.random.default_rng(7)
    n = 5000  # several chunks of resamples
    strata, scores, other = rng.integers(0, 5, n), rng.normal(size=n), rng.normal(size=n)
    goal = rng.random(n) < 0.6
    calls = [
        lambda seed: rate_interval(goal, strata, resamples=3000, seed=seed),
        lambda seed: score_interval(scores, strata, resamples=3000, seed=seed),
        lambda seed: score_interval(scores, strata, statistic="mean", resamples=3000, seed=seed),
        lambda seed: compare(scores, other, strata, resamples=3000, seed=seed),
        lambda seed: compare(scores, other, strata, statistic="iqm", resamples=3000, seed=seed),
    ]
    for call in calls:
        first, again, other_seed = call(0), call(0), call(1)
        assert first == again  # dataclass equality: every float identical
        assert first != other_seed


def test_one_stratum_equals_no_strata():
    x = np.random.default_rng(0).normal(size=300)
    assert score_interval(x, np.full(300, 4), resamples=2000) == score_interval(x, resamples=2000)
    assert score_interval(x, resamples=2000).method == "bootstrap"


def calls_made(fn) -> int:
    """How many Python and C functions ``fn`` calls: a count, unlike a time, is
    the same on a loaded CI worker as on a quiet machine."""
    count = 0

    def profile(frame, event, arg):
        nonlocal count
        if event in ("call", "c_call"):
            count += 1

    sys.setprofile(profile)
    try:
        fn()
    finally:
        sys.setprofile(None)
    return count


def test_ten_thousand_resamples_are_vectorised_not_looped():
    # A fall back to one Python iteration per resample would make at least one
    # call per resample; the vectorised paths make about a hundred per chunk of
    # resamples (a chunk holds ~16 MB of draws: 50 chunks here).
    rng = np.random.default_rng(0)
    n, resamples = 10_000, 10_000
    strata, scores, goal = rng.integers(0, 8, n), rng.normal(size=n), rng.random(n) < 0.7
    other = rng.random(n) < 0.6
    for fn in (lambda: rate_interval(goal, strata, resamples=resamples),
               lambda: compare(goal, other, strata, resamples=resamples),
               lambda: score_interval(scores, strata, statistic="mean", resamples=resamples),
               lambda: score_interval(scores, strata, resamples=resamples)):
        assert calls_made(fn) < resamples


# --- edge cases -----------------------------------------------------------------

@pytest.mark.parametrize(
    "call",
    [
        lambda: rate_interval(np.array([], dtype=bool)),
        lambda: score_interval([]),
        lambda: compare([], []),
    ],
)
def test_no_episodes_is_a_clear_error(call):
    with pytest.raises(ValueError, match="no episodes"):
        call()


@pytest.mark.parametrize("k", [0, 50])
def test_all_the_same_outcome_falls_back_to_wilson(k):
    x = np.arange(50) < k
    estimate = rate_interval(x, np.arange(50) % 5)
    ci = stats.binomtest(k, 50).proportion_ci(0.95, method="wilson")
    assert estimate.method == "Wilson"
    assert (estimate.low, estimate.high) == (ci.low, ci.high)
    assert estimate.low < estimate.high  # not a point
    assert "all 50 episodes have the same outcome" in estimate.note
    # Wilson's lower bound for 50 of 50 is 92.9 %.
    assert not at_least(estimate, 0.95, "goal rate").passed
    decision = at_least(estimate, 0.90, "goal rate")
    assert decision.passed is (k == 50)
    assert "(95 % Wilson CI, 50 episodes)" in decision.message
    assert "same outcome" in decision.message


def test_few_of_one_outcome_falls_back_and_clopper_pearson_is_an_option():
    x = np.arange(200) < 196  # 4 failures
    assert rate_interval(x).method == "Wilson"
    assert "only 4 episodes have the rarer outcome" in rate_interval(x).note
    exact = rate_interval(x, fallback="clopper-pearson")
    ci = stats.binomtest(196, 200).proportion_ci(0.95, method="exact")
    assert exact.method == "Clopper-Pearson" and (exact.low, exact.high) == (ci.low, ci.high)
    # With 10 of each outcome the bootstrap is used.
    assert rate_interval(np.arange(200) < 190).method == "bootstrap"


def test_single_episode_scores_and_equal_scores_say_the_interval_is_a_point():
    assert score_interval([3.0]).low == score_interval([3.0]).high == 3.0
    same = score_interval(np.full(40, 2.0))
    assert (same.low, same.point, same.high) == (2.0, 2.0, 2.0)
    assert "same score" in same.note
    assert "only 12 episodes" in score_interval(np.arange(12.0)).note


@pytest.mark.parametrize(
    ("call", "match"),
    [
        (lambda: rate_interval([0, 1, 2]), "booleans"),
        (lambda: score_interval([1.0, np.nan]), "episode 1 is not finite"),
        (lambda: score_interval([[1.0, 2.0]]), "1-D"),
        (lambda: compare([1, 2, 3], [1, 2]), "same episodes"),
        (lambda: score_interval([1.0, 2.0], strata=[0]), "one label per episode"),
        (lambda: score_interval([1.0, 2.0], confidence=95), "between 0 and 1"),
        (lambda: score_interval([1.0, 2.0], resamples=0), "positive integer"),
        (lambda: score_interval([1.0, 2.0], statistic="median"), "'mean' or 'iqm'"),
    ],
)
def test_bad_input_is_refused_with_the_reason(call, match):
    with pytest.raises(ValueError, match=match):
        call()
