"""Statistics of a metric across seeds: arrays in, small dataclasses out.

Nothing here knows about scenarios or the simulator; :mod:`simbench.sweeps.seeds` (``simbench
run --seeds``), :mod:`simbench.sweeps.compare` (``simbench compare``), the regression gate
(:mod:`simbench.sweeps.regression`) and the tracker study use it.

* :func:`bootstrap_summary`: per-seed values -> mean, median, SD and a bootstrap confidence
  interval of the mean (``scipy.stats.bootstrap``, BCa, percentile where BCa is undefined);
* :func:`paired_comparison`: two configurations on the same seeds -> the paired differences'
  mean with its bootstrap interval, the Wilcoxon signed-rank test (``scipy.stats.wilcoxon``),
  a verdict that respects which direction is better, and the smallest effect the number of
  seeds can detect;
* :func:`shift_test`: a one-sided test that ``current`` is worse than ``baseline`` (two
  independent seed sets; ``scipy.stats.mannwhitneyu``) with a practical-effect floor, and
  :func:`holm` to correct a family of such tests.

Every resampling takes an explicit ``numpy.random.Generator`` (the same inputs and seed
give the same interval). NaN values (a metric a seed could not compute) are counted and
left out of summaries; the gate counts them as the worst value instead (a metric that can
no longer be computed has regressed).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from typing import Literal

import numpy as np
from scipy import stats

Better = Literal["lower", "higher"]
#: Verdicts of :func:`paired_comparison`.
A_BETTER, B_BETTER, NO_DIFFERENCE = "A better", "B better", "no detectable difference at this N"
#: The verdict when the pairs' ranks move one way (signed-rank p < alpha) while the mean difference's
#: interval still holds 0 (an outlying pair against the rest).  The reverse (an interval off 0 without
#: a significant test) stays "no detectable difference": with few pairs the bootstrap is overconfident.
MIXED = "mixed: most seeds differ one way, the mean's interval holds 0"
DEFAULT_RESAMPLES = 9999


def _rng(rng: np.random.Generator | int | None) -> np.random.Generator:
    if isinstance(rng, np.random.Generator):
        return rng
    return np.random.default_rng(0 if rng is None else rng)


@dataclass(frozen=True)
class SeedSummary:
    """One metric over ``n`` seeds (``values`` in seed order, NaN where a seed had none).

    ``ci_low``/``ci_high`` bound the mean at ``confidence`` (NaN with fewer than two finite
    values; equal to the value when every seed gave the same number). ``ci_method`` says how
    the interval was made: ``BCa``, ``percentile``, ``constant`` or ``none``."""

    values: tuple[float, ...]
    n_finite: int
    mean: float
    median: float
    sd: float
    ci_low: float
    ci_high: float
    confidence: float
    ci_method: str

    @property
    def n(self) -> int:
        return len(self.values)

    @property
    def n_nan(self) -> int:
        return self.n - self.n_finite

    def to_json(self) -> dict:
        f = lambda v: None if not math.isfinite(v) else float(v)  # noqa: E731 (JSON has no NaN)
        return {"values": [f(v) for v in self.values], "n": self.n, "n_nan": self.n_nan, "mean": f(self.mean),
                "median": f(self.median), "sd": f(self.sd), f"ci{round(100 * self.confidence)}": [f(self.ci_low), f(self.ci_high)],
                "ci_method": self.ci_method}


def mean_ci(x: np.ndarray, confidence: float = 0.95, rng: np.random.Generator | int | None = None,
            n_resamples: int = DEFAULT_RESAMPLES) -> tuple[float, float, str]:
    """Bootstrap confidence interval of the mean of the finite values of ``x`` (shape (n,)).

    ``(low, high, method)``: BCa from ``scipy.stats.bootstrap``; percentile where BCa is
    undefined (its jackknife degenerates on a few tied values); ``(v, v, "constant")`` when all
    values are equal (there is nothing to resample); NaN with ``"none"`` below two values."""
    x = np.asarray(x, float)
    x = x[np.isfinite(x)]
    if x.size < 2:
        return math.nan, math.nan, "none"
    if np.all(x == x[0]):
        return float(x[0]), float(x[0]), "constant"
    gen = _rng(rng)
    for method in ("BCa", "percentile"):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # DegenerateDataWarning: handled by the fallback below
            res = stats.bootstrap((x,), np.mean, confidence_level=confidence, n_resamples=n_resamples,
                                  method=method, rng=gen, vectorized=True)
        lo, hi = float(res.confidence_interval.low), float(res.confidence_interval.high)
        if math.isfinite(lo) and math.isfinite(hi):
            return lo, hi, method
    return math.nan, math.nan, "none"


def bootstrap_summary(values, confidence: float = 0.95, rng: np.random.Generator | int | None = None,
                      n_resamples: int = DEFAULT_RESAMPLES) -> SeedSummary:
    """Mean, median, SD (ddof 1) and bootstrap CI of the mean of one metric's per-seed ``values``."""
    v = np.asarray(values, float).reshape(-1)
    fin = v[np.isfinite(v)]
    nan = math.nan
    mean = float(fin.mean()) if fin.size else nan
    median = float(np.median(fin)) if fin.size else nan
    sd = nan if fin.size < 2 else 0.0 if np.all(fin == fin[0]) else float(fin.std(ddof=1))  # exact 0 for a constant
    lo, hi, method = mean_ci(fin, confidence, rng, n_resamples)
    return SeedSummary(tuple(float(x) for x in v), int(fin.size), mean, median, sd, lo, hi, confidence, method)


# ---------------------------------------------------------------------------- paired comparison
@dataclass(frozen=True)
class PairedComparison:
    """B against A on the same seeds: ``diff = b - a`` per seed where both are finite.

    ``p_value`` is the two-sided Wilcoxon signed-rank test of the differences (1.0 when every
    difference is zero; NaN below two pairs). ``detectable`` is the smallest mean difference
    this number of pairs detects at ``alpha`` (two-sided) with ``power``, from the paired
    differences' SD (t approximation: ``(t_{1-alpha/2} + t_power) * sd / sqrt(n)`` on n-1
    degrees of freedom; the Wilcoxon test's efficiency relative to it is 0.955 for normal
    differences, so it needs about 5 % more pairs)."""

    a_mean: float
    b_mean: float
    n_pairs: int
    diff_mean: float
    diff_median: float
    diff_sd: float
    ci_low: float
    ci_high: float
    confidence: float
    p_value: float
    better: Better
    verdict: str
    detectable: float
    diffs: tuple[float, ...]

    def to_json(self) -> dict:
        f = lambda v: None if not math.isfinite(v) else float(v)  # noqa: E731
        return {"a_mean": f(self.a_mean), "b_mean": f(self.b_mean), "n_pairs": self.n_pairs, "diff_mean": f(self.diff_mean),
                "diff_median": f(self.diff_median), "diff_sd": f(self.diff_sd),
                f"diff_ci{round(100 * self.confidence)}": [f(self.ci_low), f(self.ci_high)], "wilcoxon_p": f(self.p_value),
                "better": self.better, "verdict": self.verdict, "detectable_effect": f(self.detectable),
                "diffs": [f(d) for d in self.diffs]}


def detectable_effect(sd: float, n: int, alpha: float = 0.05, power: float = 0.8) -> float:
    """Smallest mean paired difference detectable with ``n`` pairs of differences of SD ``sd``
    (two-sided ``alpha``, ``power``; t approximation). 0 when ``sd`` is 0, NaN below two pairs."""
    if n < 2 or not math.isfinite(sd):
        return math.nan
    df = n - 1
    return float((stats.t.ppf(1 - alpha / 2, df) + stats.t.ppf(power, df)) * sd / math.sqrt(n))


def paired_comparison(a, b, better: Better, alpha: float = 0.05, power: float = 0.8, confidence: float = 0.95,
                      rng: np.random.Generator | int | None = None, n_resamples: int = DEFAULT_RESAMPLES) -> PairedComparison:
    """Compare configuration B with A on the same seeds (``a[i]``, ``b[i]``: seed i).

    Verdict: "A better" / "B better" when the Wilcoxon p-value is below ``alpha`` and the
    bootstrap CI of the mean difference excludes 0 (``better`` says whether lower or higher
    values are better); :data:`MIXED` when the test is significant but the interval holds 0
    (e.g. 19 seeds a little better and one far worse); else "no detectable difference at this N"."""
    if better not in ("lower", "higher"):
        raise ValueError(f"better must be 'lower' or 'higher', got {better!r}")
    a, b = np.asarray(a, float).reshape(-1), np.asarray(b, float).reshape(-1)
    if a.shape != b.shape:
        raise ValueError(f"a and b need one value per seed each, got {a.shape} and {b.shape}")
    ok = np.isfinite(a) & np.isfinite(b)
    d = b[ok] - a[ok]
    n = int(d.size)
    nan = math.nan
    sd = float(d.std(ddof=1)) if n > 1 else nan
    lo, hi, _ = mean_ci(d, confidence, rng, n_resamples)
    if n < 2:
        p = nan
    elif np.all(d == 0):
        p = 1.0
    else:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # small-sample notes from scipy; the p-value is what we report
            p = float(stats.wilcoxon(d, zero_method="wilcox", alternative="two-sided").pvalue)
    ranks_say = math.isfinite(p) and p < alpha
    mean_says = math.isfinite(lo) and (lo > 0 or hi < 0)
    verdict = MIXED if ranks_say and not mean_says else NO_DIFFERENCE
    if ranks_say and mean_says:
        b_higher = lo > 0
        verdict = B_BETTER if b_higher == (better == "higher") else A_BETTER
    return PairedComparison(float(a[ok].mean()) if n else nan, float(b[ok].mean()) if n else nan, n,
                            float(d.mean()) if n else nan, float(np.median(d)) if n else nan, sd, lo, hi, confidence, p,
                            better, verdict, detectable_effect(sd, n, alpha, power), tuple(float(x) for x in d))


# ---------------------------------------------------------------------------- regression gate
Worse = Literal["higher", "lower"]


@dataclass(frozen=True)
class ShiftTest:
    """One-sided test that ``current`` is worse than ``baseline`` (independent seed sets).

    ``p_value``: Mann-Whitney U, alternative "current worse". ``shift``: median(current) -
    median(baseline), signed so that positive is worse (NaN counted as the worst value).
    """

    p_value: float
    shift: float
    n_baseline: int
    n_current: int
    baseline_median: float
    current_median: float


def _worst_for_nan(x: np.ndarray, worse: Worse) -> np.ndarray:
    return np.where(np.isfinite(x), x, np.inf if worse == "higher" else -np.inf)


def shift_test(baseline, current, worse: Worse) -> ShiftTest:
    """One-sided Mann-Whitney U test that ``current`` is worse than ``baseline``.

    A NaN (the metric could not be computed on that seed) ranks as the worst value on either
    side, so more NaNs than the baseline had is a regression. p = 1.0 when both samples are one
    constant (no evidence); NaN when either sample is empty."""
    if worse not in ("higher", "lower"):
        raise ValueError(f"worse must be 'higher' or 'lower', got {worse!r}")
    b = _worst_for_nan(np.asarray(baseline, float).reshape(-1), worse)
    c = _worst_for_nan(np.asarray(current, float).reshape(-1), worse)
    if b.size == 0 or c.size == 0:
        return ShiftTest(math.nan, math.nan, int(b.size), int(c.size), math.nan, math.nan)
    bm, cm = float(np.median(b)), float(np.median(c))
    with np.errstate(invalid="ignore"):
        shift = cm - bm if worse == "higher" else bm - cm
    if math.isnan(shift):  # both medians the same infinity: as bad as each other
        shift = 0.0
    both = np.concatenate([b, c])
    if np.all(both == both[0]):
        p = 1.0
    else:
        alt = "greater" if worse == "higher" else "less"
        # Ranks only: infinities (NaN seeds) are ranked as the worst values, which is what we want.
        finite_b, finite_c = _ranks_safe(b, c)
        p = float(stats.mannwhitneyu(finite_c, finite_b, alternative=alt, method="auto").pvalue)
    return ShiftTest(p, float(shift), int(b.size), int(c.size), bm, cm)


def _ranks_safe(b: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The two samples as joint ranks (Mann-Whitney depends on ranks only; scipy refuses infinities)."""
    r = stats.rankdata(np.concatenate([b, c]))
    return r[:b.size], r[b.size:]


def holm(p_values) -> np.ndarray:
    """Holm-Bonferroni adjusted p-values (same order as given; NaN stays NaN).

    Hand-written (six lines): scipy has only the Benjamini-Hochberg FDR procedure
    (``scipy.stats.false_discovery_control``), and the gate needs the family-wise rate;
    statsmodels' ``multipletests`` would add a dependency for this alone."""
    p = np.asarray(p_values, float).reshape(-1)
    out = np.full_like(p, np.nan)
    ok = np.flatnonzero(np.isfinite(p))
    m = ok.size
    order = ok[np.argsort(p[ok], kind="stable")]
    adj = np.minimum(1.0, np.maximum.accumulate((m - np.arange(m)) * p[order]))
    out[order] = adj
    return out
