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

from simbench.cli.common import console, user_errors


def _runs_progress(description: str):
    return Progress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
                    TextColumn("[red]{task.fields[failed]} failed"), TextColumn("[dim]{task.fields[skipped]} skipped"),
                    TimeElapsedColumn(), TextColumn("left"), TimeRemainingColumn(), console=console)


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
    from simbench.sweeps.sweep import default_db_path, load_sweep, run_sweep

    sw = load_sweep(sweep_file, extra_set=parse_overrides(set_))
    db = db or default_db_path(sw)
    dup = f" ({sw.duplicates} duplicate samples dropped)" if sw.duplicates else ""
    console.print(f"sweep [bold]{escape(sw.name)}[/]: {len(sw.runs)} runs{dup} -> {escape(str(db))}", highlight=False)
    if dry_run:
        for r in sw.runs:
            print(r.run_id, " ".join(f"{k}={v}" for k, v in r.factors.items()))
        return
    prog = _runs_progress(sw.name)
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
    from simbench.sweeps.report import write_sweep_report

    md = write_sweep_report(db, out, sweep=sweep_name, n_worst=worst)
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
          verbose: bool = typer.Option(False, "--verbose", "-v", help="list every metric, not only the changed ones")) -> None:
    """Run a suite of scenarios and compare every metric with the baseline.

    A scenario that cannot run (its file is missing or has a bad field, or the run raises) is one row "error: <cause>"; the others still run.

    Exit codes: 0 every metric within tolerance; 1 a metric regressed, is missing, or has no tolerance; 2 a bad command line, suites file or baseline (one line, nothing run); 3 a scenario could not run (whether or not others regressed).
    """
    from simbench.sweeps import regression as rg

    suites = rg.load_suites(suites_file)
    suites.get(suite)  # an unknown suite: a user error before anything runs
    base_path = baseline or rg.default_baseline_path(suites_file, suite)
    base = rg.load_baseline(base_path)
    t0 = time.perf_counter()
    records = _run_suite(rg, suites, suite, only, set_, out, outputs, workers, scheduler, strict=False)
    checks = rg.compare(records, base, suites.tolerances_for(suite))
    wall = time.perf_counter() - t0
    out_console = Console() if sys.stdout.isatty() else Console(width=160)
    rg.print_checks(checks, out_console, suite=suite, baseline=base_path, verbose=verbose, wall_s=wall)
    if junit:
        rg.write_junit(checks, junit, suite=suite, wall_s=wall)
        console.print(f"wrote {junit}", highlight=False, markup=False)
    code = rg.exit_code(checks)
    if code:
        raise typer.Exit(code)


def _run_suite(rg, suites, suite, only, set_, out, outputs, workers, scheduler, strict: bool = True):
    """Run the suite; ``{scenario name: record}`` in suite order. Scenarios that cannot be
    resolved raise (``strict``, for baselines) or become failed records (``check``)."""
    from simbench.scenario import parse_overrides

    out_dir = (out or Path("out") / "check" / suite) if outputs else None
    if strict:
        runs, unrunnable = suites.runs(suite, only=only, extra_set=parse_overrides(set_)), {}
    else:
        runs, unrunnable = suites.resolve(suite, only=only, extra_set=parse_overrides(set_))
    prog = _runs_progress(f"suite {suite}")
    task = prog.add_task(f"suite {suite}", total=len(runs) + len(unrunnable), failed=len(unrunnable), skipped=0,
                         completed=len(unrunnable))

    def on_record(rec, n_done: int, n_failed: int) -> None:
        prog.update(task, completed=n_done + len(unrunnable), failed=n_failed + len(unrunnable))

    with prog:
        records = rg.run_suite(runs, out_dir=out_dir, workers=workers, scheduler=scheduler, on_record=on_record)
    records.update({name: rg.unrunnable_record(suite, name, err) for name, err in unrunnable.items()})
    order = [sc.name for sc in suites.get(suite).scenarios]
    return {name: records[name] for name in order if name in records}


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
    records = _run_suite(rg, suites, suite, [], [], None, False, workers, scheduler)
    rg.write_baseline(path, suite, records)
    console.print(f"wrote {path}: {len(records)} scenarios", highlight=False, markup=False)


def register(app: typer.Typer) -> None:
    """Add the sweep, report, check and baseline commands to the ``simbench`` app."""
    app.command("sweep")(user_errors(sweep))
    app.command("report")(user_errors(report))
    app.command("check")(user_errors(check))
    app.add_typer(baseline_app, name="baseline")

