"""Seed 000's four findings checked one by one, with confidence intervals: losses (Clopper-Pearson,
exact McNemar), prediction errors (Welch), the paper's own counts (Fisher)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.stats import binomtest, fisher_exact, ttest_ind

from simbench.studies.trackers.config import ERROR_CATEGORIES, PAPER_COST, PAPER_ERRORS, PAPER_LOSSES, PAPER_VIDEOS_PER_CATEGORY, SEED_TRACKERS
from simbench.studies.trackers.study import StudyResult


REPRODUCED = "reproduced"
NOT_REPRODUCED = "not reproduced"
UNDECIDED = "not decidable at this N"
#: Significance level of the findings' tests (the paper's 99 % intervals).
ALPHA = 0.01


@dataclass(frozen=True)
class LossRate:
    """Videos with a loss out of ``n`` and the binomial confidence interval of the
    proportion (Clopper-Pearson, ``scipy.stats.binomtest(...).proportion_ci``)."""

    k: int
    n: int
    lower: float
    upper: float
    level: float

    def __str__(self) -> str:
        return f"{self.k}/{self.n} [{self.lower * self.n:.1f}-{self.upper * self.n:.1f}]"


def loss_rate(k: int, n: int, level: float = 0.99) -> LossRate:
    """Binomial ``level`` interval of ``k`` losses in ``n`` videos (exact, Clopper-Pearson)."""
    if n <= 0:
        return LossRate(k, n, float("nan"), float("nan"), level)
    ci = binomtest(int(k), int(n)).proportion_ci(confidence_level=level, method="exact")
    return LossRate(int(k), int(n), float(ci.low), float(ci.high), level)


@dataclass(frozen=True)
class PairedLosses:
    """Two trackers on the same videos: losses of each, videos only ``a`` lost and only
    ``b`` lost, and the exact McNemar test (two-sided binomial test of the discordant
    videos, ``scipy.stats.binomtest``): ``direction`` +1 when ``a`` loses significantly
    more than ``b`` at ``alpha``, -1 when significantly fewer, 0 when undecided."""

    a: str
    b: str
    a_lost: LossRate
    b_lost: LossRate
    only_a: int
    only_b: int
    p_value: float
    direction: int

    def __str__(self) -> str:
        return (f"`{self.a}` {self.a_lost} vs `{self.b}` {self.b_lost} (only one lost: {self.only_a} / {self.only_b} "
                f"videos, McNemar p = {self.p_value:.2g})")


def _video_lost(result: StudyResult, name: str, categories: tuple[str, ...] | None = None) -> np.ndarray:
    return np.array([r.runs[name].lost for r in result.videos if categories is None or r.category in categories], dtype=bool)


def paired_losses(result: StudyResult, a: str, b: str, alpha: float = ALPHA,
                  categories: tuple[str, ...] | None = None) -> PairedLosses:
    """Exact McNemar test of trackers ``a`` and ``b`` over the study's videos (of
    ``categories``, default all)."""
    la, lb = _video_lost(result, a, categories), _video_lost(result, b, categories)
    n = len(la)
    only_a, only_b = int(np.sum(la & ~lb)), int(np.sum(lb & ~la))
    p = float(binomtest(only_a, only_a + only_b, 0.5).pvalue) if only_a + only_b else 1.0
    direction = 0 if p >= alpha else (1 if only_a > only_b else -1)
    level = result.config.confidence
    return PairedLosses(a, b, loss_rate(int(la.sum()), n, level), loss_rate(int(lb.sum()), n, level),
                        only_a, only_b, p, direction)


def compare_errors(result: StudyResult, category: str, a: str, b: str, alpha: float = ALPHA) -> int | None:
    """+1 when ``a``'s mean prediction error in ``category`` is significantly larger
    than ``b``'s (Welch's t-test, ``alpha``), -1 when significantly smaller, 0 when
    undecided, None without samples (like the paper's t intervals, this treats the
    frames as independent)."""
    x, y = result.error_samples.get(category, {}).get(a), result.error_samples.get(category, {}).get(b)
    if x is None or y is None or len(x) < 2 or len(y) < 2:
        return None
    p = float(ttest_ind(x, y, equal_var=False).pvalue)
    return 0 if not p < alpha else (1 if x.mean() > y.mean() else -1)


def paper_losses_differ(a: str, b: str, alpha: float = ALPHA) -> tuple[float, int]:
    """Could seed 000's own Table I tell ``a`` from ``b``? Fisher's exact test of their
    total losses (100 videos each; the paper gives no per-video results, so the test
    cannot be paired): (p, +1 / -1 / 0 as in :class:`PairedLosses`)."""
    ka = sum(PAPER_LOSSES[c][a] for c in PAPER_LOSSES)
    kb = sum(PAPER_LOSSES[c][b] for c in PAPER_LOSSES)
    n = PAPER_VIDEOS_PER_CATEGORY * len(PAPER_LOSSES)
    p = float(fisher_exact([[ka, n - ka], [kb, n - kb]]).pvalue)
    return p, 0 if p >= alpha else (1 if ka > kb else -1)


@dataclass(frozen=True)
class Finding:
    """One of seed 000's findings checked on the bench: the claim, the verdict
    (:data:`REPRODUCED`, :data:`NOT_REPRODUCED`, :data:`UNDECIDED`), the bench's figures
    behind it and what seed 000's own figures can say."""

    claim: str
    verdict: str
    figures: str
    paper: str


def _combine(parts: list[int | None]) -> str:
    """Verdict of a claim made of parts each +1 (holds, significantly), -1 (the opposite
    holds, significantly), 0 (undecided) or None (no data)."""
    if any(p == -1 for p in parts):
        return NOT_REPRODUCED
    if parts and all(p == 1 for p in parts):
        return REPRODUCED
    return UNDECIDED


def _paper_total(name: str) -> str:
    """Seed 000's Table I total of a tracker, 'k/n'."""
    return f"{sum(PAPER_LOSSES[c][name] for c in PAPER_LOSSES)}/{PAPER_VIDEOS_PER_CATEGORY * len(PAPER_LOSSES)}"


def _paper_apart(category: str, low: str, high: str) -> bool:
    """Seed 000's 99 % intervals of ``low`` and ``high`` in ``category`` do not overlap,
    ``low`` below."""
    return PAPER_ERRORS[category][low][3] < PAPER_ERRORS[category][high][1]


def _fitted_only(result: StudyResult, pairs: list[tuple[str, str]], alpha: float) -> str:
    """The same paired loss tests on the fitted categories alone (slow, rapid,
    acceleration): occlusion and swap difficulty is not calibrated."""
    cats = tuple(c for c in ERROR_CATEGORIES if c in result.losses)
    if not cats or len(cats) == len(result.losses):
        return ""
    tests = [paired_losses(result, a, b, alpha, cats) for a, b in pairs]
    return (f" Fitted categories alone ({', '.join(cats)}): "
            + "; ".join(f"`{t.a}` {t.a_lost.k} vs `{t.b}` {t.b_lost.k} of {t.a_lost.n} (p = {t.p_value:.2g})" for t in tests) + ".")


def _err(result: StudyResult, c: str, n: str) -> str:
    s = result.errors.get(c, {}).get(n)
    return "n/a" if s is None or not s.n else f"{s.interval.mean:.1f} [{s.interval.lower:.1f}-{s.interval.upper:.1f}]"


def findings(result: StudyResult, alpha: float = ALPHA) -> list[Finding]:
    """Seed 000's four findings, each checked on the study's videos (module docstring)."""
    ab, km, cd = SEED_TRACKERS
    names = set(result.trackers)
    out: list[Finding] = []
    have = {ab, km, cd} <= names
    cats = [c for c in ERROR_CATEGORIES if c in result.errors]
    if not have:
        miss = ", ".join(f"`{n}`" for n in SEED_TRACKERS if n not in names)
        return [Finding(claim, UNDECIDED, f"{miss} not run", "") for claim in (
            "alpha-beta has the lowest prediction error but the most losses", "Kalman gives the best overall results",
            "CONDENSATION has the highest prediction error", "a search area that grows with uncertainty reduces losses")]
    err_txt = "; ".join(f"{c} {_err(result, c, ab)} / {_err(result, c, km)} / {_err(result, c, cd)} px" for c in cats)
    paper_err = "; ".join(f"{c} " + " / ".join(f"{PAPER_ERRORS[c][n][2]:.1f} [{PAPER_ERRORS[c][n][1]:.1f}-"
                                               f"{PAPER_ERRORS[c][n][3]:.1f}]" for n in SEED_TRACKERS) for c in cats)

    # 1. alpha-beta: lowest error, most losses.
    lowest = [None if d is None else -d for d in (compare_errors(result, c, ab, o, alpha) for c in cats for o in (km, cd))]
    most = [paired_losses(result, ab, o, alpha) for o in (km, cd)]
    pf = [paper_losses_differ(ab, o, alpha) for o in (km, cd)]
    out.append(Finding(
        "alpha-beta has the lowest prediction error but the most losses",
        _combine(lowest + [m.direction for m in most]),
        f"mean error alpha-beta / Kalman / CONDENSATION, px, 99 % t interval: {err_txt}. "
        f"Losses (videos, 99 % binomial interval): " + "; ".join(str(m) for m in most) + "."
        + _fitted_only(result, [(ab, km), (ab, cd)], alpha),
        f"errors {paper_err} ("
        + ("intervals apart: lowest holds" if all(_paper_apart(c, ab, o) for c in cats for o in (km, cd))
           else "intervals overlap somewhere") + f"); losses {_paper_total(ab)} vs Kalman {_paper_total(km)} (Fisher p = {pf[0][0]:.2g}), "
        f"vs CONDENSATION {_paper_total(cd)} (p = {pf[1][0]:.2g}): " + ("decidable" if all(d == 1 for _, d in pf) else
                                                            "the paper's own counts cannot tell 'most' at 1 %") + "."))

    # 2. Kalman: best overall (fewest losses of the three).
    best = [paired_losses(result, km, o, alpha) for o in (ab, cd)]
    pk = [paper_losses_differ(km, o, alpha) for o in (ab, cd)]
    out.append(Finding(
        "Kalman gives the best overall results (fewest losses of the three)",
        _combine([-b.direction for b in best]),
        "; ".join(str(b) for b in best) + "." + _fitted_only(result, [(km, ab), (km, cd)], alpha),
        f"{_paper_total(km)} vs alpha-beta {_paper_total(ab)} (Fisher p = {pk[0][0]:.2g}), vs CONDENSATION "
        f"{_paper_total(cd)} (p = {pk[1][0]:.2g})" + (
            "." if all(d == -1 for _, d in pk) else ": not significant at 1 % on the paper's own counts.")))

    # 3. CONDENSATION: highest prediction error.
    highest = [compare_errors(result, c, cd, o, alpha) for c in cats for o in (ab, km)]
    out.append(Finding(
        "CONDENSATION has the highest prediction error",
        _combine(highest),
        f"mean error alpha-beta / Kalman / CONDENSATION: {err_txt}.",
        f"{paper_err}: " + ("intervals apart, holds in every table." if all(_paper_apart(c, o, cd) for c in cats for o in (ab, km))
                            else "intervals overlap somewhere.")))

    # 4. A search area that grows with uncertainty reduces losses: the same alpha-beta
    # filter with a fixed circle and with one that grows with its residuals and speed.
    adaptive = "alpha_beta_adaptive"
    if adaptive in names:
        pair = paired_losses(result, adaptive, ab, alpha)
        others = [paired_losses(result, o, ab, alpha) for o in (km, cd)]
        out.append(Finding(
            "a search area that grows with uncertainty reduces losses",
            _combine([-pair.direction]),
            f"same alpha-beta filter, growing vs fixed circle: {pair}. Seed 000's own comparison (Kalman, "
            f"CONDENSATION: growing areas, vs alpha-beta: fixed): " + "; ".join(str(o) for o in others) + "."
            + _fitted_only(result, [(adaptive, ab)], alpha),
            f"no controlled comparison (the trackers differ in more than the search area); Kalman {_paper_total(km)} "
            f"and CONDENSATION {_paper_total(cd)} vs alpha-beta {_paper_total(ab)} videos lost."))
    else:
        out.append(Finding("a search area that grows with uncertainty reduces losses", UNDECIDED,
                           f"`{adaptive}` (the controlled comparison) not run", ""))
    return out


def format_findings(result: StudyResult) -> str:
    """The findings table, one line each: claim, verdict, the bench's figures, seed 000's."""
    lines = ["| seed 000's finding | verdict on the bench | bench figures | seed 000's own figures |", "|---|---|---|---|"]
    for f in findings(result):
        lines.append(f"| {f.claim} | **{f.verdict}** | {f.figures} | {f.paper} |")
    return "\n".join(lines)


def cost_ratios(result: StudyResult) -> dict[str, tuple[float, float | None]]:
    """Per tracker: median per-frame cost at the most markers over that at the fewest
    (30 and 1 by default), and the paper's same ratio (None for trackers it lacks)."""
    out = {}
    for n in result.trackers:
        rows = {r.n_markers: r for r in result.cost.rows if r.tracker == n}
        if len(rows) < 2:
            continue
        lo, hi = min(rows), max(rows)
        paper = PAPER_COST.get(n, {})
        out[n] = (rows[hi].median_ms / rows[lo].median_ms,
                  paper[hi][1] / paper[lo][1] if lo in paper and hi in paper else None)
    return out


def format_cost_ratios(result: StudyResult) -> str:
    """Markdown table of :func:`cost_ratios`."""
    counts = sorted({r.n_markers for r in result.cost.rows})
    lo, hi = counts[0], counts[-1]
    lines = [f"| tracker | median cost at {hi} markers / at {lo} (bench) | seed 000 |", "|---|---:|---:|"]
    for n, (ours, paper) in cost_ratios(result).items():
        lines.append(f"| {n} | {ours:.1f} | {'-' if paper is None else f'{paper:.1f}'} |")
    return "\n".join(lines)
