"""eval.seed_stats against known values: bootstrap summaries (N=1, constants, NaNs, coverage),
the paired comparison's verdicts and detectable effect, the one-sided shift test and Holm."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats

from eval import seed_stats as ss


def test_summary_of_known_values_and_determinism():
    s = ss.bootstrap_summary([1.0, 2.0, 3.0, 4.0, 5.0], rng=1)
    assert (s.mean, s.median, s.n, s.n_nan) == (3.0, 3.0, 5, 0)
    assert s.sd == pytest.approx(math.sqrt(2.5))
    assert 1.0 < s.ci_low < 3.0 < s.ci_high < 5.0 and s.ci_method == "BCa"
    again = ss.bootstrap_summary([1.0, 2.0, 3.0, 4.0, 5.0], rng=1)
    assert (again.ci_low, again.ci_high) == (s.ci_low, s.ci_high)  # same values, same generator: same interval


def test_one_seed_constant_values_and_nans_are_explicit():
    one = ss.bootstrap_summary([2.5])
    assert one.mean == one.median == 2.5 and math.isnan(one.sd) and math.isnan(one.ci_low) and one.ci_method == "none"
    const = ss.bootstrap_summary([0.0, 0.0, 0.0, 0.0])
    assert (const.ci_low, const.ci_high, const.sd, const.ci_method) == (0.0, 0.0, 0.0, "constant")
    with_nan = ss.bootstrap_summary([1.0, np.nan, 3.0])
    assert (with_nan.n, with_nan.n_finite, with_nan.n_nan, with_nan.mean) == (3, 2, 1, 2.0)
    assert math.isnan(with_nan.values[1])
    none = ss.bootstrap_summary([np.nan, np.nan])
    assert none.n_finite == 0 and math.isnan(none.mean) and math.isnan(none.ci_low)
    js = with_nan.to_json()
    assert js["values"] == [1.0, None, 3.0] and js["n_nan"] == 1 and len(js["ci95"]) == 2


def test_interval_covers_the_true_mean_about_95_percent_of_the_time():
    rng = np.random.default_rng(7)
    hits = 0
    trials = 200
    for _ in range(trials):
        s = ss.bootstrap_summary(rng.normal(10.0, 2.0, 20), rng=rng, n_resamples=999)
        hits += s.ci_low <= 10.0 <= s.ci_high
    assert 0.88 <= hits / trials <= 0.99  # nominal 0.95 (BCa is slightly liberal at n = 20)


@pytest.mark.parametrize("better, shift, verdict", [
    ("lower", +0.5, ss.A_BETTER),   # B higher, lower is better: A better
    ("lower", -0.5, ss.B_BETTER),
    ("higher", +0.5, ss.B_BETTER),
    ("higher", -0.5, ss.A_BETTER),
    ("lower", 0.0, ss.NO_DIFFERENCE),
])
def test_paired_verdict_respects_the_metrics_direction(better, shift, verdict):
    rng = np.random.default_rng(3)
    a = rng.normal(5.0, 1.0, 20)  # large spread across seeds, small paired noise: pairing detects the shift
    b = a + shift + rng.normal(0.0, 0.1, 20)
    r = ss.paired_comparison(a, b, better, rng=0)
    assert r.verdict == verdict
    assert r.n_pairs == 20 and r.diff_mean == pytest.approx(np.mean(b - a))
    assert r.ci_low <= r.diff_mean <= r.ci_high
    assert r.p_value == pytest.approx(stats.wilcoxon(b - a).pvalue)


def test_paired_verdict_is_mixed_when_the_ranks_and_the_mean_disagree():
    # 19 seeds 0.1 lower under B, one 5 higher: the signed-rank test says B lower (p < 0.001),
    # the mean difference (+0.16) has an interval that holds 0; neither "B better" nor "no difference"
    rng = np.random.default_rng(0)
    a = rng.normal(5.0, 1.0, 20)
    d = -0.1 + rng.normal(0.0, 0.02, 20)
    d[7] = 5.0
    r = ss.paired_comparison(a, a + d, "lower", rng=0)
    assert r.p_value < 0.001 and r.ci_low < 0.0 < r.ci_high
    assert r.verdict == ss.MIXED
    # without the outlier both criteria agree
    d[7] = -0.1
    assert ss.paired_comparison(a, a + d, "lower", rng=0).verdict == ss.B_BETTER


def test_detectable_effect_matches_the_t_power_formula_and_shrinks_with_n():
    sd = 0.3
    d20 = ss.detectable_effect(sd, 20)
    assert d20 == pytest.approx((stats.t.ppf(0.975, 19) + stats.t.ppf(0.8, 19)) * sd / math.sqrt(20))
    assert ss.detectable_effect(sd, 80) < d20 / 1.9
    assert math.isnan(ss.detectable_effect(sd, 1)) and ss.detectable_effect(0.0, 10) == 0.0
    # the power it promises: a shift of d20 is detected by a paired t-test about 80 % of the time
    rng = np.random.default_rng(11)
    hits = sum(stats.ttest_1samp(rng.normal(d20, sd, 20), 0.0).pvalue < 0.05 for _ in range(400))
    assert 0.72 <= hits / 400 <= 0.88


def test_paired_comparison_drops_pairs_with_a_nan_and_handles_identical_sides():
    a = np.array([1.0, 2.0, np.nan, 4.0])
    b = np.array([1.0, 2.0, 3.0, np.nan])
    r = ss.paired_comparison(a, b, "lower")
    assert r.n_pairs == 2 and r.p_value == 1.0 and r.verdict == ss.NO_DIFFERENCE and r.diff_sd == 0.0
    with pytest.raises(ValueError):
        ss.paired_comparison([1.0], [1.0, 2.0], "lower")
    with pytest.raises(ValueError):
        ss.paired_comparison([1.0], [2.0], "up")


def test_shift_test_is_one_sided_and_counts_nan_as_worst():
    base = np.linspace(1.0, 2.0, 20)
    worse = ss.shift_test(base, base[-5:] + 1.0, "higher")
    assert worse.p_value == pytest.approx(1 / math.comb(25, 5))  # exact: every current value above every baseline one
    assert worse.shift == pytest.approx(np.median(base[-5:] + 1.0) - np.median(base))
    better = ss.shift_test(base, base[:5] - 1.0, "higher")
    assert better.p_value > 0.99 and better.shift < 0
    # lower-is-worse metrics (reconstructed fraction): a drop is the regression
    assert ss.shift_test(base, base[:5] - 1.0, "lower").p_value < 1e-3
    # a metric that can no longer be computed ranks as the worst value
    nan_now = ss.shift_test(base, [np.nan] * 5, "higher")
    assert nan_now.p_value < 1e-3 and nan_now.shift == math.inf
    same = ss.shift_test([0.0] * 20, [0.0] * 5, "higher")
    assert same.p_value == 1.0 and same.shift == 0.0


def test_shift_test_false_alarm_rate_is_at_most_alpha_on_identical_distributions():
    rng = np.random.default_rng(5)
    p = np.array([ss.shift_test(rng.normal(size=24), rng.normal(size=8), "higher").p_value for _ in range(1000)])
    assert np.mean(p < 0.05) <= 0.065  # nominal 0.05
    assert np.mean(p < 0.01) <= 0.02


def test_holm_against_hand_computed_values():
    adj = ss.holm([0.01, 0.04, 0.03, np.nan, 0.005])
    # sorted 0.005, 0.01, 0.03, 0.04 times 4, 3, 2, 1 -> 0.02, 0.03, 0.06, 0.04 -> running max 0.02, 0.03, 0.06, 0.06
    np.testing.assert_allclose(adj[[4, 0, 2, 1]], [0.02, 0.03, 0.06, 0.06])
    assert math.isnan(adj[3])
    assert ss.holm([0.9, 0.8]).tolist() == [1.0, 1.0]
