"""Seed 000's tracker experiments (Tables I-VII) regenerated on the bench.

``simbench study trackers --out DIR`` renders seed 000's test videos through the bench's
own camera model, runs every registered 2D tracker on the same detections, scores them
against the exact ground truth with :mod:`eval.tracking_metrics` and writes
``report.md`` with the paper's numbers beside ours.

The videos
----------
One virtual 640x480 webcam (60 deg horizontal field of view, so 554 px focal length,
no distortion) at 30 fps looks at a vertical plane 2 m in front of it; retro-reflective
14 mm markers (about 4 px across, blobs of ~6 px with their glow and motion blur) move in
that plane in front of a dark room, seen in IR mode (ring light, 8 ms exposure, motion
blur by shutter sub-frames, photon and read noise). Paths are drawn in pixels and placed
on the plane by back-projection, so the speeds below are image speeds. Five categories,
``videos_per_category`` seeded videos each, ``n_frames`` frames (80 by default), their
motion set by ``config.difficulty`` (:class:`VideoDifficulty`; default
:data:`CALIBRATED_DIFFICULTY`, fitted so that seed 000's three trackers' mean prediction
errors match its Tables II-IV, :mod:`simbench.studies.trackers.fit`):

* ``slow`` and ``rapid`` -- zigzags in several directions (about 19-28 px/frame; rapid:
  shorter legs, sharper turns);
* ``acceleration`` -- speeding up from ~1 px/frame to 22-29 px/frame along a gently bent
  path, braking the other way round, or oscillating to and fro (simple harmonic motion,
  0.36-0.66 s period);
* ``occlusion`` -- a dark box (the barrier, 1 m from the camera, 30-120 px wide, 100-220 px
  tall in the image) hides the marker while it crosses it at the slow speeds on a
  straight, arc or wavy path; a fast marker may leave the image later (not scored there);
* ``swap`` -- as seed 000's Fig. 5, a labelled marker and an unlabelled one ("NULL", 3 cm
  behind it) whose straight paths cross at 8-30 deg, 0-5 px apart, at the slow speeds;
  their blobs merge while they overlap. They start at least ``3 * loss_radius_px``
  apart. A label that takes the NULL marker's blob is a loss.

Occlusion and swap have no prediction-error table in the paper: their difficulty is not
fitted.

Each video is rendered once; every tracker runs on its detections
(:func:`mocap.detection.detect_markers`), its labels initialised at the labelled
markers' true first-frame positions (seed 000's manual initialisation), with a generator
seeded per video and tracker. A marker is *visible* in a frame when at least half of its expected area shows
in the id map at mid-exposure (``min_visible_fraction``), it lies in the image and no other
marker is within ``merge_px`` (7 px: closer blobs merge into one, and neither marker is
visible on its own -- the swap videos' crossing, scored like an occlusion).

Scores (definitions in :mod:`eval.tracking_metrics`, the same for every tracker)
----------------------------------------------------------------------------------
* Table I: videos (of ``videos_per_category``) in which some label was lost: declared
  lost, estimate more than ``loss_radius_px`` (10 px, about 1.7 blob diameters) from its
  visible marker, or took another marker's blob while the markers were apart. Beside it,
  two variants of the same count: *strict* (merged frames scored too) and *unrecovered*
  (a label still lost at its marker's last visible frame).
* Tables II-IV: prediction error (prior prediction to associated detection, px) of the
  ``slow``, ``rapid`` and ``acceleration`` videos without a loss, pooled: sample count,
  99 % confidence interval of the mean, Shapiro-Wilk test.
* Tables V-VII: per-frame tracking cost for 1..30 markers over 200 frames, percentiles
  (:func:`simbench.benchmarks.trackers.run_tracker_benchmark`, measured in the same run, after
  the videos, in the main process), and the ratio of the median cost at 30 markers to
  that at 1 beside the paper's (:func:`cost_ratios`).
* Findings (:func:`findings`): seed 000's four conclusions, each "reproduced", "not
  reproduced" or "not decidable at this N" at the 1 % level -- losses by the exact
  McNemar test of two trackers on the same videos, with Clopper-Pearson intervals
  (:func:`loss_rate`), prediction errors by Welch's t-test.

Outputs of :func:`write_study`: ``report.md``, ``tables.json``, ``losses.csv``,
``videos/<category>_<k>.json`` and ``.npz`` (per-video logs from which every count can
be re-derived), ``plots/*.png`` and ``frames/*.png`` (a rendered frame per category, raw
and annotated like the paper's Figs. 3-5).

Trackers are taken from the registry (:func:`mocap.trackers.available_trackers`): seed
000's three as OpenMoCap had them (:data:`SEED_TRACKERS`), the bench's variants
(:data:`BENCH_TRACKERS`), then any other registered tracker, which appears in the study
without other changes.
"""

from simbench.studies.trackers.config import (
    BENCH_TRACKERS, CALIBRATED_DIFFICULTY, ERROR_CATEGORIES, IMAGE_H, IMAGE_W, OWN_TRACKER, PAPER_COST, PAPER_ERRORS,
    PAPER_LOSSES, SEED_TRACKERS, AccelerationDifficulty, OcclusionDifficulty, StudyConfig, SwapDifficulty,
    VideoDifficulty, ZigzagDifficulty, study_trackers,
)
from simbench.studies.trackers.findings import (
    NOT_REPRODUCED, REPRODUCED, UNDECIDED, cost_ratios, findings, format_findings, loss_rate, paired_losses,
)
from simbench.studies.trackers.logs import load_video_arrays, tracker_key, write_study
from simbench.studies.trackers.report import format_report, format_tables
from simbench.studies.trackers.study import StudyResult, run_study
from simbench.studies.trackers.tracking import n_labels, score_labels, tracker_rng
from simbench.studies.trackers.videos import plan_video
from mocap.tracker_trials import CATEGORIES

__all__ = [
    "BENCH_TRACKERS", "CALIBRATED_DIFFICULTY", "CATEGORIES", "ERROR_CATEGORIES", "IMAGE_H", "IMAGE_W", "NOT_REPRODUCED",
    "OWN_TRACKER", "PAPER_COST", "PAPER_ERRORS", "PAPER_LOSSES", "REPRODUCED", "SEED_TRACKERS", "UNDECIDED",
    "AccelerationDifficulty", "OcclusionDifficulty", "StudyConfig", "StudyResult", "SwapDifficulty", "VideoDifficulty",
    "ZigzagDifficulty", "cost_ratios", "findings", "format_findings", "format_report", "format_tables",
    "load_video_arrays", "loss_rate", "n_labels", "paired_losses", "plan_video", "run_study", "score_labels",
    "study_trackers", "tracker_key", "tracker_rng", "write_study",
]
