"""``simbench check --calibrate``: how often the gate raises a false alarm, and how often it
catches known regressions.

For every configuration (the unchanged code, and each injected regression) each suite
scenario is run on a pool of ``pool`` fresh seeds (``seed + CALIBRATION_SEED_OFFSET + k``:
disjoint from the check's and the baseline's seeds). Then ``checks`` times, a check's seed
set (``suite.seeds`` seeds per scenario) is drawn from the pool at random (a fixed
generator) and judged against the stored baseline exactly as ``simbench check`` judges
(:func:`simbench.sweeps.regression.compare`). A check "fails" when it does not pass (a
regression, a missing metric or a run that could not run). Reported per configuration: the
fraction of checks that failed with its Clopper-Pearson 95 % interval (the draws share the
pool's runs, so they are not independent: the pool holds ``pool // seeds`` disjoint seed
sets; the interval treats the draws as independent and is therefore too narrow), and which
metrics flagged.

Injected regressions (:data:`INJECTIONS`): 2D detection noise +0.2 px (SD per axis, added
to every detection before the pipeline), exposure 4 -> 12 ms (scenarios shot at 4 ms), the
tracker kalman -> alpha_beta (scenarios using kalman), one camera fewer (``rig.count - 1``).
A scenario an injection does not change reuses the unchanged code's runs of the same seeds.
The tracker injection changes every ci scenario; ``forehand_tracker`` is the one where it
costs labels (the others end before the subject moves fast: quickstart is identical, blur_zigzag
and visible_office move within their seed spread).
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np
from scipy import stats

from simbench.sweeps.regression import (CALIBRATION_SEED_OFFSET, EXIT_PASS, REGRESSED, Baseline, Suites, compare,
                                        ensemble_seeds, exit_code, run_suite)
from simbench.sweeps.results_db import RunRecord
from simbench.sweeps.sweep import RunSpec
from simbench.scenario import Scenario


@dataclass(frozen=True)
class Injection:
    """A known regression: scenario overrides (per scenario; empty: unchanged) and/or detection noise."""

    name: str
    overrides: Callable[[Scenario], dict[str, Any]]
    detection_noise_px: float = 0.0


def _exposure(sc: Scenario) -> dict[str, Any]:
    return {"sensor.exposure_ms": 12.0} if sc.sensor.exposure_ms == 4.0 else {}


def _tracker(sc: Scenario) -> dict[str, Any]:
    # The issue's injection: the bench's Kalman filter replaced by seed 000's alpha-beta (fixed
    # 40 px search circle). The ci suite's forehand_tracker is where that costs labels.
    return {"markers_pipeline.tracker": "alpha_beta"} if sc.markers_pipeline.tracker == "kalman" else {}


def _one_camera_fewer(sc: Scenario) -> dict[str, Any]:
    return {"rig.count": sc.rig.count - 1} if sc.rig is not None and sc.rig.count > 1 else {}


UNCHANGED = Injection("unchanged code", lambda sc: {})
INJECTIONS = (
    Injection("2D detection noise +0.2 px", lambda sc: {}, 0.2),
    Injection("exposure 4 -> 12 ms", _exposure),
    Injection("tracker kalman -> alpha_beta", _tracker),
    Injection("one camera fewer", _one_camera_fewer),
)


@dataclass
class CalibrationRow:
    name: str
    failed_checks: int
    checks: int
    changed_scenarios: list[str]
    flagged: Counter = field(default_factory=Counter)  # "scenario metric" -> checks where it regressed
    runs: int = 0

    @property
    def rate(self) -> float:
        return self.failed_checks / self.checks if self.checks else math.nan

    def interval(self) -> tuple[float, float]:
        if not self.checks:
            return math.nan, math.nan
        ci = stats.binomtest(self.failed_checks, self.checks).proportion_ci(0.95, method="exact")
        return float(ci.low), float(ci.high)


@dataclass
class Calibration:
    suite: str
    seeds_per_check: int
    pool: int
    checks: int
    alpha: float
    rows: list[CalibrationRow]
    wall_s: float = 0.0
    n_runs: int = 0
    #: configuration -> scenario -> metric -> value per pool seed (what the rates were drawn from)
    pools: dict[str, dict[str, dict[str, list[float | None]]]] = field(default_factory=dict)
    seeds: dict[str, list[int]] = field(default_factory=dict)

    def to_json(self) -> dict:
        return {"suite": self.suite, "seeds_per_check": self.seeds_per_check, "pool": self.pool, "checks": self.checks,
                "alpha": self.alpha, "wall_s": self.wall_s, "runs": self.n_runs, "pool_seeds": self.seeds,
                "rates": {r.name: {"failed_checks": r.failed_checks, "checks": r.checks, "rate": r.rate,
                                   "ci95": list(r.interval()), "scenarios_changed": r.changed_scenarios,
                                   "flagged": dict(r.flagged.most_common())} for r in self.rows},
                "pools": self.pools}


def _modified(spec: RunSpec, inj: Injection) -> RunSpec | None:
    """The suite run with the injection's overrides; None when it changes nothing."""
    ov = inj.overrides(spec.scenario)
    if not ov:
        return None
    sc = spec.scenario.with_overrides(ov)
    return RunSpec(spec.run_id + "+inj", spec.index, spec.sweep, dict(spec.factors), {**spec.overrides, **ov}, sc)


def calibrate(suites: Suites, suite: str, baseline: Baseline, pool: int = 24, checks: int = 200,
              workers: int | None = None, scheduler: str | None = None,
              on_runs: Callable[[str, int], None] | None = None,
              on_record: Callable[[RunRecord], None] | None = None,
              injections: tuple[Injection, ...] = INJECTIONS) -> Calibration:
    """Run the pools and judge ``checks`` drawn checks per configuration (see the module doc).

    ``on_runs(name, n)`` is told how many runs a configuration needs before they start;
    ``on_record`` is called after each run."""
    s = suites.get(suite)
    runs = suites.runs(suite)
    n = s.seeds
    if pool < n:
        raise ValueError(f"pool ({pool}) must hold at least one check's seeds ({n})")
    seeds = {str(r.factors["scenario"]): ensemble_seeds(r, pool, CALIBRATION_SEED_OFFSET) for r in runs}
    patterns = suites.tolerances_for(suite)
    rows: list[CalibrationRow] = []
    pools: dict[str, dict[str, list[RunRecord]]] = {}
    total_runs = 0

    def run(name: str, specs: list[RunSpec], noise: float) -> dict[str, list[RunRecord]]:
        nonlocal total_runs
        if on_runs:
            on_runs(name, len(specs) * pool)
        total_runs += len(specs) * pool
        sub = {k: v for k, v in seeds.items() if k in {str(r.factors["scenario"]) for r in specs}}
        return run_suite(specs, workers=workers, scheduler=scheduler, seeds=sub, detection_noise_px=noise,
                         on_record=(lambda rec, _d, _f: on_record(rec)) if on_record else None)

    pools[UNCHANGED.name] = run(UNCHANGED.name, runs, 0.0)
    for inj in injections:
        if inj.detection_noise_px > 0:
            changed = list(runs)
            specs = changed
        else:
            mods = {str(r.factors["scenario"]): _modified(r, inj) for r in runs}
            specs = [m for m in mods.values() if m is not None]
        got = run(inj.name, specs, inj.detection_noise_px) if specs else {}
        pools[inj.name] = {name: got.get(name, pools[UNCHANGED.name][name]) for name in seeds}
        pools[inj.name + " changed"] = {name: [] for name in got}  # which scenarios the injection touched
    rng = np.random.default_rng(np.random.SeedSequence([0xCA1B, pool, checks, n]))
    draws = [{name: np.sort(rng.choice(pool, size=n, replace=False)) for name in seeds} for _ in range(checks)]
    for inj in (UNCHANGED, *injections):
        p = pools[inj.name]
        changed = sorted(pools.get(inj.name + " changed", {}))
        row = CalibrationRow(inj.name, 0, checks, changed)
        for d in draws:
            records = {name: [p[name][i] for i in idx] for name, idx in d.items()}
            res = compare(records, baseline, patterns, alpha=s.alpha)
            if exit_code(res) != EXIT_PASS:
                row.failed_checks += 1
            for c in res:
                if c.status == REGRESSED or (c.status != "ok" and c.failing):
                    row.flagged[f"{c.scenario} {c.metric}"] += 1
        rows.append(row)
    dump = {inj.name: {name: {m: [None if not math.isfinite(v) else v
                                  for v in (float(r.metrics.get(m, math.nan)) for r in recs)]
                              for m in sorted({m for r in recs for m in r.metrics})}
                       for name, recs in pools[inj.name].items()}
            for inj in (UNCHANGED, *injections)}
    return Calibration(suite, n, pool, checks, s.alpha, rows, n_runs=total_runs, pools=dump, seeds=seeds)
