"""Replicates: one scenario on N seeds (``simbench run SCENARIO --seeds N``).

Seed ``i`` of a replicate set is ``start + i`` (``start`` defaults to the scenario's own
``seed``, so ``--seeds 1`` is the single run). The scenario's ``seed`` derives every random
stream of a run (``numpy.random.SeedSequence([seed, key])`` per stream): sensor noise
(:func:`simbench.render.frames.frame_rng`), the room's clutter
(:mod:`simbench.stage.renderer`), the motion's random draws such as prop throws and start
offsets (:meth:`simbench.stage.stage.Stage.from_scenario`), a real capture's seeded gaps
(:mod:`simbench.stage.capture`) and the pipeline's own generator (:mod:`simbench.pipelines.run`).

The runs go through the sweep machinery (:func:`simbench.sweeps.sweep.iter_records`: the
local process pool, or a Dask cluster). The output folder, built atomically like a single
run's (:class:`simbench.output_dir.AtomicOutputDir`)::

    OUT/metrics.json           per metric: per-seed values, mean, median, SD, 95 % bootstrap CI
    OUT/report.md              table of the above, plots/seed_spread.png, links to each seed
    OUT/seeds/seed-0000/...    each seed's own run folder (metrics.json, report.md, videos, ...)

The statistics come from :mod:`eval.seed_stats` (``scipy.stats.bootstrap`` with a generator
seeded per metric name, so the same values give the same interval).
"""

from __future__ import annotations

import json
import math
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from eval import plots
from eval.seed_stats import DEFAULT_RESAMPLES, SeedSummary, bootstrap_summary
from simbench.output_dir import AtomicOutputDir
from simbench.scenario import Scenario
from simbench.sweeps.results_db import STATUS_OK, RunRecord
from simbench.sweeps.sweep import RunSpec, RunTask, iter_records, run_id_for

SEEDS_DIR = "seeds"
CONFIDENCE = 0.95
#: Root of the bootstrap generators (one per metric: ``SeedSequence([BOOTSTRAP_KEY, crc32(metric)])``).
BOOTSTRAP_KEY = 0xB007


def seed_list(scenario: Scenario, n: int, start: int | None = None) -> list[int]:
    """``[start, start + 1, ..., start + n - 1]``; ``start`` defaults to the scenario's seed."""
    s = scenario.seed if start is None else int(start)
    return [s + i for i in range(int(n))]


def seed_dir_name(seed: int) -> str:
    return f"seed-{seed:04d}"


def replicate_specs(scenario: Scenario, seeds: list[int], sweep: str, overrides: dict[str, Any] | None = None,
                    factors: dict[str, object] | None = None) -> list[RunSpec]:
    """One :class:`RunSpec` per seed (the scenario with ``seed`` replaced); factors carry ``seed``."""
    specs = []
    for i, s in enumerate(seeds):
        sc = scenario.with_overrides({"seed": s})
        ov = {**(overrides or {}), "seed": s}
        specs.append(RunSpec(run_id_for(sc, ov), i, sweep, {**(factors or {}), "seed": s}, ov, sc))
    return specs


def run_specs(specs: list[RunSpec], out_dirs: list[str | None], workers: int | None = None, scheduler: str | None = None,
              on_record: Callable[[RunRecord], None] | None = None) -> list[RunRecord]:
    """Run ``specs`` on the pool (or Dask); records in the order of ``specs``."""
    tasks = [RunTask(s, d) for s, d in zip(specs, out_dirs)]
    by_id: dict[str, RunRecord] = {}
    for rec in iter_records(tasks, workers, scheduler):
        rec.per_frame = None
        by_id[rec.run_id] = rec
        if on_record is not None:
            on_record(rec)
    return [by_id[s.run_id] for s in specs]


def metric_rng(metric: str) -> np.random.Generator:
    """The bootstrap generator of one metric (independent of which other metrics exist)."""
    return np.random.default_rng(np.random.SeedSequence([BOOTSTRAP_KEY, zlib.crc32(metric.encode())]))


def per_seed_values(records: list[RunRecord]) -> dict[str, np.ndarray]:
    """``{metric: (n_seeds,) values}`` in record order, NaN where a seed has no value
    (a run that raised has none at all)."""
    names = sorted({m for r in records for m in r.metrics})
    return {m: np.array([float(r.metrics.get(m, math.nan)) for r in records]) for m in names}


def summarise(values: dict[str, np.ndarray], confidence: float = CONFIDENCE,
              n_resamples: int = DEFAULT_RESAMPLES) -> dict[str, SeedSummary]:
    return {m: bootstrap_summary(v, confidence, metric_rng(m), n_resamples) for m, v in values.items()}


@dataclass
class SeedsResult:
    scenario: str
    seeds: list[int]
    records: list[RunRecord]
    summaries: dict[str, SeedSummary]
    out_dir: Path | None = None
    failures: list[tuple[int, str]] = field(default_factory=list)  # (seed, one line)

    @property
    def ok(self) -> bool:
        return not self.failures


def _failure_line(rec: RunRecord) -> str:
    return (rec.error.splitlines() or ["failed"])[0]


def run_seeds(scenario: Scenario, out: str | Path | None, n: int, start: int | None = None,
              overrides: dict[str, Any] | None = None, workers: int | None = None, scheduler: str | None = None,
              on_record: Callable[[RunRecord], None] | None = None) -> SeedsResult:
    """Run ``scenario`` on ``n`` seeds and summarise every metric (see the module doc).

    A seed whose run failed (a stage after rendering, or the whole run) is listed in
    ``failures``; its metrics are kept where it has them, NaN where not."""
    if n < 1:
        raise ValueError(f"n must be >= 1, got {n}")
    seeds = seed_list(scenario, n, start)
    specs = replicate_specs(scenario, seeds, f"seeds:{scenario.name}", overrides)
    if out is None:
        records = run_specs(specs, [None] * len(specs), workers, scheduler, on_record)
        return _result(scenario, seeds, records, None)
    output = AtomicOutputDir(out, scenario=scenario.name, kind="run")
    with output as tmp:
        dirs = [str((tmp / SEEDS_DIR / seed_dir_name(s)).resolve()) for s in seeds]
        records = run_specs(specs, dirs, workers, scheduler, on_record)
        for r in records:  # worker messages name the partial folder: make them name the final one
            r.error = output.public(r.error)
        result = _result(scenario, seeds, records, Path(out))
        write_seeds_outputs(tmp, scenario, result)
    return result


def _result(scenario: Scenario, seeds: list[int], records: list[RunRecord], out: Path | None) -> SeedsResult:
    failures = [(s, _failure_line(r)) for s, r in zip(seeds, records) if r.status != STATUS_OK]
    return SeedsResult(scenario.name, seeds, records, summarise(per_seed_values(records)), out, failures)


def seeds_metrics_json(result: SeedsResult) -> dict:
    return {
        "scenario": result.scenario,
        "seeds": result.seeds,
        "n_seeds": len(result.seeds),
        "confidence": CONFIDENCE,
        "interval": f"bootstrap CI of the mean over seeds (scipy.stats.bootstrap, BCa, percentile where BCa is "
                    f"undefined, {DEFAULT_RESAMPLES} resamples, generator SeedSequence([{BOOTSTRAP_KEY:#x}, crc32(metric)]))",
        "metrics": {m: s.to_json() for m, s in sorted(result.summaries.items())},
        "failed_seeds": [{"seed": s, "cause": c} for s, c in result.failures],
        "failed_stages": [],
    }


def _fmt(v: float) -> str:
    return "—" if not math.isfinite(v) else f"{v:.4g}"


def write_seeds_outputs(tmp: Path, scenario: Scenario, result: SeedsResult) -> None:
    """``metrics.json``, ``report.md`` and ``plots/seed_spread.png`` of a replicate set."""
    (tmp / "metrics.json").write_text(json.dumps(seeds_metrics_json(result), indent=2) + "\n")
    (tmp / "plots").mkdir(exist_ok=True)
    shown = {m: s for m, s in sorted(result.summaries.items()) if not m.startswith("run.")}
    plots.seed_spread({m: np.array(s.values) for m, s in shown.items()}, tmp / "plots" / "seed_spread.png",
                      ci={m: (s.ci_low, s.ci_high) for m, s in shown.items()},
                      title=f"{scenario.name}: {len(result.seeds)} seeds (box: quartiles; red: mean and 95 % CI)")
    pct = round(100 * CONFIDENCE)
    lines = [f"# simbench run: {scenario.name}, {len(result.seeds)} seeds", "", scenario.description or "", "",
             f"Seeds {result.seeds[0]}..{result.seeds[-1]} (`seed` = first + i); every random stream of a run "
             f"(sensor noise, clutter, the motion's draws, seeded gaps) follows its seed. Interval: {pct} % bootstrap "
             f"confidence interval of the mean over seeds (scipy.stats.bootstrap, BCa).", ""]
    if result.failures:
        lines += ["## Failed seeds", ""] + [f"- seed {s}: {c}" for s, c in result.failures] + [""]
    lines += ["## Metrics across seeds", "", f"| metric | mean | {pct} % CI | median | SD | min | max | NaN |",
              "|---|---|---|---|---|---|---|---|"]
    for m, s in sorted(result.summaries.items()):
        fin = [v for v in s.values if math.isfinite(v)]
        lo, hi = (min(fin), max(fin)) if fin else (math.nan, math.nan)
        lines.append(f"| `{m}` | {_fmt(s.mean)} | {_fmt(s.ci_low)} .. {_fmt(s.ci_high)} | {_fmt(s.median)} | "
                     f"{_fmt(s.sd)} | {_fmt(lo)} | {_fmt(hi)} | {s.n_nan} |")
    lines += ["", "## Spread across seeds", "", "![spread across seeds](plots/seed_spread.png)", "",
              "## Per-seed values", "", "| seed | " + " | ".join(f"`{m}`" for m in shown) + " | run |",
              "|---" * (len(shown) + 2) + "|"]
    for i, (seed, rec) in enumerate(zip(result.seeds, result.records)):
        link = f"[{seed_dir_name(seed)}]({SEEDS_DIR}/{seed_dir_name(seed)}/report.md)"
        lines.append(f"| {seed} | " + " | ".join(_fmt(s.values[i]) for s in shown.values()) +
                     f" | {link}{'' if rec.status == STATUS_OK else ' (failed)'} |")
    lines.append("")
    (tmp / "report.md").write_text("\n".join(lines))
