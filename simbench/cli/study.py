"""``simbench study``: studies that regenerate a paper's experiments on the bench.

``simbench study trackers --out DIR`` runs :mod:`simbench.studies.trackers` (seed 000's
Tables I-VII for every registered tracker) and prints the tables; registered on the main
app at the end of :mod:`simbench.cli.app`.
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path
from typing import Optional

import typer
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

from simbench.cli.common import console, user_errors
from simbench.errors import SimbenchInputError

study_app = typer.Typer(no_args_is_help=True, help="Regenerate a paper's experiments on the bench, with its numbers beside ours.")


def _split_names(items: list[str]) -> tuple[str, ...] | None:
    names = [n.strip() for item in items for n in item.split(",") if n.strip()]
    return tuple(names) if names else None


def _default_workers() -> int:
    try:
        return max(1, min(2, len(os.sched_getaffinity(0))))
    except AttributeError:  # not Linux
        return max(1, min(2, os.cpu_count() or 1))


@study_app.command("trackers")
@user_errors
def trackers(
    out: Path = typer.Option(..., "--out", help="output folder (report.md, tables.json, losses.csv, videos/, plots/, frames/)"),
    videos: int = typer.Option(20, "--videos", min=1, help="videos per category (seed 000: 20)"),
    seed: int = typer.Option(0, "--seed", min=0, help="root seed of the videos and the stochastic trackers"),
    tracker_names: list[str] = typer.Option([], "--trackers", help="trackers to compare (repeat or comma-separate); default every registered tracker"),
    frames: int = typer.Option(80, "--frames", min=10, help="frames per video (seed 000: about 80)"),
    categories: list[str] = typer.Option([], "--categories", help="subset of slow, rapid, acceleration, occlusion, swap"),
    cost_frames: int = typer.Option(200, "--cost-frames", min=2, help="frames per cost measurement (Tables V-VII)"),
    workers: Optional[int] = typer.Option(None, "--workers", "-j", min=1, help="rendering processes (default: up to 2 cores)"),
) -> None:
    """Seed 000's tracker comparison (losses, prediction errors, cost: Tables I-VII) on rendered videos."""
    from simbench.studies.trackers import CATEGORIES, StudyConfig, format_findings, format_tables, run_study, write_study

    cats = _split_names(categories) or CATEGORIES
    try:
        cfg = StudyConfig(videos_per_category=videos, n_frames=frames, seed=seed, trackers=_split_names(tracker_names),
                          categories=cats, cost_frames=cost_frames, workers=workers or _default_workers())
    except ValueError as exc:
        raise SimbenchInputError(str(exc)) from exc
    total = len(cfg.categories) * cfg.videos_per_category
    t0 = time.perf_counter()
    with Progress(TextColumn("[bold]videos"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(), TextColumn("eta"),
                  TimeRemainingColumn(), console=console, disable=not sys.stderr.isatty()) as prog:
        task = prog.add_task("videos", total=total)
        result = run_study(cfg, progress=lambda done, _total: prog.update(task, completed=done))
    report = write_study(result, out)
    print(format_tables(result))
    tot = result.total_losses()
    print("Total losses: " + ", ".join(f"{n} {tot[n]}" for n in result.trackers))
    print()
    print("### Seed 000's findings, checked (99 %: McNemar on the same videos, Welch on the errors)")
    print()
    print(format_findings(result))
    console.print(f"report: {report} ({time.perf_counter() - t0:.0f} s)")


@study_app.command("fit-difficulty")
@user_errors
def fit_difficulty(
    videos: int = typer.Option(40, "--videos", min=5, help="synthetic videos per category and evaluation"),
    seed: int = typer.Option(1, "--seed", min=0, help="seed of the fit videos (the study's own default is 0)"),
    noise: float = typer.Option(0.08, "--noise", min=0.0, help="detection noise, px per axis (rendered detector: ~0.08)"),
    categories: list[str] = typer.Option([], "--categories", help="subset of slow, rapid, acceleration"),
    max_evaluations: int = typer.Option(150, "--max-evaluations", min=5, help="Nelder-Mead evaluations per category"),
) -> None:
    """Fit the videos' motion so that seed 000's trackers reproduce its Tables II-IV; print the difficulty."""
    from simbench.studies.trackers.fit import FIT_CATEGORIES, fit_difficulty as fit, format_fit

    cats = _split_names(categories) or FIT_CATEGORIES
    unknown = sorted(set(cats) - set(FIT_CATEGORIES))
    if unknown:
        raise SimbenchInputError(f"--categories: {', '.join(unknown)} not fittable; choose from {', '.join(FIT_CATEGORIES)}")
    t0 = time.perf_counter()
    print(format_fit(fit(n_videos=videos, seed=seed, noise_px=noise, categories=cats, max_evaluations=max_evaluations)))
    console.print(f"({time.perf_counter() - t0:.0f} s)")
