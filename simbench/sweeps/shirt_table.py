"""The colour shirt's seed table (issue 18): full method against baseline, seed by seed.

Reads the results databases of seed sweeps (``scenarios/sweeps/shirt_seeds_*.toml``, one
factor ``seed``) and gives, per scenario, every seed's upper-body joint RMSE of both
methods and the figures issue 18 accepts on: the full method's median, the share of
seeds where it is at most 4 cm, and the share where it is at least 20 % better than the
baseline (``shirt.joint_rmse_cm <= 0.8 * shirt.baseline_joint_rmse_cm``).

Regenerate::

    simbench sweep scenarios/sweeps/shirt_seeds_office.toml -j 2 --no-outputs   # and _outdoor, _tungsten_off
    simbench shirt seed-table out/sweeps/shirt_seeds_*/results.duckdb
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from eval.seed_stats import A_BETTER, B_BETTER, PairedComparison, paired_comparison
from simbench.errors import SimbenchInputError
from simbench.sweeps.results_db import STATUS_OK, ResultsDB

__all__ = ["SeedRow", "ScenarioSummary", "read_seed_rows", "summarise", "seed_table_markdown"]

FULL = "shirt.joint_rmse_cm"
BASELINE = "shirt.baseline_joint_rmse_cm"
GOOD_CM = 4.0          # a seed is "good" at or below this joint RMSE
BETTER_RATIO = 0.8     # "at least 20 % better than the baseline"


@dataclass(frozen=True)
class SeedRow:
    """One finished run: the scenario, its seed and both methods' joint RMSE (cm); NaN when missing."""

    scenario: str
    seed: int
    full_cm: float
    baseline_cm: float


@dataclass(frozen=True)
class ScenarioSummary:
    """Issue 18's figures of one scenario over its seeds."""

    scenario: str
    n_seeds: int
    median_full_cm: float
    median_baseline_cm: float
    share_good: float          # seeds with full <= GOOD_CM
    share_better: float        # seeds with full <= BETTER_RATIO * baseline
    worst_seed: int
    worst_full_cm: float
    comparison: PairedComparison | None = None   # full (B) against baseline (A) on the same seeds, as `simbench compare`


def read_seed_rows(db_paths: list[str | Path]) -> list[SeedRow]:
    """Every finished run with a ``seed`` factor and both shirt metrics, from each results database.

    Raises
    ------
    SimbenchInputError
        A path that is not a results database, or a database without such runs.
    """
    rows: list[SeedRow] = []
    for path in db_paths:
        path = Path(path)
        if not path.is_file():
            raise SimbenchInputError(f"{path}: no results database there; run `simbench sweep scenarios/sweeps/shirt_seeds_<scenario>.toml` first")
        wide = ResultsDB(path).metrics_wide()
        need = {"seed", FULL, BASELINE}
        if not need <= set(wide.columns):
            raise SimbenchInputError(f"{path}: no colour-shirt seed runs in it (needs a `seed` factor and the metrics {FULL}, {BASELINE})")
        ok = wide[wide["status"] == STATUS_OK]
        for _, r in ok.iterrows():
            rows.append(SeedRow(str(r["scenario"]), int(r["seed"]), float(r[FULL]), float(r[BASELINE])))
    if not rows:
        raise SimbenchInputError(f"{', '.join(map(str, db_paths))}: no finished runs yet")
    return sorted(rows, key=lambda r: (r.scenario, r.seed))


def summarise(rows: list[SeedRow]) -> list[ScenarioSummary]:
    """Per scenario (in name order): median, share at most 4 cm, share 20 % better than the baseline, worst seed."""
    out = []
    for name in sorted({r.scenario for r in rows}):
        rs = [r for r in rows if r.scenario == name]
        full = np.array([r.full_cm for r in rs])
        base = np.array([r.baseline_cm for r in rs])
        w = int(np.nanargmax(full))
        # The same paired statistics as `simbench compare` (Wilcoxon, bootstrap CI of the mean
        # difference, verdict, detectable effect), with the baseline as A and the full method as B.
        cmp = paired_comparison(base, full, better="lower", rng=np.random.default_rng(0))
        out.append(ScenarioSummary(name, len(rs), float(np.nanmedian(full)), float(np.nanmedian(base)),
                                   float(np.mean(full <= GOOD_CM)), float(np.mean(full <= BETTER_RATIO * base)),
                                   rs[w].seed, float(full[w]), cmp))
    return out


def _verdict(v: str) -> str:
    """`compare`'s verdict with A and B named (A: baseline, B: full method)."""
    return {A_BETTER: "baseline better", B_BETTER: "full better"}.get(v, v)


def _cell(r: SeedRow | None) -> str:
    if r is None:
        return ""
    bold = "**" if not (r.full_cm <= GOOD_CM) else ""
    b = "nan" if math.isnan(r.baseline_cm) else f"{r.baseline_cm:.2f}"
    return f"{bold}{r.full_cm:.2f}{bold} / {b}"


def is_seed_table(path: Path) -> bool:
    """Whether the file at ``path`` is a seed table as :func:`seed_table_markdown` writes it."""
    with open(path, encoding="utf-8", errors="replace") as fh:
        return fh.read(9) == "| seed | "


def seed_table_markdown(rows: list[SeedRow], summaries: list[ScenarioSummary] | None = None) -> str:
    """Seeds down, scenarios across, ``full / baseline`` joint RMSE (cm) per cell (bold: full above 4 cm),
    then the summary rows."""
    summaries = summaries if summaries is not None else summarise(rows)
    names = [s.scenario for s in summaries]
    by = {(r.scenario, r.seed): r for r in rows}
    seeds = sorted({r.seed for r in rows})
    lines = ["| seed | " + " | ".join(names) + " |", "|---:|" + "---:|" * len(names)]
    for sd in seeds:
        lines.append(f"| {sd} | " + " | ".join(_cell(by.get((n, sd))) for n in names) + " |")
    lines.append("| seeds | " + " | ".join(str(s.n_seeds) for s in summaries) + " |")
    lines.append("| median | " + " | ".join(f"{s.median_full_cm:.2f} / {s.median_baseline_cm:.2f}" for s in summaries) + " |")
    lines.append(f"| full <= {GOOD_CM:g} cm | " + " | ".join(f"{100 * s.share_good:.0f} %" for s in summaries) + " |")
    lines.append(f"| full >= {100 * (1 - BETTER_RATIO):.0f} % better | " + " | ".join(f"{100 * s.share_better:.0f} %" for s in summaries) + " |")
    lines.append("| worst seed | " + " | ".join(f"{s.worst_seed} ({s.worst_full_cm:.2f})" for s in summaries) + " |")
    if all(s.comparison is not None for s in summaries):
        lines.append("| full - baseline, mean (95 % CI) | " + " | ".join(
            f"{s.comparison.diff_mean:+.2f} ({s.comparison.ci_low:+.2f}..{s.comparison.ci_high:+.2f})" for s in summaries) + " |")
        lines.append("| Wilcoxon p, verdict | " + " | ".join(
            f"{s.comparison.p_value:.2g}, {_verdict(s.comparison.verdict)}" for s in summaries) + " |")
    return "\n".join(lines) + "\n"
