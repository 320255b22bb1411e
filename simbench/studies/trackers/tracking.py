"""Every tracker on one rendered video, scored against the true positions (:func:`run_video`)."""

from __future__ import annotations

from dataclasses import dataclass
import time
import zlib

import numpy as np

from eval import tracking_metrics as tm
from mocap.tracking import track_camera, CameraTracks
from simbench.render.rasterizer import Rasterizer
from simbench.studies.trackers.config import StudyConfig, _CATEGORY_CODE
from simbench.studies.trackers.rendering import RenderedVideo, render_video
from simbench.studies.trackers.videos import Barrier, VideoPlan, plan_video


@dataclass
class TrackerRun:
    """One tracker on one video: its tracks, losses (and those scoring merged frames
    too, ``losses_strict``) and prediction errors (px)."""

    tracks: CameraTracks
    losses: tm.LabelLosses
    losses_strict: tm.LabelLosses
    errors: np.ndarray

    @property
    def lost(self) -> bool:
        return tm.video_lost(self.losses)


@dataclass
class VideoResult:
    """Everything logged about one video."""

    category: str
    index: int
    params: dict
    render_seed: int
    barrier: Barrier | None
    video: RenderedVideo
    runs: dict[str, TrackerRun]
    seconds: float


def tracker_rng(config: StudyConfig, category: str, index: int, tracker: str) -> np.random.Generator:
    """Generator of one tracker on one video (stable across runs and tracker lists)."""
    return np.random.default_rng(np.random.SeedSequence(
        [config.seed, _CATEGORY_CODE[category], index, zlib.crc32(tracker.encode())]))


def n_labels(plan: VideoPlan) -> int:
    """Labelled markers of a video: all of them, except in a swap video with one labelled
    marker and an unlabelled ("NULL") one (seed 000's Fig. 5), where only marker 0 is."""
    return int(plan.params.get("labelled", plan.n_markers))


def score_labels(true_xy: np.ndarray, visible: np.ndarray, estimate: np.ndarray, status: np.ndarray,
                 measured_xy: np.ndarray, radius_px: float) -> tm.LabelLosses:
    """:func:`eval.tracking_metrics.label_losses` of the first ``L`` markers, labelled,
    among ``M >= L`` markers (the others unlabelled, e.g. the NULL marker).

    Parameters
    ----------
    true_xy : (F, M, 2) float
        True image positions of every marker, px.
    visible : (F, M) bool
    estimate, measured_xy : (F, L, 2) float
        The labels' estimates and associated detections, px.
    status : (F, L) int
    radius_px : float

    Returns
    -------
    LabelLosses of the L labels; a label that takes an unlabelled marker's blob counts
    as a loss ("other") as it does for a labelled one.
    """
    F, M = true_xy.shape[:2]
    L = estimate.shape[1]
    if L == M:
        return tm.label_losses(true_xy, visible, estimate, status, measured_xy, radius_px)
    # The unlabelled markers as phantom labels that are never scored (not visible): the
    # labelled ones are then checked against their blobs too.
    pad = ((0, 0), (0, M - L))
    est = np.concatenate([estimate, true_xy[:, L:]], axis=1)
    meas = np.concatenate([measured_xy, np.full((F, M - L, 2), np.nan)], axis=1)
    stat = np.pad(np.asarray(status), pad, constant_values=1)
    vis = np.asarray(visible, dtype=bool).copy()
    vis[:, L:] = False
    full = tm.label_losses(true_xy, vis, est, stat, meas, radius_px)
    return tm.LabelLosses(lost=full.lost[:L], first_frame=full.first_frame[:L], reason=full.reason[:L],
                          flags=full.flags[:, :L], bad_frames=full.bad_frames[:L], at_end=full.at_end[:L])


def track_video(video: RenderedVideo, plan: VideoPlan, config: StudyConfig,
                trackers: dict[str, str]) -> dict[str, TrackerRun]:
    """Run every tracker (display name -> registry name or ``module:Class``) on the
    video's detections from the labelled markers' true first-frame positions, and score it."""
    L = n_labels(plan)
    labels = [f"marker{m}" for m in range(L)]
    runs = {}
    for name, spec in trackers.items():
        tracks = track_camera(video.detections, video.true_xy[0, :L], labels, spec, config.dt,
                              tracker_rng(config, plan.category, plan.index, name))
        losses, strict = (score_labels(video.true_xy, vis, tracks.estimate, tracks.status, tracks.xy,
                                       config.loss_radius_px) for vis in (video.visible, video.visible_area))
        runs[name] = TrackerRun(tracks, losses, strict, tm.prediction_errors(tracks.predicted, tracks.xy))
    return runs


def run_video(config: StudyConfig, category: str, index: int, trackers: dict[str, str], rasterizer: Rasterizer) -> VideoResult:
    """Plan, render, detect, track and score one video."""
    t0 = time.perf_counter()
    plan = plan_video(config, category, index)
    video = render_video(plan, config, rasterizer, keep_sample=index == 0)
    runs = track_video(video, plan, config, trackers)
    return VideoResult(category, index, plan.params, plan.render_seed, plan.barrier, video, runs,
                       time.perf_counter() - t0)


def _run_chunk(config: StudyConfig, jobs: list[tuple[str, int]], trackers: dict[str, str]) -> list[VideoResult]:
    """Worker: a few videos with one GL context."""
    with Rasterizer() as raster:
        return [run_video(config, c, k, trackers, raster) for c, k in jobs]
