"""``simbench check``: a CI regression gate over a named suite of scenarios.

Suites live in ``scenarios/suites.toml``::

    [tolerances]                      # first matching pattern wins (fnmatch)
    "markers.rmse_mm" = { worse = "higher", abs = 0.25, rel = 0.10 }
    "markers.reconstructed_fraction" = { worse = "lower", abs = 0.02 }
    "*" = { worse = "either", rel = 0.05, abs = 1e-9 }

    [suites.ci]
    description = "three tiny scenarios"
    set = { "rig.count" = 2, duration_s = 0.5 }   # applied to every scenario

    [[suites.ci.scenarios]]
    name = "quickstart"                           # key in the baseline
    file = "quickstart.toml"                      # relative to suites.toml
    set = { "markers_pipeline.tracker" = "kalman" }

A suite may have its own ``[suites.NAME.tolerances]``, consulted before the global
ones. A metric's allowed change is ``max(abs, rel * |baseline|)``; ``worse`` says
which direction counts as a regression (``higher``, ``lower``, or ``either``: any
change beyond the tolerance). Changes beyond the tolerance in the good direction are
reported as improved (a hint to update the baseline) and do not fail.

The baseline (``scenarios/baselines/<suite>.json``) holds, per scenario, its content
hash and metrics; ``simbench baseline update --suite NAME`` rewrites it from a run.
"""

from __future__ import annotations

import fnmatch
import json
import math
import warnings
import xml.etree.ElementTree as ET
from dataclasses import dataclass, replace
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Callable, Literal

import numpy as np
from pydantic import Field, ValidationError, field_validator, model_validator
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from eval.seed_stats import holm, shift_test
from simbench.errors import ScenarioError, SimbenchInputError
from mocap.atomic_files import atomic_write_bytes
from simbench.sweeps.results_db import STATUS_FAILED, STATUS_OK, RunRecord
from simbench.scenario import FrozenModel, Int, Real, load_scenario, read_toml_file, validation_error_to_scenario_error
from simbench.sweeps.sweep import RunSpec, RunTask, flatten_dotted, iter_records, package_versions, run_id_for

WORSE = ("higher", "lower", "either")

# Status of one metric comparison; the first four fail the check.
REGRESSED, MISSING, ERROR, OK, IMPROVED, NEW = "regressed", "missing", "error", "ok", "improved", "new"
FAILING = (REGRESSED, MISSING, ERROR)
#: The metric name of the one row of a scenario that could not run.
RUN_ROW = "(run)"

#: ``simbench check`` exit codes (also in its --help and the README).
EXIT_PASS, EXIT_REGRESSION, EXIT_COULD_NOT_RUN = 0, 1, 3


class Tolerance(FrozenModel):
    worse: Literal["higher", "lower", "either"] = Field(description="direction that counts as a regression")
    abs: Real = Field(0.0, ge=0.0, description="allowed absolute change")
    rel: Real = Field(0.0, ge=0.0, description="allowed change as a fraction of |baseline|")

    def allowed(self, baseline: float) -> float:
        return max(self.abs, self.rel * abs(baseline))

    def describe(self) -> str:
        """E.g. ``higher worse, ±max(0.25, 10%)``."""
        parts = [f"{self.abs:g}" if self.abs else "", f"{100 * self.rel:g}%" if self.rel else ""]
        parts = [p for p in parts if p]
        tol = "±" + (f"max({', '.join(parts)})" if len(parts) == 2 else parts[0]) if parts else "exact"
        return f"{self.worse} worse, {tol}" if self.worse != "either" else f"any change, {tol}"


def _flat(v):
    return flatten_dotted(v) if isinstance(v, dict) else v


class SuiteScenario(FrozenModel):
    name: str = Field(pattern=r"^[A-Za-z0-9_.-]+$")
    file: str
    set: dict[str, Any] = Field(default_factory=dict)

    @field_validator("set", mode="before")
    @classmethod
    def _flatten(cls, v):
        return _flat(v)


class Suite(FrozenModel):
    description: str = ""
    set: dict[str, Any] = Field(default_factory=dict)
    scenarios: list[SuiteScenario] = Field(min_length=1)
    tolerances: dict[str, Tolerance] = Field(default_factory=dict)
    seeds: Int = Field(1, ge=1, le=1000, description="seeds `simbench check` runs per scenario (scenario seed + i)")
    baseline_seeds: Int | None = Field(None, ge=1, le=10000, description="seeds per scenario in the baseline "
                                       "(scenario seed + 1000 + j; default 4 x seeds)")
    alpha: Real = Field(0.01, gt=0.0, lt=0.5, description="false-alarm rate of a whole check (Holm over every tested "
                         "metric of every scenario)")

    @property
    def n_baseline_seeds(self) -> int:
        return self.baseline_seeds if self.baseline_seeds is not None else 4 * self.seeds

    @field_validator("set", mode="before")
    @classmethod
    def _flatten(cls, v):
        return _flat(v)

    @model_validator(mode="after")
    def _unique(self):
        names = [s.name for s in self.scenarios]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise ValueError(f"scenario names in a suite must be unique; repeated: {dup}")
        return self


class SuitesSpec(FrozenModel):
    tolerances: dict[str, Tolerance] = Field(default_factory=dict)
    suites: dict[str, Suite] = Field(min_length=1)


@dataclass(frozen=True)
class Suites:
    spec: SuitesSpec
    path: Path

    def get(self, name: str) -> Suite:
        if name not in self.spec.suites:
            raise ScenarioError(self.path, "suites", name, f"no such suite; defined: {', '.join(self.spec.suites)}")
        return self.spec.suites[name]

    def tolerances_for(self, name: str) -> list[tuple[str, Tolerance]]:
        """Patterns in the order they are tried: the suite's own, then the global ones."""
        return list(self.get(name).tolerances.items()) + list(self.spec.tolerances.items())

    def runs(self, name: str, only: list[str] | tuple[str, ...] = (), extra_set: dict[str, Any] | None = None) -> list[RunSpec]:
        """The suite's scenarios resolved (suite ``set``, scenario ``set``, then ``extra_set``);
        raises :class:`ScenarioError` for the first that cannot be resolved."""
        runs, unrunnable = self.resolve(name, only, extra_set)
        if unrunnable:
            raise next(iter(unrunnable.values()))
        return runs

    def resolve(self, name: str, only: list[str] | tuple[str, ...] = (),
                extra_set: dict[str, Any] | None = None) -> tuple[list[RunSpec], dict[str, ScenarioError]]:
        """``(runs, unrunnable)``: the suite's scenarios that resolve, and ``{scenario name:
        error}`` for those whose file is missing or does not validate with the suite's
        overrides (``simbench check`` shows each as an error row and goes on).

        Raises :class:`ScenarioError` for mistakes of the command line itself: an
        ``--only`` name not in the suite, or an ``extra_set`` (``--set``) that breaks a
        scenario which resolves without it.
        """
        suite = self.get(name)
        known = [s.name for s in suite.scenarios]
        for o in only:
            if o not in known:
                raise ScenarioError(self.path, f"suites.{name}.scenarios", o, f"--only names a scenario of the suite: {', '.join(known)}")
        extra = flatten_dotted(extra_set or {})
        runs: list[RunSpec] = []
        unrunnable: dict[str, ScenarioError] = {}
        for i, s in enumerate(suite.scenarios):
            if only and s.name not in only:
                continue
            path = (self.path.parent / s.file).resolve()
            own = {**suite.set, **s.set}
            overrides = {**own, **extra}
            if not path.is_file():
                unrunnable[s.name] = ScenarioError(self.path, f"suites.{name}.scenarios[{i}].file", s.file,
                                                   f"file not found (looked for {path})")
                continue
            try:
                sc = load_scenario(path, overrides=overrides)
            except ScenarioError as exc:
                if not extra:
                    unrunnable[s.name] = exc
                    continue
                try:
                    load_scenario(path, overrides=own)
                except ScenarioError as own_exc:
                    unrunnable[s.name] = own_exc
                    continue
                raise ScenarioError(exc.path, f"--set {exc.field}", exc.value, exc.allowed) from None
            runs.append(RunSpec(run_id_for(sc, overrides), len(runs), f"check:{name}", {"scenario": s.name}, overrides, sc))
        return runs, unrunnable


def load_suites(path: str | Path) -> Suites:
    path = Path(path)
    data = read_toml_file(path, "suites live in scenarios/suites.toml (--suites FILE)")
    try:
        return Suites(SuitesSpec.model_validate(data), path)
    except ValidationError as exc:
        raise validation_error_to_scenario_error(path, exc) from None


def default_baseline_path(suites_file: str | Path, suite: str) -> Path:
    return Path(suites_file).parent / "baselines" / f"{suite}.json"


# ---------------------------------------------------------------------------- running
#: Seeds of a suite scenario: ``check`` runs ``seed + i``, the baseline ``seed + BASELINE_SEED_OFFSET + j``,
#: ``check --calibrate`` draws fresh sets from ``seed + CALIBRATION_SEED_OFFSET + k``: three disjoint ranges.
BASELINE_SEED_OFFSET, CALIBRATION_SEED_OFFSET = 1000, 2000


def ensemble_seeds(spec: RunSpec, n: int, offset: int = 0) -> list[int]:
    return [spec.scenario.seed + offset + i for i in range(n)]


def run_suite(runs: list[RunSpec], out_dir: str | Path | None = None, workers: int | None = None,
              scheduler: str | None = None,
              on_record: Callable[[RunRecord, int, int], None] | None = None,
              seeds: int | dict[str, list[int]] | None = None, detection_noise_px: float = 0.0) -> dict[str, list[RunRecord]]:
    """Run the suite's scenarios on their seed ensembles (process pool or Dask).

    ``seeds``: None or 1 runs each scenario once as resolved (its own seed); ``n`` runs seeds
    ``seed + i``, ``i < n``; a dict gives each scenario's seeds. Returns ``{suite scenario name:
    [record per seed]}``; each record carries the resolved suite scenario's hash and overrides
    (the ensemble's, not the seed's), so baselines and checks compare like with like."""
    specs: list[RunSpec] = []
    base_of: dict[str, RunSpec] = {}
    for r in runs:
        name = str(r.factors["scenario"])
        base_of[name] = r
        if seeds is None or seeds == 1:
            specs.append(replace(r, index=len(specs)))
            continue
        for s in (seeds[name] if isinstance(seeds, dict) else ensemble_seeds(r, int(seeds))):
            sc = r.scenario.with_overrides({"seed": s})
            ov = {**r.overrides, "seed": s}
            specs.append(RunSpec(run_id_for(sc, ov), len(specs), r.sweep, {**r.factors, "seed": s}, ov, sc))
    multi = len(specs) > len(runs)

    def out_for(r: RunSpec) -> str | None:
        if not out_dir:
            return None
        sub = Path(out_dir, str(r.factors["scenario"]))
        return str((sub / f"seed-{r.factors['seed']:04d}" if multi else sub).resolve())

    tasks = [RunTask(r, out_for(r), detection_noise_px) for r in specs]
    by_id: dict[str, RunRecord] = {}
    failed = 0
    for rec in iter_records(tasks, workers, scheduler):
        rec.per_frame = None
        base = base_of[str(rec.factors["scenario"])]
        rec.scenario_hash = base.scenario.content_hash()
        rec.parameters = dict(base.overrides)
        by_id[rec.run_id] = rec
        failed += rec.status != STATUS_OK
        if on_record:
            on_record(rec, len(by_id), failed)
    out: dict[str, list[RunRecord]] = {str(r.factors["scenario"]): [] for r in runs}
    for sp in specs:
        out[str(sp.factors["scenario"])].append(by_id[sp.run_id])
    return out


# ---------------------------------------------------------------------------- baselines
@dataclass(frozen=True)
class Baseline:
    """A suite's baseline. ``scenarios[name]``: ``scenario_hash``, ``parameters``, ``metrics``
    (``{metric: median over the seeds}``) and ``values`` (``{metric: [value per seed]}``;
    a baseline written before seed ensembles (format 1) has one value per metric)."""

    suite: str
    scenarios: dict[str, dict]
    path: Path
    format: int = 2

    def values(self, scenario: str, metric: str) -> np.ndarray:
        base = self.scenarios[scenario]
        v = base.get("values", {}).get(metric)
        return np.array([base["metrics"][metric]] if v is None else v, float)


def load_baseline(path: str | Path) -> Baseline:
    path = Path(path)
    if not path.is_file():
        raise ScenarioError(path, "<file>", str(path), "baseline not found; write it with `simbench baseline update --suite NAME`")
    try:
        data = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise ScenarioError(path, "<syntax>", str(exc), "fix the JSON, or rewrite it with `simbench baseline update`") from None
    scen = data.get("scenarios")
    if not isinstance(scen, dict) or not all(isinstance(v, dict) and isinstance(v.get("metrics"), dict) for v in scen.values()):
        raise ScenarioError(path, "scenarios", type(scen).__name__,
                            "expected {name: {\"scenario_hash\": ..., \"metrics\": {...}}}; rewrite with `simbench baseline update`")
    for name, v in scen.items():
        v["metrics"] = {k: (math.nan if x is None else float(x)) for k, x in v["metrics"].items()}
        vals = v.get("values", {})
        if not isinstance(vals, dict) or not all(isinstance(x, list) for x in vals.values()):
            raise ScenarioError(path, f"scenarios.{name}.values", type(vals).__name__,
                                "expected {metric: [value per seed]}; rewrite with `simbench baseline update`")
        v["values"] = {k: [math.nan if x is None else float(x) for x in xs] for k, xs in vals.items()}
    return Baseline(str(data.get("suite", "")), scen, path, int(data.get("format", 1)))


def _as_list(r: RunRecord | list[RunRecord]) -> list[RunRecord]:
    return list(r) if isinstance(r, (list, tuple)) else [r]


def _json(v: float) -> float | None:
    return float(v) if math.isfinite(v) else None


def write_baseline(path: str | Path, suite: str, records: dict[str, RunRecord | list[RunRecord]]) -> Path:
    """Write the baseline of a suite run (format 2: every metric's value per seed and their
    median); refuses if any run failed."""
    records = {n: _as_list(r) for n, r in records.items()}
    bad = {f"{n} (seed {r.factors.get('seed', '-')})": r.error.splitlines()[0] if r.error else ""
           for n, rs in records.items() for r in rs if r.status != STATUS_OK}
    if bad:
        raise SimbenchInputError(f"baseline not written: scenario(s) failed: "
                                 + "; ".join(f"{n}: {e}" for n, e in bad.items()) + ". Fix them and run again.")
    scenarios = {}
    for n, rs in records.items():
        names = sorted({m for r in rs for m in r.metrics})
        vals = {m: [float(r.metrics.get(m, math.nan)) for r in rs] for m in names}
        with np.errstate(all="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # an all-NaN metric: its median is NaN (null)
            med = {m: float(np.nanmedian(v)) for m, v in vals.items()}
        scenarios[n] = {"scenario_hash": rs[0].scenario_hash, "parameters": rs[0].parameters,
                        "seeds": [r.factors.get("seed") for r in rs],
                        "metrics": {m: _json(med[m]) for m in names},
                        "values": {m: [_json(x) for x in vals[m]] for m in names}}
    data = {
        "suite": suite,
        "format": 2,
        "created_utc": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "versions": package_versions(),
        "scenarios": scenarios,
    }
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(path, (json.dumps(data, indent=2, default=str) + "\n").encode(), fsync=True)
    return path


# ---------------------------------------------------------------------------- comparing
@dataclass(frozen=True)
class MetricCheck:
    scenario: str
    metric: str
    baseline: float
    current: float
    status: str
    tolerance: Tolerance | None = None
    note: str = ""
    p_value: float = math.nan  # one-sided test that the metric got worse, Holm-adjusted over the check (NaN: not tested)
    n_baseline: int = 1
    n_current: int = 1

    @property
    def delta(self) -> float:
        return self.current - self.baseline

    @property
    def failing(self) -> bool:
        return self.status in FAILING


def tolerance_for(metric: str, patterns: list[tuple[str, Tolerance]]) -> Tolerance | None:
    for pat, tol in patterns:
        if fnmatch.fnmatchcase(metric, pat):
            return tol
    return None


def judge(baseline: float, current: float, tol: Tolerance) -> str:
    """``ok``, ``regressed`` or ``improved`` of one metric under its tolerance."""
    b_ok, c_ok = math.isfinite(baseline), math.isfinite(current)
    if not b_ok and not c_ok:
        return OK
    if b_ok and not c_ok:
        return REGRESSED  # the metric could not be computed any more
    if not b_ok:
        return IMPROVED if tol.worse != "either" else REGRESSED
    d = current - baseline
    allowed = tol.allowed(baseline)
    if abs(d) <= allowed:
        return OK
    if tol.worse == "either":
        return REGRESSED
    worse = d > 0 if tol.worse == "higher" else d < 0
    return REGRESSED if worse else IMPROVED


def _median(v: np.ndarray) -> float:
    fin = v[np.isfinite(v)]
    return float(np.median(fin)) if fin.size else math.nan


def compare(records: dict[str, RunRecord | list[RunRecord]], baseline: Baseline, patterns: list[tuple[str, Tolerance]],
            alpha: float = 0.01) -> list[MetricCheck]:
    """Every metric of every scenario run against the baseline.

    With two or more seeds on both sides, a metric with a direction (``worse`` higher or
    lower) regressed when a one-sided Mann-Whitney U test (:func:`eval.seed_stats.shift_test`:
    current worse than baseline; a NaN ranks as the worst value) rejects at ``alpha`` after
    Holm's correction over every tested metric of every scenario (so a whole check raises a
    false alarm with probability at most ``alpha``) **and** the median moved by more than the
    tolerance (``max(abs, rel * |baseline median|)``: the practical-effect floor). Improved is
    the same in the other direction. One seed on either side (or ``worse = "either"``, the
    deterministic configuration metrics): the tolerance on the medians, as before ensembles.

    Scenarios of the baseline that were not run (``--only``) are not compared; a scenario
    with a failed run is one ``error`` check; a metric in the baseline missing from the run
    is ``missing``; one not in the baseline is ``new``.
    """
    checks: list[MetricCheck] = []
    tested: list[tuple[int, float, float, float, float]] = []  # (check index, p worse, p better, shift, floor)
    nan = math.nan
    for name, recs in records.items():
        recs = _as_list(recs)
        base = baseline.scenarios.get(name)
        bad = [r for r in recs if r.status != STATUS_OK]
        if bad:
            first = bad[0].error.splitlines()[0] if bad[0].error else "failed"
            seed = f"seed {bad[0].factors['seed']}: " if "seed" in bad[0].factors and len(recs) > 1 else ""
            checks.append(MetricCheck(name, RUN_ROW, nan, nan, ERROR, note=seed + first))
            continue
        cur = {m: np.array([float(r.metrics.get(m, nan)) for r in recs]) for m in sorted({m for r in recs for m in r.metrics})}
        if base is None:
            for m, v in cur.items():
                checks.append(MetricCheck(name, m, nan, _median(v), NEW, note="scenario not in the baseline", n_current=len(v)))
            continue
        note = "" if base.get("scenario_hash") in (None, recs[0].scenario_hash) else "scenario differs from the baseline's"
        bm = base["metrics"]
        for m in sorted(set(bm) | set(cur)):
            tol = tolerance_for(m, patterns)
            if m not in cur:
                checks.append(MetricCheck(name, m, bm[m], nan, MISSING, tol, note))
                continue
            c_vals = cur[m]
            if m not in bm:
                checks.append(MetricCheck(name, m, nan, _median(c_vals), NEW, tol, note, n_current=len(c_vals)))
                continue
            b_vals = baseline.values(name, m)
            b_med, c_med = _median(b_vals), _median(c_vals)
            if tol is None:
                checks.append(MetricCheck(name, m, b_med, c_med, ERROR, None, "no tolerance matches; add one to suites.toml",
                                          n_baseline=len(b_vals), n_current=len(c_vals)))
            elif len(b_vals) >= 2 and len(c_vals) >= 2 and tol.worse != "either":
                worse = shift_test(b_vals, c_vals, tol.worse)
                better = shift_test(b_vals, c_vals, "lower" if tol.worse == "higher" else "higher")
                floor = tol.allowed(b_med) if math.isfinite(b_med) else 0.0
                tested.append((len(checks), worse.p_value, better.p_value, worse.shift, floor))
                checks.append(MetricCheck(name, m, b_med, c_med, OK, tol, note, n_baseline=len(b_vals), n_current=len(c_vals)))
            else:
                checks.append(MetricCheck(name, m, b_med, c_med, judge(b_med, c_med, tol), tol, note,
                                          n_baseline=len(b_vals), n_current=len(c_vals)))
    if tested:
        p_worse = holm([t[1] for t in tested])
        p_better = holm([t[2] for t in tested])
        for (i, _, _, shift, floor), pw, pb in zip(tested, p_worse, p_better):
            status = OK
            if pw < alpha and shift > floor:
                status = REGRESSED
            elif pb < alpha and -shift > floor:
                status = IMPROVED
            checks[i] = replace(checks[i], status=status, p_value=float(pw))
    return checks


def failed(checks: list[MetricCheck]) -> bool:
    return any(c.failing for c in checks)


def could_not_run(checks: list[MetricCheck]) -> list[MetricCheck]:
    """The rows of scenarios that could not run (missing or invalid file, a run that raised)."""
    return [c for c in checks if c.metric == RUN_ROW and c.status == ERROR]


def exit_code(checks: list[MetricCheck]) -> int:
    """3 if any scenario could not run (the gate could not judge it), else 1 on any
    regression (or missing metric, or metric without a tolerance), else 0."""
    if could_not_run(checks):
        return EXIT_COULD_NOT_RUN
    return EXIT_REGRESSION if failed(checks) else EXIT_PASS


def unrunnable_record(suite: str, scenario: str, error: BaseException | str) -> RunRecord:
    """The failed record of a suite scenario that could not even be resolved."""
    return RunRecord(run_id=f"unresolved:{scenario}", sweep=f"check:{suite}", run_index=-1, scenario=scenario,
                     scenario_hash="", factors={"scenario": scenario}, parameters={}, status=STATUS_FAILED,
                     error=str(error))


def _fmt(v: float) -> str:
    return "—" if not math.isfinite(v) else f"{v:.4g}"


def _p(c: MetricCheck) -> str:
    return f"{c.p_value:.2g}" if math.isfinite(c.p_value) else ""


def _change(c: MetricCheck) -> str:
    if not (math.isfinite(c.baseline) and math.isfinite(c.current)):
        return ""
    rel = f" ({100 * c.delta / abs(c.baseline):+.0f}%)" if c.baseline else ""
    return f"{c.delta:+.4g}{rel}"


_STYLE = {REGRESSED: "bold red", MISSING: "bold red", ERROR: "bold red", IMPROVED: "green", NEW: "cyan", OK: "dim"}
_SCENARIO_NOTES = ("scenario differs from the baseline's", "scenario not in the baseline")


def print_checks(checks: list[MetricCheck], console: Console, suite: str, baseline: Path, verbose: bool = False,
                 wall_s: float | None = None) -> None:
    """A rich table of the regressions (and other changes; every metric with ``verbose``)."""
    shown = [c for c in checks if verbose or c.status != OK]
    scen = sorted({c.scenario for c in checks})
    counts = {s: sum(c.status == s for c in checks) for s in (REGRESSED, MISSING, ERROR, IMPROVED, NEW, OK)}
    if shown:
        n_b = max((c.n_baseline for c in shown), default=1)
        n_c = max((c.n_current for c in shown), default=1)
        how = (f"; medians of {n_c} seeds against {n_b} baseline seeds; regressed: one-sided Mann-Whitney U, Holm-adjusted "
               f"p below alpha and a change beyond the tolerance" if n_b > 1 and n_c > 1 else "")
        t = Table(title=escape(f"simbench check --suite {suite} against {baseline}{how}"), title_justify="left")
        t.add_column("scenario", no_wrap=True)
        t.add_column("metric", no_wrap=True)
        t.add_column("baseline", justify="right", no_wrap=True)
        t.add_column("current", justify="right", no_wrap=True)
        t.add_column("change", justify="right", no_wrap=True)
        t.add_column("tolerance", no_wrap=True)
        t.add_column("p (Holm)", justify="right", no_wrap=True)
        t.add_column("status", no_wrap=True)
        with_notes = any(c.note and c.note not in _SCENARIO_NOTES for c in shown)
        if with_notes:
            t.add_column("note", overflow="fold")
        order = {REGRESSED: 0, MISSING: 1, ERROR: 2, IMPROVED: 3, NEW: 4, OK: 5}
        for c in sorted(shown, key=lambda c: (order[c.status], c.scenario, c.metric)):
            st = _STYLE[c.status]
            row = [escape(c.scenario), escape(c.metric), _fmt(c.baseline), _fmt(c.current), _change(c),
                   c.tolerance.describe() if c.tolerance else "", _p(c), f"[{st}]{c.status.upper()}[/]"]
            if with_notes:
                note = "" if c.note in _SCENARIO_NOTES else c.note
                row.append(escape(f"error: {note}" if c.metric == RUN_ROW and c.status == ERROR else note))
            t.add_row(*row)
        console.print(t)
    for name in scen:
        notes = {c.note for c in checks if c.scenario == name and c.note in _SCENARIO_NOTES}
        for n in sorted(notes):
            console.print(f"note: {name}: {n}", highlight=False, markup=False)
    n_fail = counts[REGRESSED] + counts[MISSING] + counts[ERROR]
    verdict = "[bold red]FAIL[/]" if n_fail else "[bold green]PASS[/]"
    took = f" in {wall_s:.0f} s" if wall_s is not None else ""
    n_b = max((c.n_baseline for c in checks), default=1)
    n_c = max((c.n_current for c in checks), default=1)
    ens = f" ({n_c} seeds each against {n_b} baseline seeds)" if n_c > 1 or n_b > 1 else ""
    console.print(f"{verdict} suite {escape(suite)}: {len(checks)} metrics of {len(scen)} scenarios{ens}{took}: "
                  f"{counts[REGRESSED]} regressed, {counts[MISSING]} missing, {counts[ERROR]} errors, "
                  f"{counts[IMPROVED]} improved, {counts[NEW]} new, {counts[OK]} within tolerance"
                  + (f"; {len(could_not_run(checks))} scenarios could not run" if could_not_run(checks) else ""),
                  highlight=False)


def is_check_junit(path: Path) -> bool:
    """Whether the file at ``path`` is JUnit XML as :func:`write_junit` writes it (a rerun replaces it)."""
    with open(path, "rb") as fh:
        return b'<testsuites name="simbench check"' in fh.read(400)


def write_junit(checks: list[MetricCheck], path: str | Path, suite: str, wall_s: float = 0.0) -> Path:
    """JUnit XML: one test case per scenario and metric; regressions are failures, crashed runs errors."""
    n_fail = sum(c.status in (REGRESSED, MISSING) for c in checks)
    n_err = sum(c.status == ERROR for c in checks)
    root = ET.Element("testsuites", name="simbench check", tests=str(len(checks)), failures=str(n_fail), errors=str(n_err),
                      time=f"{wall_s:.3f}")
    ts = ET.SubElement(root, "testsuite", name=f"simbench.check.{suite}", tests=str(len(checks)), failures=str(n_fail),
                       errors=str(n_err), skipped="0", time=f"{wall_s:.3f}",
                       timestamp=datetime.now(timezone.utc).isoformat(timespec="seconds"))
    for c in checks:
        tc = ET.SubElement(ts, "testcase", classname=f"{suite}.{c.scenario}", name=c.metric, time="0")
        detail = (f"baseline {_fmt(c.baseline)}, current {_fmt(c.current)}, change {_change(c) or 'n/a'}; "
                  f"tolerance: {c.tolerance.describe() if c.tolerance else 'none'}" + (f"; {c.note}" if c.note else "")
                  + (f"; p (one-sided Mann-Whitney U, Holm) {_p(c)}, {c.n_current} seeds against {c.n_baseline}"
                     if math.isfinite(c.p_value) else ""))
        if c.status in (REGRESSED, MISSING):
            ET.SubElement(tc, "failure", message=f"{c.metric} {c.status}: {detail}", type=c.status).text = detail
        elif c.status == ERROR:
            ET.SubElement(tc, "error", message=c.note or "error", type="error").text = c.note
        elif c.status != OK:
            ET.SubElement(tc, "system-out").text = f"{c.status}: {detail}"
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    ET.indent(root)
    atomic_write_bytes(path, ET.tostring(root, encoding="utf-8", xml_declaration=True), fsync=True)
    return path
