"""``simbench compare``: two configurations on the same seeds, metric by metric.

What can be compared (each side's runs are paired by seed, or by sweep factors):

* one scenario with two sets of overrides (``--a FIELD=VALUE``, ``--b FIELD=VALUE``): e.g.
  two trackers or two pipelines;
* two scenario files (both on the same seeds: ``--seed-start`` or the first file's seed);
* two ``simbench run --seeds`` output folders (their ``metrics.json``), paired by seed;
* two results databases of ``simbench sweep`` (e.g. the same sweep run by two versions of
  the code), runs paired by their factor levels (the sweep's ``seed`` factor included).

For each metric: the paired differences ``B - A`` with a bootstrap CI of their mean, the
Wilcoxon signed-rank test, a verdict ("A better", "B better", "no detectable difference at
this N") in the metric's better direction, and the smallest effect the number of pairs can
detect (:func:`eval.seed_stats.paired_comparison`). A metric's direction comes from the
suites file's tolerances (``worse = "higher"``: lower is better); metrics whose tolerance
says ``either`` have no better direction, so their verdict says which side is higher.
"""

from __future__ import annotations

import fnmatch
import json
import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Callable

import numpy as np

from eval.seed_stats import MIXED, NO_DIFFERENCE, PairedComparison, paired_comparison
from simbench.errors import ScenarioError, SimbenchInputError
from simbench.output_dir import AtomicOutputDir
from simbench.scenario import Scenario
from simbench.sweeps.results_db import STATUS_OK, ResultsDB, RunRecord
from simbench.sweeps.seeds import (SEEDS_DIR, SeedsResult, metric_rng, per_seed_values, replicate_specs, run_specs,
                                   seed_dir_name, seed_list, summarise, write_seeds_outputs)

ALPHA, POWER = 0.05, 0.8


@dataclass(frozen=True)
class Side:
    """One configuration: its label and ``{metric: (n_pairs,) values}`` in pair order."""

    label: str
    values: dict[str, np.ndarray]
    failures: tuple[str, ...] = ()


@dataclass
class Comparison:
    a: Side
    b: Side
    pairs: list[str]  # what pairs them: "seed 3" or the factor levels
    rows: dict[str, PairedComparison] = field(default_factory=dict)
    directions: dict[str, str | None] = field(default_factory=dict)  # "lower"/"higher" is better, None: either

    def verdict(self, metric: str) -> str:
        r = self.rows[metric]
        if self.directions.get(metric) is not None or r.verdict in (NO_DIFFERENCE, MIXED):
            return r.verdict
        return "B higher" if r.ci_low > 0 else "B lower"  # no better direction: say which way it moved

    def to_json(self) -> dict:
        return {"a": self.a.label, "b": self.b.label, "pairs": self.pairs, "alpha": ALPHA, "power": POWER,
                "test": "Wilcoxon signed-rank (scipy.stats.wilcoxon, two-sided) on B - A per pair",
                "metrics": {m: {**r.to_json(), "better": self.directions.get(m), "verdict": self.verdict(m)}
                            for m, r in self.rows.items()},
                "failures": {"a": list(self.a.failures), "b": list(self.b.failures)}}


def direction_lookup(patterns: list[tuple[str, Any]]) -> Callable[[str], str | None]:
    """``metric -> "lower" | "higher" | None`` (which values are better) from tolerance patterns
    (``(fnmatch pattern, Tolerance)``, first match wins; ``worse = "higher"`` means lower is better)."""

    def better(metric: str) -> str | None:
        for pat, tol in patterns:
            if fnmatch.fnmatchcase(metric, pat):
                return {"higher": "lower", "lower": "higher"}.get(tol.worse)
        return None

    return better


def compare_sides(a: Side, b: Side, pairs: list[str], better: Callable[[str], str | None],
                  metrics: list[str] | None = None) -> Comparison:
    names = sorted(set(a.values) & set(b.values))
    if metrics:
        names = [m for m in names if any(fnmatch.fnmatchcase(m, p) for p in metrics)]
    cmp = Comparison(a, b, pairs)
    for m in names:
        d = better(m)
        cmp.directions[m] = d
        cmp.rows[m] = paired_comparison(a.values[m], b.values[m], better=d or "lower", alpha=ALPHA, power=POWER,
                                        rng=metric_rng(m))
    return cmp


# ---------------------------------------------------------------------------- running both sides
def run_two(sc_a: Scenario, sc_b: Scenario, n: int, start: int | None, labels: tuple[str, str],
            overrides: tuple[dict, dict], better: Callable[[str], str | None], metrics: list[str] | None = None,
            out: Path | None = None, workers: int | None = None, scheduler: str | None = None,
            on_record: Callable[[RunRecord], None] | None = None) -> Comparison:
    """Both configurations on the same ``n`` seeds, in one pool (2n runs), compared. With
    ``out``: each side's replicate folder (``OUT/a``, ``OUT/b``, :mod:`simbench.sweeps.seeds`'
    layout) and ``OUT/compare.json``, ``OUT/compare.md``, built atomically."""
    seeds = seed_list(sc_a, n, start)
    specs = (replicate_specs(sc_a, seeds, "compare:a", overrides[0], {"side": "a"})
             + replicate_specs(sc_b, seeds, "compare:b", overrides[1], {"side": "b"}))
    specs = [replace(s, index=i) for i, s in enumerate(specs)]
    pairs = [f"seed {s}" for s in seeds]

    def compared(tmp: Path | None) -> Comparison:
        dirs = ([str((tmp / side / SEEDS_DIR / seed_dir_name(s)).resolve()) for side in ("a", "b") for s in seeds]
                if tmp is not None else [None] * (2 * n))
        recs = run_specs(specs, dirs, workers, scheduler, on_record)
        sides = []
        for side, label, sc, part in (("a", labels[0], sc_a, recs[:n]), ("b", labels[1], sc_b, recs[n:])):
            fails = [(s, (r.error.splitlines() or ["failed"])[0]) for s, r in zip(seeds, part) if r.status != STATUS_OK]
            if tmp is not None:
                res = SeedsResult(sc.name, seeds, part, summarise(per_seed_values(part)), out / side, fails)
                (tmp / side).mkdir(exist_ok=True)
                write_seeds_outputs(tmp / side, sc, res)
            sides.append(Side(label, per_seed_values(part), tuple(f"seed {s}: {c}" for s, c in fails)))
        cmp = compare_sides(sides[0], sides[1], pairs, better, metrics)
        if tmp is not None:
            write_comparison(tmp, cmp)
        return cmp

    if out is None:
        return compared(None)
    with AtomicOutputDir(out, scenario=f"{sc_a.name} vs {sc_b.name}", kind="run") as tmp:
        return compared(tmp)


def write_comparison(folder: Path, cmp: Comparison) -> None:
    """``compare.json`` (every figure, per-pair differences) and ``compare.md`` (the table)."""
    (folder / "compare.json").write_text(json.dumps(cmp.to_json(), indent=2) + "\n")
    (folder / "compare.md").write_text("\n".join(["# simbench compare", ""] + comparison_lines(cmp)) + "\n")


# ---------------------------------------------------------------------------- stored results
def load_seed_folder(path: Path, label: str) -> tuple[Side, list[int]]:
    """A ``simbench run --seeds`` output folder: its per-seed values (``metrics.json``)."""
    mj = path / "metrics.json"
    try:
        data = json.loads(mj.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise ScenarioError(mj, "<file>", str(path), f"cannot read a `simbench run --seeds` metrics.json ({exc})") from None
    if not isinstance(data, dict) or not isinstance(data.get("seeds"), list) or not isinstance(data.get("metrics"), dict):
        raise ScenarioError(mj, "seeds", str(path), "not the metrics.json of `simbench run --seeds N` (no per-seed values); "
                            "run with --seeds")
    vals = {m: np.array([math.nan if v is None else float(v) for v in d["values"]]) for m, d in data["metrics"].items()}
    fails = tuple(f"seed {f.get('seed')}: {f.get('cause')}" for f in data.get("failed_seeds", []))
    return Side(label, vals, fails), [int(s) for s in data["seeds"]]


def paired_seed_folders(pa: Path, pb: Path) -> tuple[Side, Side, list[str]]:
    a, seeds_a = load_seed_folder(pa, str(pa))
    b, seeds_b = load_seed_folder(pb, str(pb))
    common = [s for s in seeds_a if s in seeds_b]
    if not common:
        raise SimbenchInputError(f"{pa} and {pb}: no seed in common (seeds {seeds_a} and {seeds_b}); "
                                 f"run both with the same --seeds and --seed-start")
    ia = [seeds_a.index(s) for s in common]
    ib = [seeds_b.index(s) for s in common]
    return (Side(a.label, {m: v[ia] for m, v in a.values.items()}, a.failures),
            Side(b.label, {m: v[ib] for m, v in b.values.items()}, b.failures), [f"seed {s}" for s in common])


def paired_databases(pa: Path, pb: Path, sweep: str | None = None) -> tuple[Side, Side, list[str]]:
    """Two results databases: runs paired by their factor levels (failed runs give NaN)."""
    sides = []
    for p in (pa, pb):
        if not p.is_file():
            raise ScenarioError(p, "<file>", str(p), "results database not found (written by `simbench sweep`)")
        df = ResultsDB(p).metrics_wide(sweep)
        runs = ResultsDB(p).runs(sweep)
        keys = [json.dumps(f, sort_keys=True, default=str) for f in runs["factors"]]
        metric_cols = [c for c in df.columns if "." in str(c) and c not in ("run_id",)]
        by_key = {k: df.set_index("run_id").loc[rid] for k, rid in zip(keys, runs["run_id"])}
        sides.append((by_key, metric_cols, runs))
    (ka, ma, ra), (kb, mb, rb) = sides
    common = [k for k in ka if k in kb]
    if not common:
        raise SimbenchInputError(f"{pa} and {pb}: no run with the same factor levels in both; compare databases of the "
                                 f"same sweep file")
    metrics = sorted(set(ma) & set(mb))

    def values(by_key) -> dict[str, np.ndarray]:
        out = {}
        for m in metrics:
            col = []
            for k in common:
                row = by_key[k]
                v = row.get(m, math.nan) if row.get("status") == STATUS_OK else math.nan
                col.append(float(v) if v is not None and v == v else math.nan)
            out[m] = np.array(col)
        return out

    fails = lambda r: tuple(f"run {rid}: {(str(e).splitlines() or [''])[0]}" for rid, st, e in  # noqa: E731
                            zip(r["run_id"], r["status"], r["error"]) if st != STATUS_OK)
    pairs = [", ".join(f"{k}={v}" for k, v in json.loads(k).items()) for k in common]
    return Side(str(pa), values(ka), fails(ra)), Side(str(pb), values(kb), fails(rb)), pairs


# ---------------------------------------------------------------------------- output
def _f(v: float, spec: str = ".4g") -> str:
    return "—" if not math.isfinite(v) else format(v, spec)


def comparison_lines(cmp: Comparison) -> list[str]:
    """A Markdown table of the comparison (also the report's body)."""
    lines = [f"A = {cmp.a.label}", f"B = {cmp.b.label}", "",
             f"{len(cmp.pairs)} pairs ({cmp.pairs[0]} .. {cmp.pairs[-1]}); difference = B - A; 95 % bootstrap CI of the mean "
             f"difference; Wilcoxon signed-rank p (two-sided); verdict at alpha {ALPHA}; detectable = the smallest mean "
             f"difference these pairs detect with power {POWER} (paired SD).", "",
             "| metric | better | A mean | B mean | B - A mean | 95 % CI | Wilcoxon p | verdict | detectable |",
             "|---|---|---|---|---|---|---|---|---|"]
    for m, r in cmp.rows.items():
        d = cmp.directions.get(m)
        lines.append(f"| `{m}` | {d or 'either'} | {_f(r.a_mean)} | {_f(r.b_mean)} | {_f(r.diff_mean, '+.4g')} | "
                     f"{_f(r.ci_low, '+.4g')} .. {_f(r.ci_high, '+.4g')} | {_f(r.p_value, '.3g')} | {cmp.verdict(m)} | "
                     f"{_f(r.detectable, '.3g')} |")
    for side in (cmp.a, cmp.b):
        for f in side.failures:
            lines.append(f"\nfailed in {side.label}: {f}")
    return lines
