"""The whole study: every video of every category, rendered in worker processes, tracked and
scored, and the cost of every tracker (:func:`run_study`)."""

from __future__ import annotations

from dataclasses import dataclass, field
import concurrent.futures as cf
import multiprocessing
import time
import zlib
from typing import Callable

import numpy as np

from eval import tracking_metrics as tm
from eval.seed_stats import SeedSummary, bootstrap_summary
from simbench.benchmarks.trackers import run_tracker_benchmark, BenchmarkTable
from simbench.render.rasterizer import Rasterizer
from simbench.studies.trackers.config import ERROR_CATEGORIES, StudyConfig, _importable_spec, study_trackers
from simbench.studies.trackers.tracking import VideoResult, _run_chunk, run_video


@dataclass
class StudyResult:
    """All numbers of one study run.

    losses : category -> tracker -> videos with a loss (Table I)
    losses_strict : the same, merged frames scored too
    losses_unrecovered : videos with a label still lost at its marker's last visible frame
    errors : category -> tracker -> ErrorSummary (Tables II-IV)
    error_samples : category -> tracker -> (n,) px (for the plots)
    errors_across_videos : category -> tracker -> SeedSummary of the per-video mean prediction
        error (px; one value per video the tracker did not lose): the videos are the independent
        replicates, so this interval (bootstrap, :mod:`eval.seed_stats`) is the one to compare
        trackers by; the pooled interval of ``errors`` treats every frame as independent
    cost : BenchmarkTable (Tables V-VII)
    """

    config: StudyConfig
    trackers: list[str]
    videos: list[VideoResult]
    losses: dict[str, dict[str, int]]
    losses_strict: dict[str, dict[str, int]]
    losses_unrecovered: dict[str, dict[str, int]]
    errors: dict[str, dict[str, tm.ErrorSummary]]
    error_samples: dict[str, dict[str, np.ndarray]]
    cost: BenchmarkTable
    seconds: dict[str, float] = field(default_factory=dict)
    errors_across_videos: dict[str, dict[str, SeedSummary]] = field(default_factory=dict)

    def total_losses(self) -> dict[str, int]:
        return tm.total_losses(self.losses)


def _chunks(jobs: list[tuple[str, int]], n_chunks: int) -> list[list[tuple[str, int]]]:
    n_chunks = max(1, min(n_chunks, len(jobs)))
    return [jobs[k::n_chunks] for k in range(n_chunks)]


def run_study(config: StudyConfig, progress: Callable[[int, int], None] | None = None) -> StudyResult:
    """Render every video, run every tracker, score them, and time the trackers.

    Parameters
    ----------
    config : StudyConfig
    progress : callable (done, total), optional
        Called after each finished chunk of videos.
    """
    names = study_trackers(config)
    jobs = [(c, k) for c in config.categories for k in range(config.videos_per_category)]
    t0 = time.perf_counter()
    results: list[VideoResult] = []
    if config.workers == 1:
        with Rasterizer() as raster:
            for done, (c, k) in enumerate(jobs, 1):
                results.append(run_video(config, c, k, {n: n for n in names}, raster))
                if progress is not None:
                    progress(done, len(jobs))
    else:
        specs = {n: _importable_spec(n) for n in names}
        chunks = _chunks(jobs, 4 * config.workers)
        ctx = multiprocessing.get_context("spawn")  # fresh GL state per worker
        with cf.ProcessPoolExecutor(max_workers=config.workers, mp_context=ctx) as pool:
            futures = [pool.submit(_run_chunk, config, ch, specs) for ch in chunks]
            done = 0
            for fut in cf.as_completed(futures):
                part = fut.result()
                results.extend(part)
                done += len(part)
                if progress is not None:
                    progress(done, len(jobs))
    order = {j: i for i, j in enumerate(jobs)}
    results.sort(key=lambda r: order[(r.category, r.index)])
    t_videos = time.perf_counter() - t0

    losses = tm.count_losses((r.category, n, r.runs[n].lost) for r in results for n in names)
    strict = tm.count_losses((r.category, n, tm.video_lost(r.runs[n].losses_strict)) for r in results for n in names)
    unrecovered = tm.count_losses((r.category, n, bool(r.runs[n].losses.at_end.any())) for r in results for n in names)
    errors: dict[str, dict[str, tm.ErrorSummary]] = {}
    samples: dict[str, dict[str, np.ndarray]] = {}
    across: dict[str, dict[str, SeedSummary]] = {}
    for c in ERROR_CATEGORIES:
        if c not in config.categories:
            continue
        samples[c] = {}
        errors[c] = {}
        across[c] = {}
        for n in names:
            vals = [r.runs[n].errors for r in results if r.category == c and not r.runs[n].lost]
            v = np.concatenate(vals) if vals else np.zeros(0)
            samples[c][n] = v
            errors[c][n] = tm.summarise_errors(v, level=config.confidence)
            video_means = [float(np.mean(x)) for x in vals if len(x)]
            across[c][n] = bootstrap_summary(video_means, 0.95, np.random.default_rng(
                np.random.SeedSequence([config.seed, 0xB007, zlib.crc32(f"{c}/{n}".encode())])))

    t1 = time.perf_counter()
    cost = run_tracker_benchmark(marker_counts=config.cost_marker_counts, n_frames=config.cost_frames,
                                 seed=config.seed, trackers=names, dt=config.dt, include_reference=False)
    seconds = {"videos": t_videos, "cost": time.perf_counter() - t1}
    return StudyResult(config, names, results, losses, strict, unrecovered, errors, samples, cost, seconds, across)
