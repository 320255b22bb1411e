"""``simbench sweep``, ``simbench report``, ``simbench check`` and ``simbench baseline update``.

Registered on the main app by :func:`register` (see the end of :mod:`simbench.cli.app`).
Each command imports :mod:`simbench.sweeps` when it runs (DuckDB, pandas: the CLI's
``--help`` stays fast).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import Optional

import typer
from rich.console import Console
from rich.markup import escape
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

from simbench.cli.common import console, prepare_shirt_caches_here, user_errors
from simbench.errors import SimbenchInputError


def runs_progress(description: str):
    return Progress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
                    TextColumn("[red]{task.fields[failed]} failed"), TextColumn("[dim]{task.fields[skipped]} skipped"),
                    TimeElapsedColumn(), TextColumn("left"), TimeRemainingColumn(), console=console)


def counting_progress(description: str, total: int):
    """``(progress, on_record)``: a :func:`runs_progress` bar with one task of ``total`` runs, and
    the callback that advances it by one record and counts the failed ones."""
    prog = runs_progress(description)
    task = prog.add_task(description, total=total, failed=0, skipped=0)
    failed = 0

    def on_record(rec) -> None:
        nonlocal failed
        failed += rec.status != "ok"
        prog.update(task, advance=1, failed=failed)

    return prog, on_record


def sweep(sweep_file: Path = typer.Argument(..., help="sweep TOML (scenarios/sweeps/*.toml)"),
          db: Optional[Path] = typer.Option(None, "--db", help="results database (default out/sweeps/<name>/results.duckdb)"),
          workers: Optional[int] = typer.Option(None, "--workers", "-j", min=1, help="local worker processes (default: all cores)"),
          scheduler: Optional[str] = typer.Option(None, "--scheduler", help="run on a Dask cluster: tcp://HOST:PORT"),
          resume: bool = typer.Option(False, "--resume", help="skip runs already finished in this database"),
          outputs: bool = typer.Option(True, "--outputs/--no-outputs", help="keep each run's videos, report and exports"),
          set_: list[str] = typer.Option([], "--set", help="override a field in every run, e.g. --set duration_s=0.3"),
          dry_run: bool = typer.Option(False, "--dry-run", help="list the runs and exit")) -> None:
    """Run a grid or random sample of scenarios; record every run in a DuckDB results database."""
    from simbench.scenario import parse_overrides
    from simbench.sweeps.results_db import ResultsDB
    from simbench.sweeps.sweep import default_db_path, load_sweep, run_sweep

    sw = load_sweep(sweep_file, extra_set=parse_overrides(set_))
    db = db or default_db_path(sw)
    ResultsDB(db)  # refuses a folder that holds another database, before anything is printed or written
    dup = f" ({sw.duplicates} duplicate samples dropped)" if sw.duplicates else ""
    console.print(f"sweep [bold]{escape(sw.name)}[/]: {len(sw.runs)} runs{dup} -> {escape(str(db))}", highlight=False)
    if dry_run:
        for r in sw.runs:
            print(r.run_id, " ".join(f"{k}={v}" for k, v in r.factors.items()))
        return
    prepare_shirt_caches_here((r.scenario for r in sw.runs), scheduler)
    prog = runs_progress(sw.name)
    task = prog.add_task(sw.name, total=len(sw.runs), failed=0, skipped=0)

    def on_progress(p) -> None:
        if p.event == "start":  # runs already done do not count towards the speed (time left)
            prog.reset(task, total=p.total, completed=p.done, failed=p.failed, skipped=p.skipped)
            return
        prog.update(task, completed=p.done, failed=p.failed, skipped=p.skipped)
        if p.event == "run" and p.last is not None and p.last.status != "ok":
            first = p.last.error.splitlines()[0] if p.last.error else ""
            prog.console.print(f"[red]failed[/] run {p.last.run_id} ({escape(_factors(p.last.factors))}): {escape(first)}",
                               highlight=False)

    with prog:
        summary = run_sweep(sw, db, workers=workers, scheduler=scheduler, resume=resume, outputs=outputs,
                            on_progress=on_progress)
    console.print(f"{summary.ran} runs in {summary.wall_s:.1f} s ({summary.failed} failed, {summary.skipped} already done or run by another sweep); "
                  f"database {summary.db}", highlight=False, markup=False)
    if summary.not_ingested:
        console.print(f"{summary.not_ingested} runs are stored in {summary.db.parent / 'results'} but not yet in the "
                      f"database (it was locked by another process); `simbench report` or `--resume` ingests them",
                      highlight=False, markup=False)
    if summary.failed:
        raise typer.Exit(1)


def _factors(f: dict) -> str:
    return ", ".join(f"{k}={v}" for k, v in f.items())


def report(db: Path = typer.Argument(..., help="results database written by `simbench sweep`"),
           out: Path = typer.Option(..., "--out", help="report directory (report.md, report.html, plots/)"),
           sweep_name: Optional[str] = typer.Option(None, "--sweep", help="only this sweep (default: every sweep in the database)"),
           worst: int = typer.Option(8, "--worst", min=1, help="how many worst runs to list")) -> None:
    """HTML and Markdown report of a sweep: each metric against each factor, heatmaps, trackers, worst runs."""
    from simbench.output_dir import AtomicOutputDir
    from simbench.sweeps.report import write_sweep_report

    # a folder of the user's is refused before anything is written, and a report cut short leaves none
    with AtomicOutputDir(out, scenario=f"report of {db}", kind="report") as tmp:
        md = out / write_sweep_report(db, tmp, sweep=sweep_name, n_worst=worst).name
    console.print(f"wrote {md} and {md.with_suffix('.html')}", highlight=False, markup=False)


def check(suite: str = typer.Option(..., "--suite", help="suite name in the suites file, e.g. ci"),
          baseline: Optional[Path] = typer.Option(None, "--baseline", help="baseline JSON (default scenarios/baselines/<suite>.json)"),
          suites_file: Path = typer.Option(Path("scenarios/suites.toml"), "--suites", help="suites file"),
          junit: Optional[Path] = typer.Option(None, "--junit", help="also write JUnit XML here"),
          only: list[str] = typer.Option([], "--only", help="run only these scenarios of the suite"),
          set_: list[str] = typer.Option([], "--set", help="override a field in every scenario (what-if)"),
          out: Optional[Path] = typer.Option(None, "--out", help="run outputs (default out/check/<suite>)"),
          outputs: bool = typer.Option(False, "--outputs/--no-outputs", help="keep each run's videos, report and exports"),
          workers: Optional[int] = typer.Option(None, "--workers", "-j", min=1, help="local worker processes (default: all cores)"),
          scheduler: Optional[str] = typer.Option(None, "--scheduler", help="run on a Dask cluster: tcp://HOST:PORT"),
          verbose: bool = typer.Option(False, "--verbose", "-v", help="list every metric, not only the changed ones"),
          seeds: Optional[int] = typer.Option(None, "--seeds", min=1, max=1000, help="seeds per scenario (default: the suite's `seeds`)"),
          calibrate: bool = typer.Option(False, "--calibrate", help="measure the gate instead: false-alarm rate of the unchanged code "
                                         "and detection rate of injected regressions, on fresh seed sets (long)"),
          calibrate_pool: int = typer.Option(24, "--calibrate-pool", min=2, help="--calibrate: fresh seeds run per scenario and configuration"),
          calibrate_checks: int = typer.Option(200, "--calibrate-checks", min=1, help="--calibrate: checks drawn from each pool")) -> None:
    """Run a suite of scenarios on their seed ensembles and test every metric against the baseline's distribution.

    A metric regressed when a one-sided Mann-Whitney U test (Holm-corrected over the whole check, at the suite's `alpha`, 1 % for ci) finds the current seeds worse than the baseline's and the median moved beyond the metric's tolerance; with one seed per side, the tolerance alone (as before ensembles). A scenario that cannot run (its file is missing or has a bad field, or the run raises) is one row "error: <cause>"; the others still run.

    --calibrate measures the gate: the unchanged code and four injected regressions (2D detection noise +0.2 px, exposure 4 -> 12 ms, tracker kalman -> alpha_beta, one camera fewer) on pools of fresh seeds; prints the false-alarm and detection rates.

    Exit codes: 0 every metric within tolerance; 1 a metric regressed, is missing, or has no tolerance; 2 a bad command line, suites file or baseline (one line, nothing run); 3 a scenario could not run (whether or not others regressed).
    """
    from mocap.atomic_files import check_output_file
    from simbench.output_dir import OutputPathError
    from simbench.sweeps import regression as rg

    suites = rg.load_suites(suites_file)
    suites.get(suite)  # an unknown suite: a user error before anything runs
    if junit is not None:  # a file of the user's there is not replaced (checked before anything runs)
        check_output_file(junit, rg.is_check_junit, "a JUnit file written by simbench check", error=OutputPathError)
    base_path = baseline or rg.default_baseline_path(suites_file, suite)
    base = rg.load_baseline(base_path)
    if calibrate:
        if only or set_ or outputs or seeds is not None:
            raise SimbenchInputError("--calibrate runs the whole suite as defined; drop --only/--set/--outputs/--seeds")
        _calibrate(rg, suites, suite, base, calibrate_pool, calibrate_checks, workers, scheduler, out)
        return
    t0 = time.perf_counter()
    n_seeds = seeds if seeds is not None else suites.get(suite).seeds
    records = _run_suite(rg, suites, suite, only, set_, out, outputs, workers, scheduler, strict=False, seeds=n_seeds)
    checks = rg.compare(records, base, suites.tolerances_for(suite), alpha=suites.get(suite).alpha)
    wall = time.perf_counter() - t0
    out_console = Console() if sys.stdout.isatty() else Console(width=160)
    rg.print_checks(checks, out_console, suite=suite, baseline=base_path, verbose=verbose, wall_s=wall)
    if junit:
        rg.write_junit(checks, junit, suite=suite, wall_s=wall)
        console.print(f"wrote {junit}", highlight=False, markup=False)
    code = rg.exit_code(checks)
    if code:
        raise typer.Exit(code)


def _calibrate(rg, suites, suite, base, pool: int, n_checks: int, workers, scheduler, out: Optional[Path]) -> None:
    """``simbench check --calibrate``: run the pools with a progress bar, print the rates; with
    ``--out DIR``, ``DIR/calibration.json`` holds the rates and every pool run's metrics."""
    import json

    from simbench.output_dir import AtomicOutputDir, replaceable_state
    from simbench.sweeps.calibrate import INJECTIONS, calibrate

    if out is not None:
        replaceable_state(out)  # before hours of runs
    suites.get(suite)  # an unknown suite is refused before any run
    n_configs = 1 + len(INJECTIONS)
    prog = runs_progress(f"calibrate {suite}")
    task = prog.add_task(f"calibrate {suite}", total=None, failed=0, skipped=0)
    state = {"done": 0, "failed": 0, "total": 0, "configs": 0}

    def on_runs(name: str, n: int) -> None:
        state["total"] += n
        state["configs"] += 1
        prog.update(task, total=state["total"], description=f"calibrate {suite}: {name} ({state['configs']}/{n_configs})")

    def on_record(rec) -> None:
        state["done"] += 1
        state["failed"] += rec.status != "ok"
        prog.update(task, completed=state["done"], failed=state["failed"])

    t0 = time.perf_counter()
    with prog:
        cal = calibrate(suites, suite, base, pool=pool, checks=n_checks, workers=workers, scheduler=scheduler,
                        on_runs=on_runs, on_record=on_record)
    cal.wall_s = time.perf_counter() - t0
    from rich.table import Table

    out_console = Console() if sys.stdout.isatty() else Console(width=200)
    t = Table(title=f"simbench check --calibrate --suite {escape(suite)}: {cal.checks} checks per configuration, each "
                    f"{cal.seeds_per_check} seeds per scenario drawn from {cal.pool} fresh seeds "
                    f"({cal.pool // cal.seeds_per_check} disjoint sets), against {escape(str(base.path))}; alpha {cal.alpha:g} per check",
              title_justify="left")
    for col in ("configuration", "scenarios changed", "checks failed", "rate", "95% CI (draws as independent)", "most flagged"):
        t.add_column(col, no_wrap=col != "most flagged")
    for i, r in enumerate(cal.rows):
        lo, hi = r.interval()
        kind = "false alarms" if i == 0 else "detected"
        top = ", ".join(f"{k} ({v})" for k, v in r.flagged.most_common(3))
        t.add_row(escape(r.name), escape(", ".join(r.changed_scenarios) or ("-" if i == 0 else "none")),
                  f"{r.failed_checks}/{r.checks} {kind}", f"{100 * r.rate:.1f} %", f"{100 * lo:.1f} .. {100 * hi:.1f} %",
                  escape(top))
    out_console.print(t)
    fa = cal.rows[0].rate
    det = [r.rate for r in cal.rows[1:]]
    verdict = "[bold green]meets[/]" if fa <= 0.01 and all(d >= 0.95 for d in det) else "[bold red]misses[/]"
    out_console.print(f"{verdict} the bar (false alarms <= 1 % of checks, detection >= 95 % per injected regression): "
                      f"false alarms {100 * fa:.1f} %, detection " + ", ".join(f"{100 * d:.0f} %" for d in det)
                      + f"; {cal.n_runs} runs in {cal.wall_s:.0f} s", highlight=False)
    if out is not None:
        with AtomicOutputDir(out, scenario=f"calibrate {suite}", kind="run") as tmp:
            (tmp / "calibration.json").write_text(json.dumps(cal.to_json(), indent=1) + "\n")
        console.print(f"wrote {out}/calibration.json", highlight=False, markup=False)


def _run_suite(rg, suites, suite, only, set_, out, outputs, workers, scheduler, strict: bool = True, seeds=None):
    """Run the suite; ``{scenario name: [record per seed]}`` in suite order. Scenarios that cannot be
    resolved raise (``strict``, for baselines) or become failed records (``check``). ``seeds``:
    see :func:`simbench.sweeps.regression.run_suite`."""
    from simbench.scenario import parse_overrides

    out_dir = (out or Path("out") / "check" / suite) if outputs else None
    if strict:
        runs, unrunnable = suites.runs(suite, only=only, extra_set=parse_overrides(set_)), {}
    else:
        runs, unrunnable = suites.resolve(suite, only=only, extra_set=parse_overrides(set_))
    per = len(next(iter(seeds.values()))) if isinstance(seeds, dict) else (seeds or 1)
    prepare_shirt_caches_here((r.scenario for r in runs), scheduler)
    prog = runs_progress(f"suite {suite}")
    task = prog.add_task(f"suite {suite}" + (f", {per} seeds each" if per > 1 else ""), total=per * len(runs) + len(unrunnable),
                         failed=len(unrunnable), skipped=0, completed=len(unrunnable))

    def on_record(rec, n_done: int, n_failed: int) -> None:
        prog.update(task, completed=n_done + len(unrunnable), failed=n_failed + len(unrunnable))

    with prog:
        records = rg.run_suite(runs, out_dir=out_dir, workers=workers, scheduler=scheduler, on_record=on_record, seeds=seeds)
    records.update({name: rg.unrunnable_record(suite, name, err) for name, err in unrunnable.items()})
    order = [sc.name for sc in suites.get(suite).scenarios]
    return {name: records[name] for name in order if name in records}


def compare(first: Path = typer.Argument(..., help="scenario TOML, `simbench run --seeds` folder or results database (A)"),
            second: Optional[Path] = typer.Argument(None, help="the same kind for B (omit with --a/--b overrides on one scenario)"),
            a_set: list[str] = typer.Option([], "--a", help="override for configuration A, e.g. --a markers_pipeline.tracker=kalman"),
            b_set: list[str] = typer.Option([], "--b", help="override for configuration B, e.g. --b markers_pipeline.tracker=alpha_beta"),
            set_: list[str] = typer.Option([], "--set", help="override a field on both sides"),
            seeds: int = typer.Option(10, "--seeds", min=2, max=1000, help="number of seeds (the same seeds on both sides)"),
            seed_start: Optional[int] = typer.Option(None, "--seed-start", min=0, help="first seed (default: A's scenario seed)"),
            metric: list[str] = typer.Option([], "--metric", help="only metrics matching this pattern (fnmatch; repeatable)"),
            suites_file: Path = typer.Option(Path("scenarios/suites.toml"), "--suites", help="suites file whose tolerances give each metric's better direction"),
            sweep_name: Optional[str] = typer.Option(None, "--sweep", help="databases: only this sweep's runs"),
            out: Optional[Path] = typer.Option(None, "--out", help="also keep both sides' runs, compare.json and compare.md here"),
            workers: Optional[int] = typer.Option(None, "--workers", "-j", min=1, help="local worker processes (default: all cores)"),
            scheduler: Optional[str] = typer.Option(None, "--scheduler", help="run on a Dask cluster: tcp://HOST:PORT")) -> None:
    """Compare two configurations on the same seeds: paired differences with their CI, Wilcoxon test, verdict, detectable effect.

    A and B: one scenario with --a/--b overrides (two trackers, two pipelines), two scenario files, two `simbench run --seeds` folders (paired by seed), or two results databases of `simbench sweep` (paired by factor levels).

    Exit codes: 0 compared; 2 a bad command line or file; 3 some runs failed (their metrics are NaN, left out of the pairs).
    """
    from simbench.output_dir import replaceable_state
    from simbench.scenario import load_scenario, parse_overrides
    from simbench.sweeps import compare as cp
    from simbench.sweeps import regression as rg

    better = cp.direction_lookup(list(rg.load_suites(suites_file).spec.tolerances.items()))
    both, ov_a, ov_b = parse_overrides(set_), parse_overrides(a_set), parse_overrides(b_set)
    kind = _compare_kind(first, second, bool(a_set or b_set))
    if kind == "scenario":
        path_b = second or first
        sc_a = load_scenario(first, overrides={**both, **ov_a})
        sc_b = load_scenario(path_b, overrides={**both, **ov_b})
        if sc_a.content_hash() == sc_b.content_hash():
            raise SimbenchInputError(f"{first}: A and B are the same configuration; give --a/--b overrides that differ, "
                                     f"or two different scenario files")
        if out is not None:
            replaceable_state(out)
        label = lambda p, ov: f"{p}" + (f" ({' '.join(f'{k}={v}' for k, v in ov.items())})" if ov else "")  # noqa: E731
        prepare_shirt_caches_here([sc_a, sc_b], scheduler)
        prog, on_record = counting_progress(f"compare {sc_a.name}, {seeds} seeds x 2", 2 * seeds)
        with prog:
            cmp = cp.run_two(sc_a, sc_b, seeds, seed_start, (label(first, ov_a), label(path_b, ov_b)), ({**both, **ov_a}, {**both, **ov_b}),
                             better, metric or None, out, workers, scheduler, on_record)
    else:
        if set_ or a_set or b_set or out is not None:
            raise SimbenchInputError("--set/--a/--b/--out are for scenarios; stored results are compared as they are")
        side_a, side_b, pairs = (cp.paired_seed_folders(first, second) if kind == "folders"
                                 else cp.paired_databases(first, second, sweep_name))
        cmp = cp.compare_sides(side_a, side_b, pairs, better, metric or None)
    _print_comparison(cp, cmp)
    if out is not None:
        console.print(f"wrote {out}/compare.json, {out}/compare.md and each side's runs in {out}/a, {out}/b",
                      highlight=False, markup=False)
    if cmp.a.failures or cmp.b.failures:
        raise typer.Exit(3)


def _compare_kind(first: Path, second: Optional[Path], overrides: bool) -> str:
    if second is None:
        if first.suffix != ".toml":
            raise SimbenchInputError(f"{first}: one argument must be a scenario TOML with --a/--b overrides; "
                                     f"to compare stored results give two folders or two databases")
        if not overrides:
            raise SimbenchInputError(f"{first}: one scenario needs --a FIELD=VALUE and/or --b FIELD=VALUE to differ")
        return "scenario"
    kinds = []
    for p in (first, second):
        if p.is_dir() and (p / "metrics.json").is_file():
            kinds.append("folders")
        elif p.suffix == ".duckdb":
            kinds.append("databases")
        elif p.suffix == ".toml":
            kinds.append("scenario")
        else:
            raise SimbenchInputError(f"{p}: not a scenario TOML, a `simbench run --seeds` folder (with metrics.json) or a "
                                     f"results database (.duckdb)")
    if kinds[0] != kinds[1]:
        raise SimbenchInputError(f"{first} and {second}: compare two of the same kind (got {kinds[0]} and {kinds[1]})")
    return kinds[0]


def _print_comparison(cp, cmp) -> None:
    from rich.table import Table

    out_console = Console() if sys.stdout.isatty() else Console(width=200)
    out_console.print(f"A = {escape(cmp.a.label)}\nB = {escape(cmp.b.label)}", highlight=False)
    t = Table(title=f"B - A over {len(cmp.pairs)} pairs ({escape(cmp.pairs[0])} .. {escape(cmp.pairs[-1])}); "
                    f"Wilcoxon signed-rank, alpha {cp.ALPHA}; detectable: power {cp.POWER}", title_justify="left")
    for col, just in (("metric", "left"), ("better", "left"), ("A mean", "right"), ("B mean", "right"),
                      ("B - A", "right"), ("95% CI", "right"), ("p", "right"), ("verdict", "left"), ("detectable", "right")):
        t.add_column(col, justify=just, no_wrap=True)
    for m, r in cmp.rows.items():
        v = cmp.verdict(m)
        style = "dim" if v.startswith("no detectable") else "bold"
        t.add_row(escape(m), cmp.directions.get(m) or "either", cp._f(r.a_mean), cp._f(r.b_mean), cp._f(r.diff_mean, "+.4g"),
                  f"{cp._f(r.ci_low, '+.3g')} .. {cp._f(r.ci_high, '+.3g')}", cp._f(r.p_value, ".2g"),
                  f"[{style}]{escape(v)}[/]", cp._f(r.detectable, ".3g"))
    out_console.print(t)
    for side in (cmp.a, cmp.b):
        for f in side.failures:
            console.print(f"failed in {side.label}: {f}", highlight=False, markup=False)


baseline_app = typer.Typer(no_args_is_help=True, help="Baselines of regression suites.")


@baseline_app.command("update")
@user_errors
def baseline_update(suite: str = typer.Option(..., "--suite", help="suite name in the suites file"),
                    baseline: Optional[Path] = typer.Option(None, "--baseline", help="baseline JSON to write (default scenarios/baselines/<suite>.json)"),
                    suites_file: Path = typer.Option(Path("scenarios/suites.toml"), "--suites", help="suites file"),
                    workers: Optional[int] = typer.Option(None, "--workers", "-j", min=1),
                    scheduler: Optional[str] = typer.Option(None, "--scheduler")) -> None:
    """Run a suite and rewrite its baseline from the results (failed runs abort the update)."""
    from simbench.sweeps import regression as rg

    suites = rg.load_suites(suites_file)
    suites.get(suite)
    path = baseline or rg.default_baseline_path(suites_file, suite)
    s = suites.get(suite)
    seeds = None
    if s.seeds > 1:  # the baseline's own seeds, disjoint from the check's
        seeds = {str(r.factors["scenario"]): rg.ensemble_seeds(r, s.n_baseline_seeds, rg.BASELINE_SEED_OFFSET)
                 for r in suites.runs(suite)}
    records = _run_suite(rg, suites, suite, [], [], None, False, workers, scheduler, seeds=seeds)
    rg.write_baseline(path, suite, records)
    console.print(f"wrote {path}: {len(records)} scenarios" + (f", {s.n_baseline_seeds} seeds each" if seeds else ""),
                  highlight=False, markup=False)


def register(app: typer.Typer) -> None:
    """Add the sweep, report, check and baseline commands to the ``simbench`` app."""
    app.command("sweep")(user_errors(sweep))
    app.command("report")(user_errors(report))
    app.command("check")(user_errors(check))
    app.command("compare")(user_errors(compare))
    app.add_typer(baseline_app, name="baseline")

