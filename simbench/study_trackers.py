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
errors match its Tables II-IV, :mod:`simbench.study_trackers_fit`):

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

from __future__ import annotations

import concurrent.futures as cf
import csv
import json
import multiprocessing
import re
import time
import zlib
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from eval import tracking_metrics as tm
from simbench.benchmarks.trackers import BenchmarkTable, run_tracker_benchmark
from mocap.detection import DetectionParams, detect_markers
from mocap.tracking import CameraTracks, track_camera
from mocap.trackers import available_trackers, get_tracker

CATEGORIES = ("slow", "rapid", "acceleration", "occlusion", "swap")
#: Categories of seed 000's prediction-error tables (II, III, IV).
ERROR_CATEGORIES = ("slow", "rapid", "acceleration")
#: Seed 000's three trackers as OpenMoCap had them (:mod:`mocap.trackers.openmocap`).
SEED_TRACKERS = ("alpha_beta", "kalman_openmocap", "condensation")
#: The bench's own variants: adaptive search area, tuned Kalman, drifting particles, IMM.
BENCH_TRACKERS = ("alpha_beta_adaptive", "kalman", "condensation_drift", "imm")
OWN_TRACKER = "imm"
COST_MARKER_COUNTS = (1, 5, 10, 15, 20, 25, 30)

# ----------------------------------------------------------------------------------------
# Seed 000's numbers, copied from the paper's text (../shared/seeds/000_*.txt, Section IV).
# Table I, number of losses (of 20 videos per category).
PAPER_VIDEOS_PER_CATEGORY = 20
PAPER_LOSSES: dict[str, dict[str, int]] = {
    "slow": {"alpha_beta": 3, "kalman_openmocap": 0, "condensation": 0},
    "rapid": {"alpha_beta": 9, "kalman_openmocap": 0, "condensation": 4},
    "acceleration": {"alpha_beta": 4, "kalman_openmocap": 1, "condensation": 2},
    "occlusion": {"alpha_beta": 7, "kalman_openmocap": 6, "condensation": 8},
    "swap": {"alpha_beta": 9, "kalman_openmocap": 11, "condensation": 16},
}
# Tables II-IV, prediction error in px: (samples, lower limit, mean, upper limit), 99 % CI.
# Table III's CONDENSATION row is scrambled in the text ("864 ... 38.77 40,02 41.27"); read
# as 864 samples, 38.77 / 40.02 / 41.27 px.
PAPER_ERRORS: dict[str, dict[str, tuple[int, float, float, float]]] = {
    "slow": {"alpha_beta": (1445, 6.67, 7.21, 7.75), "kalman_openmocap": (1700, 9.71, 10.31, 10.91),
             "condensation": (1700, 38.51, 39.18, 39.83)},
    "rapid": {"alpha_beta": (594, 9.77, 10.81, 11.84), "kalman_openmocap": (1080, 14.03, 14.98, 15.93),
              "condensation": (864, 38.77, 40.02, 41.27)},
    "acceleration": {"alpha_beta": (1360, 2.86, 3.17, 3.48), "kalman_openmocap": (1615, 5.50, 5.98, 6.47),
                     "condensation": (1530, 21.82, 22.67, 23.51)},
}
# Tables V-VII, per-frame cost in ms over 200 frames: markers -> (5th pct, median, 95th pct, max).
PAPER_COST: dict[str, dict[int, tuple[float, float, float, float]]] = {
    "alpha_beta": {1: (0.043, 0.046, 0.053, 0.077), 5: (0.064, 0.067, 0.084, 0.104),
                   10: (0.086, 0.091, 0.110, 0.116), 15: (0.109, 0.113, 0.126, 0.218),
                   20: (0.130, 0.140, 0.155, 0.221), 25: (0.136, 0.164, 0.184, 0.211),
                   30: (0.168, 0.194, 0.214, 0.274)},
    "kalman_openmocap": {1: (0.067, 0.077, 0.100, 0.126), 5: (0.120, 0.130, 0.148, 0.174),
               10: (0.172, 0.175, 0.195, 0.268), 15: (0.226, 0.234, 0.256, 0.331),
               20: (0.293, 0.296, 0.314, 0.386), 25: (0.338, 0.356, 0.376, 0.453),
               30: (0.409, 0.418, 0.445, 0.503)},
    "condensation": {1: (0.134, 0.146, 0.162, 0.180), 5: (0.387, 0.499, 0.529, 0.801),
                     10: (0.824, 0.950, 1.017, 1.095), 15: (0.958, 1.384, 1.423, 1.604),
                     20: (1.285, 1.842, 1.920, 2.116), 25: (1.560, 1.934, 2.333, 2.427),
                     30: (1.886, 2.105, 2.791, 2.812)},
}
TABLE_TITLES = {"slow": "Table II: slow movements", "rapid": "Table III: rapid movements",
                "acceleration": "Table IV: acceleration movements"}

_CATEGORY_CODE = {c: k for k, c in enumerate(CATEGORIES)}


Range = tuple[float, float]


def _check_range(owner: str, name: str, r: Range, lo: float = 0.0, hi: float = float("inf")) -> None:
    if len(r) != 2 or not (lo <= r[0] <= r[1] <= hi):
        raise ValueError(f"{owner}.{name} must be a range (low, high) with {lo:g} <= low <= high <= {hi:g}, got {r!r}")


@dataclass(frozen=True)
class ZigzagDifficulty:
    """A zigzag in several directions: straight legs at one drawn speed, turning left or
    right by a drawn angle at each corner (a leg that would leave the image is cut short).

    speed_px_per_frame : (low, high) image speed, px/frame; leg_frames : (low, high)
    frames per leg; turn_deg : (low, high) turn at a corner, deg.
    """

    speed_px_per_frame: Range
    leg_frames: Range
    turn_deg: Range

    def __post_init__(self) -> None:
        _check_range("zigzag", "speed_px_per_frame", self.speed_px_per_frame, 0.1)
        _check_range("zigzag", "leg_frames", self.leg_frames, 1.0)
        _check_range("zigzag", "turn_deg", self.turn_deg, 0.0, 180.0)


@dataclass(frozen=True)
class AccelerationDifficulty:
    """Motions with acceleration, one of three kinds per video: speeding up from
    ``start_speed`` to ``top_speed`` along a gently bent path (``speed ~ start + (top -
    start) (t / T) ** power``), the same braking, or oscillating to and fro (simple
    harmonic motion of peak speed ``top_speed`` and period ``period_s``).

    top_speed_px_per_frame, start_speed_px_per_frame : (low, high) px/frame;
    ramp_power : (low, high); bend_deg : largest bend over a ramp, deg; period_s :
    (low, high) oscillation period, s.
    """

    top_speed_px_per_frame: Range
    period_s: Range
    start_speed_px_per_frame: Range = (0.5, 1.5)
    ramp_power: Range = (1.0, 2.5)
    bend_deg: float = 40.0

    def __post_init__(self) -> None:
        _check_range("acceleration", "top_speed_px_per_frame", self.top_speed_px_per_frame, 0.1)
        _check_range("acceleration", "period_s", self.period_s, 0.1)
        _check_range("acceleration", "start_speed_px_per_frame", self.start_speed_px_per_frame, 0.0)
        _check_range("acceleration", "ramp_power", self.ramp_power, 0.1)


@dataclass(frozen=True)
class OcclusionDifficulty:
    """A marker crossing a barrier on a straight, arc or wavy path.

    speed_px_per_frame : (low, high) px/frame; barrier_width_px, barrier_height_px :
    (low, high) size of the barrier in the image, px (it hides the marker for at least
    one frame).
    """

    speed_px_per_frame: Range
    barrier_width_px: Range = (30.0, 120.0)
    barrier_height_px: Range = (100.0, 220.0)

    def __post_init__(self) -> None:
        _check_range("occlusion", "speed_px_per_frame", self.speed_px_per_frame, 0.1)
        _check_range("occlusion", "barrier_width_px", self.barrier_width_px, 1.0)
        _check_range("occlusion", "barrier_height_px", self.barrier_height_px, 10.0)


@dataclass(frozen=True)
class SwapDifficulty:
    """Two markers whose straight paths cross at a small angle, passing ``miss_px`` apart.

    speed_px_per_frame : (low, high) px/frame, each marker; crossing_angle_deg : (low,
    high); miss_px : (low, high) closest distance of the paths, px; labelled : 1 (seed
    000: a labelled marker and an unlabelled "NULL" one) or 2 (both labelled).
    """

    speed_px_per_frame: Range
    crossing_angle_deg: Range = (8.0, 30.0)
    miss_px: Range = (0.0, 5.0)
    labelled: int = 1

    def __post_init__(self) -> None:
        _check_range("swap", "speed_px_per_frame", self.speed_px_per_frame, 0.1)
        _check_range("swap", "crossing_angle_deg", self.crossing_angle_deg, 0.0, 90.0)
        _check_range("swap", "miss_px", self.miss_px, 0.0)
        if self.labelled not in (1, 2):
            raise ValueError(f"swap.labelled must be 1 (seed 000: one labelled marker and a NULL one) or 2, got {self.labelled!r}")


@dataclass(frozen=True)
class VideoDifficulty:
    """How hard the test videos are: the motion of each category, and Gaussian noise
    added to the detected centroids (px per axis; 0: the rendered detector's own)."""

    slow: ZigzagDifficulty
    rapid: ZigzagDifficulty
    acceleration: AccelerationDifficulty
    occlusion: OcclusionDifficulty
    swap: SwapDifficulty
    detection_noise_px: float = 0.0

    def __post_init__(self) -> None:
        if not self.detection_noise_px >= 0:
            raise ValueError(f"difficulty.detection_noise_px must be >= 0, got {self.detection_noise_px!r}")


#: Seed 000's difficulty, fitted so that its three trackers' mean prediction errors
#: match Tables II-IV: ``simbench study fit-difficulty`` (defaults: 40 synthetic videos
#: per category from seed 1, 0.08 px detection noise; :mod:`simbench.study_trackers_fit`)
#: printed these values. Fitted / paper mean error, alpha-beta, Kalman, CONDENSATION:
#: slow 0.96, 1.02, 1.02; rapid 0.96, 1.06, 1.01; acceleration 1.08, 0.91, 0.99.
CALIBRATED_DIFFICULTY = VideoDifficulty(
    # fitted centres: 22.61 px/frame, 5.98 frames per leg, 89.7 deg turns
    slow=ZigzagDifficulty(speed_px_per_frame=(19.22, 26.0), leg_frames=(4.19, 7.78), turn_deg=(44.7, 134.7)),
    # fitted centres: 24.18 px/frame, 4.27 frames per leg, 96.6 deg turns
    rapid=ZigzagDifficulty(speed_px_per_frame=(20.55, 27.81), leg_frames=(2.99, 5.55), turn_deg=(51.6, 141.6)),
    # fitted centres: top speed 25.46 px/frame, swing period 0.51 s
    acceleration=AccelerationDifficulty(top_speed_px_per_frame=(21.64, 29.28), period_s=(0.35, 0.66)),
    # not fitted (no error table in the paper): the slow speeds
    occlusion=OcclusionDifficulty(speed_px_per_frame=(19.22, 26.0)),
    swap=SwapDifficulty(speed_px_per_frame=(19.22, 26.0)),
)


@dataclass(frozen=True)
class StudyConfig:
    """Everything that determines the study's numbers.

    Attributes
    ----------
    videos_per_category : int
        Seeded videos per category (seed 000: 20).
    n_frames : int
        Frames per video (seed 000: about 80).
    seed : int
        Root seed; each video's generator is ``SeedSequence([seed, category, video])``.
    trackers : tuple of str, optional
        Registry names (or ``"module:Class"``); default every registered tracker.
    categories : tuple of str
        Subset of :data:`CATEGORIES`.
    fps : float
    loss_radius_px : float
        Loss radius of :func:`eval.tracking_metrics.label_losses`, px.
    min_visible_fraction : float
        A marker is visible when this fraction of its expected area shows...
    merge_px : float
        ... and no other marker's centre is closer than this in the image, px.
    confidence : float
        Level of the prediction-error confidence intervals.
    plane_distance_m : float
        Distance of the markers' plane from the camera.
    barrier_distance_m : float
        Distance of the occluding box from the camera.
    hfov_deg : float
        Horizontal field of view of the 640x480 camera.
    marker_radius_m : float
    sensor_mode : {"ir", "visible"}
    exposure_ms : float
    motion_blur : bool
    antialias : int
        Supersampling per axis (1 keeps the study fast).
    cost_marker_counts : tuple of int
        Marker counts of Tables V-VII.
    cost_frames : int
        Frames per cost measurement (seed 000: 200).
    workers : int
        Processes rendering videos (1: in this process).
    difficulty : VideoDifficulty
        The videos' motion and detection noise (default: :data:`CALIBRATED_DIFFICULTY`).
    """

    videos_per_category: int = 20
    n_frames: int = 80
    seed: int = 0
    trackers: tuple[str, ...] | None = None
    categories: tuple[str, ...] = CATEGORIES
    fps: float = 30.0
    loss_radius_px: float = 10.0
    min_visible_fraction: float = 0.5
    merge_px: float = 7.0
    confidence: float = 0.99
    plane_distance_m: float = 2.0
    barrier_distance_m: float = 1.0
    hfov_deg: float = 60.0
    marker_radius_m: float = 0.007
    sensor_mode: str = "ir"
    exposure_ms: float = 8.0
    motion_blur: bool = True
    antialias: int = 1
    cost_marker_counts: tuple[int, ...] = COST_MARKER_COUNTS
    cost_frames: int = 200
    workers: int = 1
    difficulty: VideoDifficulty = CALIBRATED_DIFFICULTY

    def __post_init__(self) -> None:
        def need(ok: bool, what: str) -> None:
            if not ok:
                raise ValueError(f"StudyConfig: {what}")

        need(self.videos_per_category >= 1, f"videos_per_category must be >= 1, got {self.videos_per_category}")
        need(self.n_frames >= 10, f"n_frames must be >= 10, got {self.n_frames}")
        unknown = sorted(set(self.categories) - set(CATEGORIES))
        need(not unknown and len(self.categories) > 0, f"categories must be among {', '.join(CATEGORIES)}, got {self.categories}")
        need(self.loss_radius_px > 0, f"loss_radius_px must be > 0, got {self.loss_radius_px}")
        need(0 < self.min_visible_fraction <= 1, f"min_visible_fraction must be in (0, 1], got {self.min_visible_fraction}")
        need(self.merge_px >= 0, f"merge_px must be >= 0, got {self.merge_px}")
        need(0 < self.confidence < 1, f"confidence must be in (0, 1), got {self.confidence}")
        need(0 < self.barrier_distance_m < self.plane_distance_m, "the barrier must lie between the camera and the plane")
        need(self.sensor_mode in ("ir", "visible"), f"sensor_mode must be 'ir' or 'visible', got {self.sensor_mode!r}")
        need(self.exposure_ms * self.fps <= 1000.0, "exposure_ms must fit in one frame interval")
        need(self.cost_frames >= 2 and len(self.cost_marker_counts) > 0, "need cost_frames >= 2 and some cost_marker_counts")
        need(self.workers >= 1, f"workers must be >= 1, got {self.workers}")
        need(isinstance(self.difficulty, VideoDifficulty), f"difficulty must be a VideoDifficulty, got {type(self.difficulty).__name__}")
        if self.trackers is not None:
            need(len(self.trackers) > 0, "trackers must name at least one tracker (or be None for all)")

    @property
    def dt(self) -> float:
        return 1.0 / self.fps


def study_trackers(config: StudyConfig) -> list[str]:
    """Tracker names of the study: the configured ones, or every registered tracker
    (seed 000's three first, in the paper's order, then the bench's variants, then the
    others alphabetically)."""
    if config.trackers is not None:
        for name in config.trackers:
            get_tracker(name)  # fail early, with the list of known names
        return list(dict.fromkeys(config.trackers))
    names = available_trackers()
    first = [n for n in SEED_TRACKERS + BENCH_TRACKERS if n in names]
    return first + [n for n in names if n not in first]


def _importable_spec(name: str) -> str:
    """``module:Class`` of a tracker, so that worker processes find it without the
    registration having run there (entry-point names pass through)."""
    if ":" in name:
        return name
    cls = get_tracker(name)
    return f"{cls.__module__}:{cls.__qualname__}"


# ======================================================================== video plans
IMAGE_W, IMAGE_H = 640, 480
MARGIN_PX = 25.0


@dataclass(frozen=True)
class Barrier:
    """The occluding box as seen in the image: centre (2,) px, width and height px."""

    centre_px: tuple[float, float]
    width_px: float
    height_px: float

    def hides(self, xy: np.ndarray) -> np.ndarray:
        """(...,) bool: image points ``xy`` (..., 2) px inside the barrier's rectangle."""
        d = np.abs(np.asarray(xy) - np.asarray(self.centre_px))
        return (d[..., 0] < self.width_px / 2) & (d[..., 1] < self.height_px / 2)


@dataclass
class VideoPlan:
    """One test video before rendering: marker paths in pixels, continuous in time.

    Attributes
    ----------
    category : str
    index : int
        Video number within its category.
    knot_t : (K,) float
        Increasing times, s, covering every frame's exposure.
    knot_xy : (K, M, 2) float
        Marker image positions at ``knot_t``, px (piecewise linear in between: exact for
        zigzag legs, densely sampled for smooth paths).
    depth_m : (M,) float
        Distance of each marker's plane from the camera.
    barrier : Barrier or None
    params : dict
        The drawn parameters (speeds, angles, ...), for the logs.
    render_seed : int
        Seed of the sensor noise.
    """

    category: str
    index: int
    knot_t: np.ndarray
    knot_xy: np.ndarray
    depth_m: np.ndarray
    barrier: Barrier | None
    params: dict
    render_seed: int

    @property
    def n_markers(self) -> int:
        return self.knot_xy.shape[1]

    def xy_at(self, times: np.ndarray) -> np.ndarray:
        """(T, M, 2) image positions, px, at ``times`` (T,) s."""
        t = np.asarray(times, dtype=np.float64)
        K, M, _ = self.knot_xy.shape
        flat = self.knot_xy.reshape(K, M * 2)
        out = np.stack([np.interp(t, self.knot_t, flat[:, j]) for j in range(M * 2)], axis=-1)
        return out.reshape(len(t), M, 2)


def video_rng(config: StudyConfig, category: str, index: int) -> np.random.Generator:
    """The generator of one video's drawn parameters (independent of every other video)."""
    return np.random.default_rng(np.random.SeedSequence([config.seed, _CATEGORY_CODE[category], index]))


def _inside(xy: np.ndarray, margin: float = MARGIN_PX) -> bool:
    xy = np.asarray(xy)
    return bool(np.all((xy[..., 0] >= margin) & (xy[..., 0] <= IMAGE_W - 1 - margin)
                       & (xy[..., 1] >= margin) & (xy[..., 1] <= IMAGE_H - 1 - margin)))


def _ray_room(p: np.ndarray, heading: float, margin: float = MARGIN_PX) -> float:
    """Distance, px, from ``p`` along ``heading`` to the image margin."""
    d = np.array([np.cos(heading), np.sin(heading)])
    lo = np.array([margin, margin])
    hi = np.array([IMAGE_W - 1 - margin, IMAGE_H - 1 - margin])
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(d > 1e-12, (hi - p) / d, np.where(d < -1e-12, (lo - p) / d, np.inf))
    return float(max(0.0, t.min()))


def _zigzag(rng: np.random.Generator, duration_s: float, fps: float, d: ZigzagDifficulty) -> tuple[np.ndarray, np.ndarray, dict]:
    """Piecewise-linear zigzag: corner times (K,) s and positions (K, 2) px."""
    v = rng.uniform(*d.speed_px_per_frame) * fps  # px/s
    p = np.array([rng.uniform(200, IMAGE_W - 200), rng.uniform(150, IMAGE_H - 150)])
    heading = rng.uniform(0, 2 * np.pi)
    times, points, turns = [0.0], [p.copy()], []
    t = 0.0
    first = True
    while t < duration_s:
        if not first:
            turn = np.radians(rng.uniform(*d.turn_deg))
            cand = (heading + turn, heading - turn)
            rooms = [_ray_room(p, h) for h in cand]
            k = int(rng.integers(2)) if min(rooms) > 60 else int(np.argmax(rooms))
            heading = cand[k]
            turns.append(float(np.degrees(turn)) * (1 if k == 0 else -1))
            if rooms[k] < 5.0:  # cornered: head for the image centre
                heading = float(np.arctan2(IMAGE_H / 2 - p[1], IMAGE_W / 2 - p[0]))
        first = False
        length = rng.uniform(*d.leg_frames) * v / fps  # px
        length = min(length, _ray_room(p, heading))
        length = max(length, 1.0)
        p = p + length * np.array([np.cos(heading), np.sin(heading)])
        t += length / v
        times.append(t)
        points.append(p.copy())
    params = {"speed_px_per_frame": v / fps, "legs": len(times) - 1,
              "mean_abs_turn_deg": float(np.mean(np.abs(turns))) if turns else 0.0}
    return np.array(times), np.array(points), params


def _integrate_path(t: np.ndarray, speed_px_s: np.ndarray, heading: np.ndarray, start: np.ndarray) -> np.ndarray:
    """(T, 2) positions from speeds (px/s) and headings (rad) on the time grid ``t``."""
    dt = np.diff(t, prepend=t[0])
    step = np.stack([speed_px_s * np.cos(heading), speed_px_s * np.sin(heading)], axis=1) * dt[:, None]
    return start + np.cumsum(step, axis=0)


def _centre_path(xy: np.ndarray, rng: np.random.Generator, jitter_px: float = 40.0) -> np.ndarray | None:
    """Shift a path (T, ..., 2) to the image centre (plus jitter), None if it does not fit."""
    lo, hi = xy.reshape(-1, 2).min(axis=0), xy.reshape(-1, 2).max(axis=0)
    room = np.array([IMAGE_W - 1, IMAGE_H - 1]) - 2 * MARGIN_PX - (hi - lo)
    if np.any(room < 0):
        return None
    shift = np.array([MARGIN_PX, MARGIN_PX]) + room / 2 - lo
    shift += np.clip(rng.uniform(-jitter_px, jitter_px, 2), -room / 2, room / 2)
    return xy + shift


def _fine_grid(duration_s: float, fps: float) -> np.ndarray:
    return np.linspace(0.0, duration_s, int(np.ceil(duration_s * fps * 20)) + 1)


def _plan_acceleration(rng: np.random.Generator, duration_s: float, fps: float,
                       d: AccelerationDifficulty) -> tuple[np.ndarray, np.ndarray, dict]:
    t = _fine_grid(duration_s, fps)
    T = t[-1]
    kind = ["speed_up", "brake", "oscillate"][int(rng.integers(3))]
    for _ in range(200):
        if kind == "oscillate":
            peak = rng.uniform(*d.top_speed_px_per_frame) * fps  # px/s
            period = rng.uniform(*d.period_s)
            amp = peak * period / (2 * np.pi)
            phase = rng.uniform(0, 2 * np.pi)
            ang = rng.uniform(0, np.pi)
            s = amp * np.sin(2 * np.pi * t / period + phase)
            drift = rng.uniform(-1.0, 1.0) * fps  # px/s across the swing
            e = np.array([np.cos(ang), np.sin(ang)])
            n = np.array([-e[1], e[0]])
            xy = s[:, None] * e + (drift * t)[:, None] * n
            params = {"kind": kind, "peak_speed_px_per_frame": peak / fps, "period_s": period, "amplitude_px": amp}
        else:
            s0, s1 = rng.uniform(*d.start_speed_px_per_frame), rng.uniform(*d.top_speed_px_per_frame)
            power = rng.uniform(*d.ramp_power)
            speed = (s0 + (s1 - s0) * (t / T) ** power) * fps
            if kind == "brake":
                speed = speed[::-1]
            curvature = rng.uniform(-1.0, 1.0) * np.radians(d.bend_deg) / (0.5 * (s0 + s1) * fps * T)  # rad/px
            dist = np.concatenate([[0.0], np.cumsum(speed[1:] * np.diff(t))])
            heading = rng.uniform(0, 2 * np.pi) + curvature * dist
            xy = _integrate_path(t, speed, heading, np.zeros(2))
            params = {"kind": kind, "start_speed_px_per_frame": float(speed[0] / fps),
                      "end_speed_px_per_frame": float(speed[-1] / fps), "power": power,
                      "turn_deg": float(np.degrees(curvature * dist[-1]))}
        placed = _centre_path(xy, rng)
        if placed is not None:
            return t, placed, params
    raise RuntimeError("could not fit an acceleration path in the image; lower difficulty.acceleration.top_speed_px_per_frame")


def _plan_occlusion(rng: np.random.Generator, duration_s: float, fps: float,
                    d: OcclusionDifficulty) -> tuple[np.ndarray, np.ndarray, Barrier, dict]:
    """A marker crossing the barrier on a straight, arc or wavy path. It starts inside the
    image, at least 6 frames before the barrier; a fast one may leave the image later
    (it is not scored outside)."""
    t = _fine_grid(duration_s, fps)
    frames = np.arange(int(round(duration_s * fps))) / fps
    for _ in range(1000):
        speed = rng.uniform(*d.speed_px_per_frame) * fps  # px/s
        width = rng.uniform(*d.barrier_width_px)
        hide = width * fps / speed  # frames behind the barrier, roughly
        height = rng.uniform(*d.barrier_height_px)
        centre = np.array([IMAGE_W / 2 + rng.uniform(-60, 60), IMAGE_H / 2 + rng.uniform(-40, 40)])
        barrier = Barrier((float(centre[0]), float(centre[1])), float(width), float(height))
        heading0 = rng.uniform(-np.radians(25), np.radians(25)) + (np.pi if rng.random() < 0.5 else 0.0)
        shape = ["linear", "arc", "wave"][int(rng.integers(3))]
        t_cross = rng.uniform(6.0 + hide / 2, max(6.0 + hide / 2, 0.5 * duration_s * fps + 9.0)) / fps
        u = speed * (t - t_cross)  # arc length from the crossing, px
        e = np.array([np.cos(heading0), np.sin(heading0)])
        n = np.array([-e[1], e[0]])
        if shape == "linear":
            off = np.zeros_like(u)
            extra = {}
        elif shape == "arc":
            bend = rng.uniform(20.0, 60.0) * rng.choice([-1.0, 1.0])  # deg over the video
            kappa = np.radians(bend) / (speed * duration_s)  # 1/px
            off = 0.5 * kappa * u**2  # parabola ~ arc for small angles
            extra = {"bend_deg": float(bend)}
        else:
            amp = rng.uniform(15.0, 40.0)
            period = rng.uniform(0.8, 2.0)
            off = amp * np.sin(2 * np.pi * (t - t_cross) / period + rng.uniform(0, 2 * np.pi))
            extra = {"wave_amplitude_px": float(amp), "wave_period_s": float(period)}
        xy = centre + u[:, None] * e + off[:, None] * n
        xf = np.stack([np.interp(frames, t, xy[:, k]) for k in range(2)], axis=1)
        inside = _inside_mask(xf)
        hidden = barrier.hides(xf) & inside
        seen_after = inside & ~hidden & (frames > t_cross)
        if not inside[:3].all() or hidden[:3].any() or hidden.sum() < 1 or seen_after.sum() < 3:
            continue
        params = {"shape": shape, "speed_px_per_frame": speed / fps, "barrier_width_px": width,
                  "barrier_height_px": height, "hidden_frames": int(hidden.sum()),
                  "frames_in_image": int(inside.sum()), **extra}
        return t, xy, barrier, params
    raise RuntimeError("could not draw an occlusion video; lower difficulty.occlusion.speed_px_per_frame")


def _plan_swap(rng: np.random.Generator, duration_s: float, fps: float, min_apart_px: float,
               d: SwapDifficulty) -> tuple[np.ndarray, np.ndarray, dict]:
    """Two markers on straight paths crossing closely, both inside the image from the
    start until 10 frames after the crossing (fast ones may leave the image later)."""
    t = _fine_grid(duration_s, fps)
    frames = np.arange(int(round(duration_s * fps))) / fps
    for _ in range(1000):
        angle = np.radians(rng.uniform(*d.crossing_angle_deg))
        speeds = rng.uniform(*d.speed_px_per_frame, 2) * fps  # px/s
        base = rng.uniform(0, 2 * np.pi)
        miss = rng.uniform(*d.miss_px)
        t_cross = rng.uniform(10.0, max(10.0, 0.5 * duration_s * fps + 8.0)) / fps
        normal = np.array([-np.sin(base), np.cos(base)])
        centre = np.array([IMAGE_W / 2, IMAGE_H / 2]) + rng.uniform(-60, 60, 2)
        xy = np.empty((len(t), 2, 2))
        for k, h in enumerate((base - angle / 2, base + angle / 2)):
            v = speeds[k] * np.array([np.cos(h), np.sin(h)])
            xy[:, k] = centre + (k - 0.5) * miss * normal + (t - t_cross)[:, None] * v
        xf = np.stack([np.stack([np.interp(frames, t, xy[:, m, k]) for k in range(2)], axis=1) for m in range(2)], axis=1)
        sep = np.linalg.norm(xf[:, 0] - xf[:, 1], axis=1)
        until = frames <= t_cross + 10.0 / fps
        if not (_inside_mask(xf[until, 0]).all() and _inside_mask(xf[until, 1]).all()) or sep[0] < min_apart_px:
            continue
        params = {"crossing_angle_deg": float(np.degrees(angle)), "miss_px": float(miss),
                  "speeds_px_per_frame": [float(s / fps) for s in speeds], "crossing_frame": float(t_cross * fps),
                  "labelled": d.labelled}
        return t, xy, params
    raise RuntimeError("could not draw a swap video; lower difficulty.swap.speed_px_per_frame")


def _inside_mask(xy: np.ndarray, margin: float = MARGIN_PX) -> np.ndarray:
    """(T,) bool: points ``xy`` (T, 2) px inside the image margin."""
    return ((xy[:, 0] >= margin) & (xy[:, 0] <= IMAGE_W - 1 - margin)
            & (xy[:, 1] >= margin) & (xy[:, 1] <= IMAGE_H - 1 - margin))


def plan_video(config: StudyConfig, category: str, index: int) -> VideoPlan:
    """Draw one video of a category (deterministic in ``config.seed``, category, index),
    at ``config.difficulty``."""
    if category not in CATEGORIES:
        raise ValueError(f"unknown category {category!r}; expected one of {', '.join(CATEGORIES)}")
    rng = video_rng(config, category, index)
    fps = config.fps
    d = config.difficulty
    duration = (config.n_frames + 1) / fps  # every frame's exposure is inside
    depth = np.array([config.plane_distance_m])
    barrier = None
    if category in ("slow", "rapid"):
        t, xy, params = _zigzag(rng, duration, fps, getattr(d, category))
    elif category == "acceleration":
        t, xy, params = _plan_acceleration(rng, duration, fps, d.acceleration)
    elif category == "occlusion":
        t, xy, barrier, params = _plan_occlusion(rng, duration, fps, d.occlusion)
    else:
        t, xy, params = _plan_swap(rng, duration, fps, 3.0 * config.loss_radius_px, d.swap)
        depth = np.array([config.plane_distance_m, config.plane_distance_m + 0.03])
    if xy.ndim == 2:
        xy = xy[:, None, :]
    render_seed = int(rng.integers(2**31 - 1))
    return VideoPlan(category, index, np.asarray(t, float), np.asarray(xy, float), depth, barrier, params, render_seed)

# ======================================================================== rendering
@dataclass
class RenderedVideo:
    """A rendered video reduced to what the trackers and the scores need.

    true_xy : (F, M, 2) float, px at mid-exposure; visible_fraction : (F, M) float;
    visible_area : (F, M) bool, enough area shows and in the image; visible : (F, M) bool,
    also not merged with another marker's blob; detections : list of F (n, 2) float px;
    sample_frame : int; sample_image : (H, W, 3) uint8 or None; mean_subframes : float.
    """

    true_xy: np.ndarray
    visible_fraction: np.ndarray
    visible_area: np.ndarray
    visible: np.ndarray
    detections: list[np.ndarray]
    sample_frame: int
    sample_image: np.ndarray | None
    mean_subframes: float


def study_camera(config: StudyConfig):
    """The webcam: 640x480 at the origin's side, looking at the markers' plane along +y."""
    from simbench.render.camera import VirtualCamera
    from simbench.scenario import CameraConfig

    h = 1.2
    return VirtualCamera.from_config(CameraConfig(
        name="webcam", position=(0.0, -config.plane_distance_m, h), look_at=(0.0, 0.0, h),
        width=IMAGE_W, height=IMAGE_H, hfov_deg=config.hfov_deg))


def back_project(camera, xy: np.ndarray, depth_m: np.ndarray) -> np.ndarray:
    """World points (..., 3) m of image points ``xy`` (..., 2) px at camera depths ``depth_m``
    (broadcast against ``xy[..., 0]``); the camera has no distortion."""
    xy = np.asarray(xy, dtype=np.float64)
    rays = np.concatenate([xy, np.ones(xy.shape[:-1] + (1,))], axis=-1) @ np.linalg.inv(camera.K).T
    cam_pts = rays * np.asarray(depth_m)[..., None]
    return (cam_pts - camera.t) @ camera.R  # R^T (p - t) for row vectors


def _barrier_transform(camera, barrier: Barrier, distance_m: float) -> tuple[np.ndarray, tuple[float, float, float]]:
    """Pose (4, 4) and size (x, y, z) m of the box that covers ``barrier`` in the image."""
    f = 0.5 * (camera.K[0, 0] + camera.K[1, 1])
    centre = back_project(camera, np.array(barrier.centre_px), np.array(distance_m))
    T = np.eye(4)
    T[:3, 3] = centre
    # The camera looks along +y with z up: image width is world x, image height world z.
    size = (barrier.width_px * distance_m / f, 0.03, barrier.height_px * distance_m / f)
    return T, size


def render_video(plan: VideoPlan, config: StudyConfig, rasterizer, keep_sample: bool = False) -> RenderedVideo:
    """Render ``plan`` through the bench's camera model and detect the marker blobs."""
    import trimesh

    from simbench.render import ids
    from simbench.render.frames import FrameRenderer, Pose, iterate_frames
    from simbench.render.geometry import moving_geometry, set_geometry
    from simbench.render.lighting import Lighting
    from simbench.scenario import LightingConfig, SensorConfig, SetConfig

    cam = study_camera(config)
    sensor = SensorConfig(mode=config.sensor_mode, exposure_ms=config.exposure_ms, motion_blur=config.motion_blur,
                          antialias=config.antialias, blur_step_px=1.0)
    static = set_geometry(SetConfig(floor=True, walls=True, room_size_m=8.0), np.random.default_rng(0))
    props, prop_T = [], np.zeros((0, 4, 4))
    if plan.barrier is not None:
        T, size = _barrier_transform(cam, plan.barrier, config.barrier_distance_m)
        props = [(trimesh.creation.box(size), np.array([0.04, 0.04, 0.05]), ids.PROP_BASE)]
        prop_T = T[None]
    M = plan.n_markers
    moving = moving_geometry([], {}, n_markers=M, prop_meshes=props, marker_radius=config.marker_radius_m)
    renderer = FrameRenderer([cam], sensor, config.fps, Lighting(LightingConfig()), static, moving, M,
                             config.marker_radius_m, rasterizer=rasterizer)
    no_bodies, no_rots = np.zeros((0, 3)), np.zeros((0, 3, 3))

    def pose_at(times: np.ndarray) -> list[Pose]:
        world = back_project(cam, plan.xy_at(times), plan.depth_m[None, :])  # (T, M, 3)
        return [Pose(no_bodies, no_rots, w, prop_T, w) for w in world]

    times = np.arange(config.n_frames) / config.fps + 0.5 * config.exposure_ms * 1e-3
    params = DetectionParams(mode=config.sensor_mode)
    true_xy = np.empty((config.n_frames, M, 2))
    frac = np.empty((config.n_frames, M))
    dets: list[np.ndarray] = []
    images: list[np.ndarray] = []
    subframes = []
    noise_px = config.difficulty.detection_noise_px
    noise_rng = np.random.default_rng(np.random.SeedSequence([plan.render_seed, 1]))
    for out in iterate_frames(renderer, times, pose_at, seed=plan.render_seed):
        f = out.index
        true_xy[f] = cam.project(back_project(cam, plan.xy_at(times[f:f + 1])[0], plan.depth_m))
        frac[f] = out.marker_visible_fraction[0]
        xy = detect_markers(out.images[0], params).xy
        if noise_px > 0:
            xy = xy + noise_rng.normal(0.0, noise_px, xy.shape)
        dets.append(xy)
        subframes.append(out.n_subframes)
        if keep_sample:
            images.append(out.images[0])
    in_image = ((true_xy[..., 0] >= 0) & (true_xy[..., 0] <= IMAGE_W - 1)
                & (true_xy[..., 1] >= 0) & (true_xy[..., 1] <= IMAGE_H - 1))
    visible_area = (frac >= config.min_visible_fraction) & in_image
    visible = visible_area & ~tm.merged_markers(true_xy, config.merge_px)
    sample = _sample_frame(plan, true_xy, visible)
    return RenderedVideo(true_xy, frac, visible_area, visible, dets, sample, images[sample] if keep_sample else None,
                         float(np.mean(subframes)))


def _sample_frame(plan: VideoPlan, true_xy: np.ndarray, visible: np.ndarray) -> int:
    """The frame shown in the report: the marker behind the barrier (occlusion), the
    closest approach (swap), else the middle."""
    F = len(true_xy)
    if plan.category == "occlusion" and (~visible[:, 0]).any():
        hidden = np.flatnonzero(~visible[:, 0])
        return int(hidden[len(hidden) // 2])
    if plan.category == "swap":
        return int(np.argmin(np.linalg.norm(true_xy[:, 0] - true_xy[:, 1], axis=1)))
    return F // 2


# ======================================================================== tracking
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


def run_video(config: StudyConfig, category: str, index: int, trackers: dict[str, str], rasterizer) -> VideoResult:
    """Plan, render, detect, track and score one video."""
    t0 = time.perf_counter()
    plan = plan_video(config, category, index)
    video = render_video(plan, config, rasterizer, keep_sample=index == 0)
    runs = track_video(video, plan, config, trackers)
    return VideoResult(category, index, plan.params, plan.render_seed, plan.barrier, video, runs,
                       time.perf_counter() - t0)


def _run_chunk(config: StudyConfig, jobs: list[tuple[str, int]], trackers: dict[str, str]) -> list[VideoResult]:
    """Worker: a few videos with one GL context."""
    from simbench.render.rasterizer import Rasterizer

    raster = Rasterizer()
    try:
        return [run_video(config, c, k, trackers, raster) for c, k in jobs]
    finally:
        raster.context.close()


# ======================================================================== the study
@dataclass
class StudyResult:
    """All numbers of one study run.

    losses : category -> tracker -> videos with a loss (Table I)
    losses_strict : the same, merged frames scored too
    losses_unrecovered : videos with a label still lost at its marker's last visible frame
    errors : category -> tracker -> ErrorSummary (Tables II-IV)
    error_samples : category -> tracker -> (n,) px (for the plots)
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
        from simbench.render.rasterizer import Rasterizer

        raster = Rasterizer()
        try:
            for done, (c, k) in enumerate(jobs, 1):
                results.append(run_video(config, c, k, {n: n for n in names}, raster))
                if progress is not None:
                    progress(done, len(jobs))
        finally:
            raster.context.close()
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
    for c in ERROR_CATEGORIES:
        if c not in config.categories:
            continue
        samples[c] = {}
        errors[c] = {}
        for n in names:
            vals = [r.runs[n].errors for r in results if r.category == c and not r.runs[n].lost]
            v = np.concatenate(vals) if vals else np.zeros(0)
            samples[c][n] = v
            errors[c][n] = tm.summarise_errors(v, level=config.confidence)

    t1 = time.perf_counter()
    cost = run_tracker_benchmark(marker_counts=config.cost_marker_counts, n_frames=config.cost_frames,
                                 seed=config.seed, trackers=names, dt=config.dt, include_reference=False)
    seconds = {"videos": t_videos, "cost": time.perf_counter() - t1}
    return StudyResult(config, names, results, losses, strict, unrecovered, errors, samples, cost, seconds)


# ======================================================================== findings
REPRODUCED = "reproduced"
NOT_REPRODUCED = "not reproduced"
UNDECIDED = "not decidable at this N"
#: Significance level of the findings' tests (the paper's 99 % intervals).
ALPHA = 0.01


@dataclass(frozen=True)
class LossRate:
    """Videos with a loss out of ``n`` and the binomial confidence interval of the
    proportion (Clopper-Pearson, ``scipy.stats.binomtest(...).proportion_ci``)."""

    k: int
    n: int
    lower: float
    upper: float
    level: float

    def __str__(self) -> str:
        return f"{self.k}/{self.n} [{self.lower * self.n:.1f}-{self.upper * self.n:.1f}]"


def loss_rate(k: int, n: int, level: float = 0.99) -> LossRate:
    """Binomial ``level`` interval of ``k`` losses in ``n`` videos (exact, Clopper-Pearson)."""
    from scipy.stats import binomtest

    if n <= 0:
        return LossRate(k, n, float("nan"), float("nan"), level)
    ci = binomtest(int(k), int(n)).proportion_ci(confidence_level=level, method="exact")
    return LossRate(int(k), int(n), float(ci.low), float(ci.high), level)


@dataclass(frozen=True)
class PairedLosses:
    """Two trackers on the same videos: losses of each, videos only ``a`` lost and only
    ``b`` lost, and the exact McNemar test (two-sided binomial test of the discordant
    videos, ``scipy.stats.binomtest``): ``direction`` +1 when ``a`` loses significantly
    more than ``b`` at ``alpha``, -1 when significantly fewer, 0 when undecided."""

    a: str
    b: str
    a_lost: LossRate
    b_lost: LossRate
    only_a: int
    only_b: int
    p_value: float
    direction: int

    def __str__(self) -> str:
        return (f"`{self.a}` {self.a_lost} vs `{self.b}` {self.b_lost} (only one lost: {self.only_a} / {self.only_b} "
                f"videos, McNemar p = {self.p_value:.2g})")


def _video_lost(result: StudyResult, name: str, categories: tuple[str, ...] | None = None) -> np.ndarray:
    return np.array([r.runs[name].lost for r in result.videos if categories is None or r.category in categories], dtype=bool)


def paired_losses(result: StudyResult, a: str, b: str, alpha: float = ALPHA,
                  categories: tuple[str, ...] | None = None) -> PairedLosses:
    """Exact McNemar test of trackers ``a`` and ``b`` over the study's videos (of
    ``categories``, default all)."""
    from scipy.stats import binomtest

    la, lb = _video_lost(result, a, categories), _video_lost(result, b, categories)
    n = len(la)
    only_a, only_b = int(np.sum(la & ~lb)), int(np.sum(lb & ~la))
    p = float(binomtest(only_a, only_a + only_b, 0.5).pvalue) if only_a + only_b else 1.0
    direction = 0 if p >= alpha else (1 if only_a > only_b else -1)
    level = result.config.confidence
    return PairedLosses(a, b, loss_rate(int(la.sum()), n, level), loss_rate(int(lb.sum()), n, level),
                        only_a, only_b, p, direction)


def compare_errors(result: StudyResult, category: str, a: str, b: str, alpha: float = ALPHA) -> int | None:
    """+1 when ``a``'s mean prediction error in ``category`` is significantly larger
    than ``b``'s (Welch's t-test, ``alpha``), -1 when significantly smaller, 0 when
    undecided, None without samples (like the paper's t intervals, this treats the
    frames as independent)."""
    from scipy.stats import ttest_ind

    x, y = result.error_samples.get(category, {}).get(a), result.error_samples.get(category, {}).get(b)
    if x is None or y is None or len(x) < 2 or len(y) < 2:
        return None
    p = float(ttest_ind(x, y, equal_var=False).pvalue)
    return 0 if not p < alpha else (1 if x.mean() > y.mean() else -1)


def paper_losses_differ(a: str, b: str, alpha: float = ALPHA) -> tuple[float, int]:
    """Could seed 000's own Table I tell ``a`` from ``b``? Fisher's exact test of their
    total losses (100 videos each; the paper gives no per-video results, so the test
    cannot be paired): (p, +1 / -1 / 0 as in :class:`PairedLosses`)."""
    from scipy.stats import fisher_exact

    ka = sum(PAPER_LOSSES[c][a] for c in PAPER_LOSSES)
    kb = sum(PAPER_LOSSES[c][b] for c in PAPER_LOSSES)
    n = PAPER_VIDEOS_PER_CATEGORY * len(PAPER_LOSSES)
    p = float(fisher_exact([[ka, n - ka], [kb, n - kb]]).pvalue)
    return p, 0 if p >= alpha else (1 if ka > kb else -1)


@dataclass(frozen=True)
class Finding:
    """One of seed 000's findings checked on the bench: the claim, the verdict
    (:data:`REPRODUCED`, :data:`NOT_REPRODUCED`, :data:`UNDECIDED`), the bench's figures
    behind it and what seed 000's own figures can say."""

    claim: str
    verdict: str
    figures: str
    paper: str


def _combine(parts: list[int | None]) -> str:
    """Verdict of a claim made of parts each +1 (holds, significantly), -1 (the opposite
    holds, significantly), 0 (undecided) or None (no data)."""
    if any(p == -1 for p in parts):
        return NOT_REPRODUCED
    if parts and all(p == 1 for p in parts):
        return REPRODUCED
    return UNDECIDED


def _paper_total(name: str) -> str:
    """Seed 000's Table I total of a tracker, 'k/n'."""
    return f"{sum(PAPER_LOSSES[c][name] for c in PAPER_LOSSES)}/{PAPER_VIDEOS_PER_CATEGORY * len(PAPER_LOSSES)}"


def _paper_apart(category: str, low: str, high: str) -> bool:
    """Seed 000's 99 % intervals of ``low`` and ``high`` in ``category`` do not overlap,
    ``low`` below."""
    return PAPER_ERRORS[category][low][3] < PAPER_ERRORS[category][high][1]


def _fitted_only(result: StudyResult, pairs: list[tuple[str, str]], alpha: float) -> str:
    """The same paired loss tests on the fitted categories alone (slow, rapid,
    acceleration): occlusion and swap difficulty is not calibrated."""
    cats = tuple(c for c in ERROR_CATEGORIES if c in result.losses)
    if not cats or len(cats) == len(result.losses):
        return ""
    tests = [paired_losses(result, a, b, alpha, cats) for a, b in pairs]
    return (f" Fitted categories alone ({', '.join(cats)}): "
            + "; ".join(f"`{t.a}` {t.a_lost.k} vs `{t.b}` {t.b_lost.k} of {t.a_lost.n} (p = {t.p_value:.2g})" for t in tests) + ".")


def _err(result: StudyResult, c: str, n: str) -> str:
    s = result.errors.get(c, {}).get(n)
    return "n/a" if s is None or not s.n else f"{s.interval.mean:.1f} [{s.interval.lower:.1f}-{s.interval.upper:.1f}]"


def findings(result: StudyResult, alpha: float = ALPHA) -> list[Finding]:
    """Seed 000's four findings, each checked on the study's videos (module docstring)."""
    ab, km, cd = SEED_TRACKERS
    names = set(result.trackers)
    out: list[Finding] = []
    have = {ab, km, cd} <= names
    cats = [c for c in ERROR_CATEGORIES if c in result.errors]
    if not have:
        miss = ", ".join(f"`{n}`" for n in SEED_TRACKERS if n not in names)
        return [Finding(claim, UNDECIDED, f"{miss} not run", "") for claim in (
            "alpha-beta has the lowest prediction error but the most losses", "Kalman gives the best overall results",
            "CONDENSATION has the highest prediction error", "a search area that grows with uncertainty reduces losses")]
    err_txt = "; ".join(f"{c} {_err(result, c, ab)} / {_err(result, c, km)} / {_err(result, c, cd)} px" for c in cats)
    paper_err = "; ".join(f"{c} " + " / ".join(f"{PAPER_ERRORS[c][n][2]:.1f} [{PAPER_ERRORS[c][n][1]:.1f}-"
                                               f"{PAPER_ERRORS[c][n][3]:.1f}]" for n in SEED_TRACKERS) for c in cats)

    # 1. alpha-beta: lowest error, most losses.
    lowest = [None if d is None else -d for d in (compare_errors(result, c, ab, o, alpha) for c in cats for o in (km, cd))]
    most = [paired_losses(result, ab, o, alpha) for o in (km, cd)]
    pf = [paper_losses_differ(ab, o, alpha) for o in (km, cd)]
    out.append(Finding(
        "alpha-beta has the lowest prediction error but the most losses",
        _combine(lowest + [m.direction for m in most]),
        f"mean error alpha-beta / Kalman / CONDENSATION, px, 99 % t interval: {err_txt}. "
        f"Losses (videos, 99 % binomial interval): " + "; ".join(str(m) for m in most) + "."
        + _fitted_only(result, [(ab, km), (ab, cd)], alpha),
        f"errors {paper_err} ("
        + ("intervals apart: lowest holds" if all(_paper_apart(c, ab, o) for c in cats for o in (km, cd))
           else "intervals overlap somewhere") + f"); losses {_paper_total(ab)} vs Kalman {_paper_total(km)} (Fisher p = {pf[0][0]:.2g}), "
        f"vs CONDENSATION {_paper_total(cd)} (p = {pf[1][0]:.2g}): " + ("decidable" if all(d == 1 for _, d in pf) else
                                                            "the paper's own counts cannot tell 'most' at 1 %") + "."))

    # 2. Kalman: best overall (fewest losses of the three).
    best = [paired_losses(result, km, o, alpha) for o in (ab, cd)]
    pk = [paper_losses_differ(km, o, alpha) for o in (ab, cd)]
    out.append(Finding(
        "Kalman gives the best overall results (fewest losses of the three)",
        _combine([-b.direction for b in best]),
        "; ".join(str(b) for b in best) + "." + _fitted_only(result, [(km, ab), (km, cd)], alpha),
        f"{_paper_total(km)} vs alpha-beta {_paper_total(ab)} (Fisher p = {pk[0][0]:.2g}), vs CONDENSATION "
        f"{_paper_total(cd)} (p = {pk[1][0]:.2g})" + (
            "." if all(d == -1 for _, d in pk) else ": not significant at 1 % on the paper's own counts.")))

    # 3. CONDENSATION: highest prediction error.
    highest = [compare_errors(result, c, cd, o, alpha) for c in cats for o in (ab, km)]
    out.append(Finding(
        "CONDENSATION has the highest prediction error",
        _combine(highest),
        f"mean error alpha-beta / Kalman / CONDENSATION: {err_txt}.",
        f"{paper_err}: " + ("intervals apart, holds in every table." if all(_paper_apart(c, o, cd) for c in cats for o in (ab, km))
                            else "intervals overlap somewhere.")))

    # 4. A search area that grows with uncertainty reduces losses: the same alpha-beta
    # filter with a fixed circle and with one that grows with its residuals and speed.
    adaptive = "alpha_beta_adaptive"
    if adaptive in names:
        pair = paired_losses(result, adaptive, ab, alpha)
        others = [paired_losses(result, o, ab, alpha) for o in (km, cd)]
        out.append(Finding(
            "a search area that grows with uncertainty reduces losses",
            _combine([-pair.direction]),
            f"same alpha-beta filter, growing vs fixed circle: {pair}. Seed 000's own comparison (Kalman, "
            f"CONDENSATION: growing areas, vs alpha-beta: fixed): " + "; ".join(str(o) for o in others) + "."
            + _fitted_only(result, [(adaptive, ab)], alpha),
            f"no controlled comparison (the trackers differ in more than the search area); Kalman {_paper_total(km)} "
            f"and CONDENSATION {_paper_total(cd)} vs alpha-beta {_paper_total(ab)} videos lost."))
    else:
        out.append(Finding("a search area that grows with uncertainty reduces losses", UNDECIDED,
                           f"`{adaptive}` (the controlled comparison) not run", ""))
    return out


def format_findings(result: StudyResult) -> str:
    """The findings table, one line each: claim, verdict, the bench's figures, seed 000's."""
    lines = ["| seed 000's finding | verdict on the bench | bench figures | seed 000's own figures |", "|---|---|---|---|"]
    for f in findings(result):
        lines.append(f"| {f.claim} | **{f.verdict}** | {f.figures} | {f.paper} |")
    return "\n".join(lines)


def cost_ratios(result: StudyResult) -> dict[str, tuple[float, float | None]]:
    """Per tracker: median per-frame cost at the most markers over that at the fewest
    (30 and 1 by default), and the paper's same ratio (None for trackers it lacks)."""
    out = {}
    for n in result.trackers:
        rows = {r.n_markers: r for r in result.cost.rows if r.tracker == n}
        if len(rows) < 2:
            continue
        lo, hi = min(rows), max(rows)
        paper = PAPER_COST.get(n, {})
        out[n] = (rows[hi].median_ms / rows[lo].median_ms,
                  paper[hi][1] / paper[lo][1] if lo in paper and hi in paper else None)
    return out


def format_cost_ratios(result: StudyResult) -> str:
    """Markdown table of :func:`cost_ratios`."""
    counts = sorted({r.n_markers for r in result.cost.rows})
    lo, hi = counts[0], counts[-1]
    lines = [f"| tracker | median cost at {hi} markers / at {lo} (bench) | seed 000 |", "|---|---:|---:|"]
    for n, (ours, paper) in cost_ratios(result).items():
        lines.append(f"| {n} | {ours:.1f} | {'-' if paper is None else f'{paper:.1f}'} |")
    return "\n".join(lines)


# ======================================================================== logs
def _safe(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_]+", "_", name)


def video_stem(category: str, index: int) -> str:
    return f"{category}_{index:02d}"


def _json_default(o):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def _nan_to_none(x: float) -> float | None:
    return None if not np.isfinite(x) else float(x)


def video_log(r: VideoResult, config: StudyConfig) -> dict:
    """The per-video JSON log: drawn parameters and, per tracker, each label's loss."""
    F, M = r.video.visible.shape
    n_lab = next(iter(r.runs.values())).tracks.xy.shape[1] if r.runs else M
    out = {
        "category": r.category, "index": r.index, "seed": config.seed, "render_seed": r.render_seed,
        "n_frames": F, "n_markers": M, "n_labels": n_lab, "params": r.params,
        "barrier": None if r.barrier is None else asdict(r.barrier),
        "visible_frames": r.video.visible.sum(axis=0).tolist(),
        "mean_detections_per_frame": float(np.mean([len(d) for d in r.video.detections])),
        "mean_subframes": r.video.mean_subframes, "seconds": r.seconds,
        "loss_radius_px": config.loss_radius_px, "trackers": {},
    }
    for name, run in r.runs.items():
        out["trackers"][name] = {
            "video_lost": run.lost,
            "label_lost": run.losses.lost.tolist(),
            "first_loss_frame": run.losses.first_frame.tolist(),
            "loss_reason": run.losses.reason_names(),
            "loss_frames": run.losses.bad_frames.tolist(),
            "lost_at_end": run.losses.at_end.tolist(),
            "video_lost_strict": tm.video_lost(run.losses_strict),
            "label_lost_strict": run.losses_strict.lost.tolist(),
            "n_prediction_errors": int(len(run.errors)),
            "mean_prediction_error_px": _nan_to_none(float(np.mean(run.errors))) if len(run.errors) else None,
            "in_error_table": (r.category in ERROR_CATEGORIES) and not run.lost,
        }
    return out


def save_video_arrays(r: VideoResult, path: Path) -> None:
    """Per-video arrays (``.npz``) from which the losses and errors can be recomputed."""
    dets = r.video.detections
    n = max((len(d) for d in dets), default=0)
    padded = np.full((len(dets), n, 2), np.nan)
    for f, d in enumerate(dets):
        padded[f, :len(d)] = d
    arrays = {"true_xy": r.video.true_xy, "visible": r.video.visible, "visible_area": r.video.visible_area,
              "visible_fraction": r.video.visible_fraction,
              "detections": padded, "trackers": np.array(list(r.runs))}
    for name, run in r.runs.items():
        k = _safe(name)
        t = run.tracks
        arrays.update({f"{k}__predicted": t.predicted, f"{k}__measured": t.xy, f"{k}__estimate": t.estimate,
                       f"{k}__status": t.status, f"{k}__search_radius": t.search_radius,
                       f"{k}__loss_flags": run.losses.flags, f"{k}__loss_flags_strict": run.losses_strict.flags})
    np.savez_compressed(path, **arrays)


def load_video_arrays(path: Path) -> dict[str, np.ndarray]:
    """Read a per-video ``.npz`` back (keys as written by :func:`save_video_arrays`)."""
    with np.load(path) as z:
        return {k: z[k] for k in z.files}


def tracker_key(name: str) -> str:
    """Prefix of a tracker's arrays in the per-video ``.npz``."""
    return _safe(name)


def tables_dict(result: StudyResult) -> dict:
    """All seven tables (ours and the paper's) as plain data (``tables.json``)."""
    cfg = result.config
    errs = {}
    for c, row in result.errors.items():
        errs[c] = {}
        for n, s in row.items():
            errs[c][n] = {"samples": s.n, "lower": _nan_to_none(s.interval.lower), "mean": _nan_to_none(s.interval.mean),
                          "upper": _nan_to_none(s.interval.upper),
                          "shapiro_w": _nan_to_none(s.normality.statistic), "shapiro_p": _nan_to_none(s.normality.p_value),
                          "normal": s.normality.normal}
    cost = {n: {str(r.n_markers): {"p5_ms": r.p5_ms, "median_ms": r.median_ms, "p95_ms": r.p95_ms, "max_ms": r.max_ms}
                for r in result.cost.rows if r.tracker == n} for n in result.trackers}
    return {
        "config": {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(cfg).items()},
        "trackers": result.trackers,
        "table_I_losses": result.losses,
        "table_I_losses_strict": result.losses_strict,
        "table_I_losses_unrecovered": result.losses_unrecovered,
        "total_losses": result.total_losses(),
        "tables_II_IV_prediction_error_px": errs,
        "tables_V_VII_cost_ms": cost,
        "paper": {"table_I_losses": PAPER_LOSSES, "tables_II_IV": PAPER_ERRORS,
                  "tables_V_VII": {n: {str(m): v for m, v in d.items()} for n, d in PAPER_COST.items()}},
        "seconds": result.seconds,
    }


def write_study(result: StudyResult, out_dir: str | Path) -> Path:
    """Write logs, tables, plots, sample frames and ``report.md`` into ``out_dir``; return the report path."""
    out = Path(out_dir)
    (out / "videos").mkdir(parents=True, exist_ok=True)
    (out / "plots").mkdir(exist_ok=True)
    (out / "frames").mkdir(exist_ok=True)
    cfg = result.config
    rows = []
    for r in result.videos:
        stem = video_stem(r.category, r.index)
        (out / "videos" / f"{stem}.json").write_text(json.dumps(video_log(r, cfg), indent=1, default=_json_default))
        save_video_arrays(r, out / "videos" / f"{stem}.npz")
        for name, run in r.runs.items():
            for m in range(len(run.losses.lost)):
                rows.append([r.category, r.index, name, m, int(run.losses.lost[m]), int(run.losses.first_frame[m]),
                             run.losses.reason_names()[m], int(run.losses.bad_frames[m]), int(run.losses.at_end[m]),
                             int(run.losses_strict.lost[m])])
    with open(out / "losses.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["category", "video", "tracker", "label", "lost", "first_loss_frame", "reason", "loss_frames",
                    "lost_at_end", "lost_strict"])
        w.writerows(rows)
    (out / "tables.json").write_text(json.dumps(tables_dict(result), indent=1, default=_json_default))
    plot_losses(result, out / "plots" / "losses.png")
    plot_errors(result, out / "plots" / "prediction_errors.png")
    plot_cost(result, out / "plots" / "cost.png")
    frames = write_sample_frames(result, out / "frames")
    report = out / "report.md"
    report.write_text(format_report(result, frames))
    return report


# ======================================================================== plots
_COLOURS = ["#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f"]


def _figure(w: float, h: float):
    from matplotlib.figure import Figure

    return Figure(figsize=(w, h), dpi=110, layout="constrained")


def plot_losses(result: StudyResult, path: Path) -> None:
    """Grouped bars: videos with a loss per category and tracker; the paper's as diamonds."""
    fig = _figure(8, 4)
    ax = fig.add_subplot()
    cats = [c for c in CATEGORIES if c in result.losses]
    names = result.trackers
    width = 0.8 / len(names)
    x = np.arange(len(cats))
    for k, n in enumerate(names):
        xs = x - 0.4 + width * (k + 0.5)
        ax.bar(xs, [result.losses[c][n] for c in cats], width, label=n, color=_COLOURS[k % len(_COLOURS)])
        paper = [PAPER_LOSSES.get(c, {}).get(n, np.nan) for c in cats]
        if np.isfinite(paper).any():
            ax.plot(xs, paper, "D", mfc="none", mec="k", ms=6, label="paper" if k == 0 else None)
    ax.set_xticks(x, cats)
    ax.set_ylabel(f"videos with a loss (of {result.config.videos_per_category})")
    ax.set_title("Table I: losses per category (bars: bench, diamonds: seed 000)")
    ax.legend(fontsize=8, ncols=2)
    fig.savefig(path)


def plot_errors(result: StudyResult, path: Path) -> None:
    """Box plots of the prediction errors per tracker, one panel per category."""
    cats = list(result.error_samples)
    if not cats:
        return
    fig = _figure(4 * len(cats), 4)
    axes = fig.subplots(1, len(cats), squeeze=False)[0]
    for ax, c in zip(axes, cats):
        names = result.trackers
        data = [result.error_samples[c][n] for n in names]
        pos = [i for i, d in enumerate(data) if len(d)]
        if pos:
            ax.violinplot([data[i] for i in pos], positions=pos, showmedians=True, showextrema=False)
        ax.plot(range(len(names)), [result.errors[c][n].interval.mean for n in names], "o", color="k", label="mean (bench)")
        paper = [PAPER_ERRORS[c].get(n, (0, np.nan, np.nan, np.nan))[2] for n in names]
        ax.plot(range(len(names)), paper, "D", mfc="none", mec="r", label="mean (seed 000)")
        ax.set_xticks(range(len(names)), names, rotation=20, fontsize=8)
        ax.set_yscale("symlog", linthresh=1.0)
        ax.set_ylim(bottom=0.0)
        ax.set_title(TABLE_TITLES[c], fontsize=9)
        ax.set_ylabel("prediction error, px")
    axes[0].legend(fontsize=7)
    fig.savefig(path)


def plot_cost(result: StudyResult, path: Path) -> None:
    """Median per-frame cost against marker count (5-95 % band); the paper's medians dashed."""
    fig = _figure(7, 4)
    ax = fig.add_subplot()
    for k, n in enumerate(result.trackers):
        rows = sorted((r for r in result.cost.rows if r.tracker == n), key=lambda r: r.n_markers)
        m = [r.n_markers for r in rows]
        col = _COLOURS[k % len(_COLOURS)]
        ax.plot(m, [r.median_ms for r in rows], "o-", color=col, label=f"{n} (bench)")
        ax.fill_between(m, [r.p5_ms for r in rows], [r.p95_ms for r in rows], color=col, alpha=0.12)
        if n in PAPER_COST:
            pm = sorted(PAPER_COST[n])
            ax.plot(pm, [PAPER_COST[n][q][1] for q in pm], "--", color=col, label=f"{n} (seed 000)")
    ax.set_yscale("log")
    ax.set_xlabel("markers")
    ax.set_ylabel("per-frame tracking cost, ms")
    ax.set_title(f"Tables V-VII: median and 5-95 % over {result.cost.n_frames} frames")
    ax.legend(fontsize=7, ncols=2)
    fig.savefig(path)


def write_sample_frames(result: StudyResult, folder: Path) -> dict[str, tuple[str, str]]:
    """Per category, the first video's sample frame raw and annotated (true path dashed,
    each tracker's estimate and search circle); returns category -> (raw, annotated) names."""
    import cv2

    out = {}
    for r in result.videos:
        v = r.video
        if v.sample_image is None:
            continue
        f = v.sample_frame
        raw = f"{r.category}.png"
        cv2.imwrite(str(folder / raw), cv2.cvtColor(v.sample_image, cv2.COLOR_RGB2BGR))
        fig = _figure(6.4, 4.8)
        ax = fig.add_subplot()
        ax.imshow(np.clip(v.sample_image.astype(np.float32) * 3.0, 0, 255).astype(np.uint8))
        n_lab = next(iter(r.runs.values())).tracks.predicted.shape[1] if r.runs else v.true_xy.shape[1]
        for m in range(v.true_xy.shape[1]):
            ax.plot(v.true_xy[:, m, 0], v.true_xy[:, m, 1], "--", color="w", lw=0.6, alpha=0.7)
            if m >= n_lab:  # an unlabelled marker, as seed 000's Fig. 5
                ax.annotate("NULL", v.true_xy[f, m], xytext=(6, -6), textcoords="offset points", color="y", fontsize=7)
        for k, (name, run) in enumerate(r.runs.items()):
            col = _COLOURS[k % len(_COLOURS)]
            for m in range(n_lab):
                p = run.tracks.predicted[f, m]
                e = run.tracks.estimate[f, m]
                rad = run.tracks.search_radius[f, m]
                if np.isfinite(p).all() and np.isfinite(rad):
                    ax.add_patch(_circle(p, rad, col))
                if np.isfinite(e).all():
                    ax.plot(*e, "o", color=col, ms=4, label=name if m == 0 else None)
        if r.barrier is not None:
            b = r.barrier
            ax.add_patch(_rect(b))
        ax.set_xlim(0, IMAGE_W)
        ax.set_ylim(IMAGE_H, 0)
        ax.set_title(f"{r.category} video {r.index}, frame {f} (x3 brightness)", fontsize=9)
        ax.legend(fontsize=7, loc="best")
        ax.set_axis_off()
        ann = f"{r.category}_annotated.png"
        fig.savefig(folder / ann)
        out[r.category] = (raw, ann)
    return out


def _circle(centre: np.ndarray, radius: float, colour: str):
    from matplotlib.patches import Circle

    return Circle((float(centre[0]), float(centre[1])), float(radius), fill=False, ec=colour, lw=0.8)


def _rect(b: Barrier):
    from matplotlib.patches import Rectangle

    return Rectangle((b.centre_px[0] - b.width_px / 2, b.centre_px[1] - b.height_px / 2), b.width_px, b.height_px,
                     fill=False, ec="y", lw=0.6, ls=":")


# ======================================================================== report
def _f(x: float, digits: int = 2) -> str:
    return "n/a" if x is None or not np.isfinite(x) else f"{x:.{digits}f}"


def format_loss_table(result: StudyResult) -> str:
    """Table I in Markdown: per category and tracker the videos with a loss and the 99 %
    binomial interval in videos (Clopper-Pearson), seed 000's count in brackets; totals."""
    names = result.trackers
    level = result.config.confidence
    nv = result.config.videos_per_category
    lines = ["| category | " + " | ".join(names) + " |", "|---|" + "---:|" * len(names)]

    def cell(k: int, n: int, p: int | None, bold: bool = False) -> str:
        r = loss_rate(k, n, level)
        txt = f"**{k}**" if bold else f"{k}"
        return f"{txt} [{r.lower * n:.1f}-{r.upper * n:.1f}]" + (f" ({p})" if p is not None else "")

    for c, row in result.losses.items():
        lines.append(f"| {c} | " + " | ".join(cell(row[n], nv, PAPER_LOSSES.get(c, {}).get(n)) for n in names) + " |")
    tot = result.total_losses()
    n_all = nv * len(result.losses)
    cells = []
    for n in names:
        p = sum(PAPER_LOSSES[c][n] for c in result.losses if n in PAPER_LOSSES.get(c, {})) if n in SEED_TRACKERS else None
        cells.append(cell(tot[n], n_all, p, bold=True))
    lines.append("| **total** | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def format_loss_variants(result: StudyResult) -> str:
    """Table I's count under the two variant definitions: strict / unrecovered."""
    names = result.trackers
    lines = ["| category | " + " | ".join(names) + " |", "|---|" + "---:|" * len(names)]
    for c in result.losses:
        lines.append(f"| {c} | " + " | ".join(f"{result.losses_strict[c][n]} / {result.losses_unrecovered[c][n]}"
                                              for n in names) + " |")
    ts, tu = tm.total_losses(result.losses_strict), tm.total_losses(result.losses_unrecovered)
    lines.append("| **total** | " + " | ".join(f"**{ts[n]} / {tu[n]}**" for n in names) + " |")
    return "\n".join(lines)


def format_error_table(result: StudyResult, category: str) -> str:
    """One of Tables II-IV in Markdown, the paper's row beside ours."""
    lines = ["| tracker | samples | lower | mean | upper | Shapiro-Wilk W (p) | normal? | seed 000: samples, lower, mean, upper |",
             "|---|---:|---:|---:|---:|---:|---|---|"]
    for n in result.trackers:
        s = result.errors[category][n]
        iv, nt = s.interval, s.normality
        p = PAPER_ERRORS[category].get(n)
        paper = f"{p[0]}, {p[1]:.2f}, {p[2]:.2f}, {p[3]:.2f}" if p else "-"
        sw = f"{_f(nt.statistic, 3)} ({nt.p_value:.1e})" if np.isfinite(nt.p_value) else "n/a"
        normal = "n/a" if not np.isfinite(nt.p_value) else ("yes" if nt.normal else "no")
        lines.append(f"| {n} | {iv.n} | {_f(iv.lower)} | {_f(iv.mean)} | {_f(iv.upper)} | {sw} | {normal} | {paper} |")
    return "\n".join(lines)


def format_cost_table(result: StudyResult, tracker: str) -> str:
    """One of Tables V-VII (or the same for another tracker) in Markdown, ms."""
    lines = ["| markers | 5th pct | median | 95th pct | maximum | seed 000: 5th, median, 95th, max |",
             "|---:|---:|---:|---:|---:|---|"]
    for r in sorted((r for r in result.cost.rows if r.tracker == tracker), key=lambda r: r.n_markers):
        p = PAPER_COST.get(tracker, {}).get(r.n_markers)
        paper = ", ".join(f"{v:.3f}" for v in p) if p else "-"
        lines.append(f"| {r.n_markers} | {r.p5_ms:.4f} | {r.median_ms:.4f} | {r.p95_ms:.4f} | {r.max_ms:.4f} | {paper} |")
    return "\n".join(lines)


def format_tables(result: StudyResult) -> str:
    """All seven tables in Markdown (what the CLI prints), then the cost ratios."""
    cfg = result.config
    parts = [f"### Table I: videos with a loss, of {cfg.videos_per_category} per category -- bench [{cfg.confidence:.0%} "
             "binomial interval, videos] (seed 000)",
             "", format_loss_table(result), "",
             "Same count, strict (frames where the markers' blobs merge scored too) / unrecovered (a label still "
             "lost at its marker's last visible frame):", "", format_loss_variants(result), ""]
    for c in result.errors:
        parts += [f"### {TABLE_TITLES[c]}: prediction error, px, {cfg.confidence:.0%} CI of the mean", "",
                  format_error_table(result, c), ""]
    roman = {"alpha_beta": "Table V", "kalman_openmocap": "Table VI", "condensation": "Table VII"}
    for n in result.trackers:
        title = roman.get(n, "Table V-VII layout")
        parts += [f"### {title}: {n}, per-frame tracking cost over {result.cost.n_frames} frames, ms", "",
                  format_cost_table(result, n), ""]
    if cost_ratios(result):
        parts += ["### Cost growth: median cost at the most markers over the median at the fewest", "",
                  format_cost_ratios(result), ""]
    return "\n".join(parts)


def _discussion(result: StudyResult) -> list[str]:
    """Data-driven remarks on where the bench agrees with seed 000 and where not."""
    tot = result.total_losses()
    names = result.trackers
    lines = []
    seeds = [n for n in SEED_TRACKERS if n in names]
    calib = [(c, n, result.errors[c][n].interval.mean / PAPER_ERRORS[c][n][2])
             for c in ERROR_CATEGORIES if c in result.errors for n in seeds if result.errors[c][n].n]
    if calib:
        lines.append("* **Difficulty.** The videos' motion was fitted to seed 000's Tables II-IV "
                     "(`simbench study fit-difficulty`, see the setup); our mean prediction error over the paper's: "
                     + "; ".join(f"{c} " + ", ".join(f"`{n}` {r:.2f}" for cc, n, r in calib if cc == c)
                                 for c in ERROR_CATEGORIES if any(cc == c for cc, _, _ in calib)) + ".")
    if OWN_TRACKER in names and seeds:
        beaten = [n for n in seeds if tot[OWN_TRACKER] < tot[n]]
        lines.append(f"* **Own tracker.** `{OWN_TRACKER}` lost {tot[OWN_TRACKER]} videos in total against "
                     + ", ".join(f"`{n}` {tot[n]}" for n in seeds) + ": "
                     + ("fewer than each of seed 000's trackers." if len(beaten) == len(seeds)
                        else "NOT fewer than " + ", ".join(f"`{n}`" for n in seeds if n not in beaten) + "."))
        worse = [(c, n) for c in result.losses for n in seeds if result.losses[c][OWN_TRACKER] > result.losses[c][n]]
        if worse:
            lines.append("  Categories where it loses more videos than a seed tracker: "
                         + ", ".join(f"{c} (vs `{n}`: {result.losses[c][OWN_TRACKER]} > {result.losses[c][n]})"
                                     for c, n in worse) + ".")
        own_lost = [r for r in result.videos if r.runs[OWN_TRACKER].lost]
        if own_lost:
            lines.append(f"  Its lost videos (label: first frame, reason; which seed trackers lost the same video): "
                         + "; ".join(f"{r.category} {r.index} ("
                                     + ", ".join(f"{m}: {r.runs[OWN_TRACKER].losses.first_frame[m]} "
                                                 f"{r.runs[OWN_TRACKER].losses.reason_names()[m]}"
                                                 for m in np.flatnonzero(r.runs[OWN_TRACKER].losses.lost))
                                     + "; " + (", ".join(f"`{n}`" for n in seeds if r.runs[n].lost) or "none") + ")"
                                     for r in own_lost) + ".")
    if seeds:
        rank_bench = sorted(seeds, key=lambda n: tot[n])
        paper_tot = {n: sum(PAPER_LOSSES[c][n] for c in PAPER_LOSSES if c in result.losses) for n in seeds}
        rank_paper = sorted(seeds, key=lambda n: paper_tot[n])
        lines.append("* **Ranking by losses** (same categories). Seed 000: "
                     + " < ".join(f"`{n}` {paper_tot[n]}" for n in rank_paper)
                     + "; bench: " + " < ".join(f"`{n}` {tot[n]}" for n in rank_bench)
                     + (" -- the same order." if rank_bench == rank_paper else " -- a different order."))
        per_cat = {c: sum(result.losses[c][n] for n in seeds) for c in result.losses}
        hard = max(per_cat, key=per_cat.get)
        easy = [c for c, v in per_cat.items() if v == 0]
        text = (f"hardest for seed 000's trackers on the bench: `{hard}` ({per_cat[hard]} losses over the three; "
                "the paper's hardest: marker swapping, 36)") if per_cat[hard] > 0 else ""
        if easy:
            text += ("; " if text else "") + (f"none of them lost a marker in {', '.join(f'`{c}`' for c in easy)}, where "
                                              "the paper counts " + ", ".join(f"{sum(PAPER_LOSSES[c].values())}" for c in easy)
                                              + " losses")
        lines.append(f"* **Categories.** {text[0].upper() + text[1:]}.")
        strict, unrec = tm.total_losses(result.losses_strict), tm.total_losses(result.losses_unrecovered)
        lines.append("* **Definition matters.** Scoring the frames where the two swap markers' blobs merge as well "
                     "(strict) gives " + ", ".join(f"`{n}` {strict[n]}" for n in names)
                     + "; counting only losses a label never recovered from gives "
                     + ", ".join(f"`{n}` {unrec[n]}" for n in names) + ".")
    if result.errors:
        agree = []
        for c, row in result.errors.items():
            m = {n: row[n].interval.mean for n in seeds if row[n].n}
            if len(m) >= 2:
                agree.append((c, min(m, key=m.get), max(m, key=m.get)))
        if agree:
            lines.append("* **Prediction errors.** Smallest / largest mean among seed 000's trackers: "
                         + "; ".join(f"{c}: `{lo}` / `{hi}`" for c, lo, hi in agree)
                         + " (paper: `alpha_beta` / `condensation` in every category). Our means are "
                         + ", ".join(f"{c} {min(row[n].interval.mean for n in seeds if row[n].n):.1f}-"
                                     f"{max(row[n].interval.mean for n in seeds if row[n].n):.1f} px"
                                     for c, row in result.errors.items() if any(row[n].n for n in seeds))
                         + " against the paper's 7-39, 11-40 and 3-23 px.")
        nonnormal = sum(1 for row in result.errors.values() for s in row.values() if s.n >= 3 and not s.normality.normal)
        total = sum(1 for row in result.errors.values() for s in row.values() if s.n >= 3)
        lines.append(f"* **Normality.** Shapiro-Wilk rejects normality (p < 0.01) for {nonnormal} of {total} error "
                     "samples, as the paper found; the t intervals lean on the central limit theorem as the paper's do.")
    ratios = cost_ratios(result)
    if ratios:
        lines.append("* **Cost.** Median cost at the most markers over that at the fewest: "
                     + ", ".join(f"`{n}` x{o:.1f}" + (f" (paper x{p:.1f})" if p else "") for n, (o, p) in ratios.items())
                     + ". The bench's trackers are vectorised over markers, so a fixed per-frame overhead weighs more "
                     "than the per-marker work and the cost grows far less than OpenMoCap's per-marker loops. Maxima "
                     "are single frames disturbed by the (shared) machine.")
    return lines


_STATIC_DISCUSSION = """\
Why the numbers may differ from the paper's, beyond the videos being different draws:

* **Trackers.** Seed 000's three trackers (`alpha_beta`, `kalman_openmocap`,
  `condensation`) are re-implementations of OpenMoCap's own (the software the paper
  evaluates; its source gives what the paper leaves out: alpha-beta's fixed search
  circle of 5 % of the image diagonal, the Kalman filter's Q, R and search radius, the
  CONDENSATION diffusion), in `mocap/trackers/openmocap.py`. They share the bench's
  gated assignment, which for one labelled marker is OpenMoCap's nearest detection in
  the search circle. The bench's own variants are separate rows: `alpha_beta_adaptive`
  (a search area that grows with the residuals and the speed, starting at the same
  40 px circle), `kalman` (the bench's tuned Kalman filter), `condensation_drift`
  (particles with a drift velocity) and `imm`.
* **Difficulty.** Seed 000 gives no marker speeds. The zigzag and acceleration motions
  were fitted so that its three trackers' mean prediction errors match Tables II-IV
  (`simbench/study_trackers_fit.py`): the markers move about 20-28 px per frame. The
  occlusion and swap videos have no error table to fit: their markers move at the
  fitted slow speeds, the barrier is 30-120 px wide, and their loss counts are not
  calibrated to anything.
* **Detections.** The blobs are rendered through the camera model and found by the
  pipeline's detector, within about 0.1 px of the truth; the errors are those of the
  motion models.
* **Loss definition.** The paper does not define a loss; ours is strict (one frame with
  the estimate more than the loss radius from a visible marker counts, even if the
  label picks its marker up again the next frame), hence the two variants above.
* **Swapping.** As in the paper's Fig. 5, one marker is labelled and the other is not
  ("NULL"); a label that takes the NULL marker's blob is a loss.
* **Cost.** Absolute times are not comparable (numpy on a shared 2-core machine here,
  OpenMoCap on 2010 hardware there); how the cost grows with the marker count is.
"""


def describe_difficulty(d: VideoDifficulty) -> list[str]:
    """Markdown bullets of the videos' motion (``config.difficulty``)."""
    def r(x: Range, unit: str = "") -> str:
        return f"{x[0]:g}-{x[1]:g}{unit}"

    out = [f"* **{c}**: zigzag at {r(z.speed_px_per_frame, ' px/frame')}, legs of {r(z.leg_frames)} frames, turns of "
           f"{r(z.turn_deg, ' deg')}" for c, z in (("slow", d.slow), ("rapid", d.rapid))]
    a = d.acceleration
    out.append(f"* **acceleration**: speeding up from {r(a.start_speed_px_per_frame)} to {r(a.top_speed_px_per_frame, ' px/frame')} "
               f"(ramp power {r(a.ramp_power)}, bent up to {a.bend_deg:g} deg), the same braking, or oscillating at up to "
               f"{r(a.top_speed_px_per_frame, ' px/frame')} with a period of {r(a.period_s, ' s')}")
    o = d.occlusion
    out.append(f"* **occlusion**: {r(o.speed_px_per_frame, ' px/frame')} on a straight, arc or wavy path behind a barrier "
               f"{r(o.barrier_width_px)} px wide and {r(o.barrier_height_px)} px tall")
    w = d.swap
    out.append(f"* **swap**: {'a labelled and an unlabelled (NULL) marker' if w.labelled == 1 else 'two labelled markers'} at "
               f"{r(w.speed_px_per_frame, ' px/frame')}, paths crossing at {r(w.crossing_angle_deg, ' deg')}, "
               f"{r(w.miss_px, ' px')} apart")
    if d.detection_noise_px > 0:
        out.append(f"* detection noise added: {d.detection_noise_px:g} px per axis")
    return out


def format_report(result: StudyResult, frames: dict[str, tuple[str, str]] | None = None) -> str:
    """The Markdown report: setup, the seven tables beside the paper's, plots, discussion."""
    cfg = result.config
    n_videos = len(result.videos)
    parts = [
        "# Tracker study: seed 000's experiments on the bench", "",
        f"{n_videos} rendered videos ({cfg.videos_per_category} per category: {', '.join(cfg.categories)}), "
        f"{cfg.n_frames} frames each at {cfg.fps:g} fps, 640x480, one webcam {cfg.plane_distance_m:g} m from the "
        f"markers' plane, sensor mode `{cfg.sensor_mode}`, exposure {cfg.exposure_ms:g} ms, motion blur "
        f"{'on' if cfg.motion_blur else 'off'}; seed {cfg.seed}; trackers: {', '.join(f'`{n}`' for n in result.trackers)}.",
        f"Videos took {result.seconds.get('videos', 0):.0f} s ({cfg.workers} worker(s)), the cost tables "
        f"{result.seconds.get('cost', 0):.0f} s. Regenerate with "
        f"`simbench study trackers --out DIR --videos {cfg.videos_per_category} --seed {cfg.seed}`.", "",
        "Motion (image speeds; zigzag and acceleration fitted to seed 000's Tables II-IV by "
        "`simbench study fit-difficulty`, occlusion and swap at the fitted slow speeds):", "",
        *describe_difficulty(cfg.difficulty), "",
        "## Definitions", "",
        f"* **Loss** (Table I): a video counts one loss for a tracker when, at some frame after the first "
        f"(the labels start at the true positions, as seed 000's manual initialisation), a label whose marker is "
        f"visible (at least {cfg.min_visible_fraction:.0%} of its area shows, and no other marker within "
        f"{cfg.merge_px:g} px, where the two blobs merge into one) is declared lost, or its estimate is "
        f"more than **{cfg.loss_radius_px:g} px** (about 1.7 blob diameters) from the marker, or it took a blob "
        f"nearer to the other marker while the two markers were more than {cfg.loss_radius_px:g} px apart. "
        "Per label and video: `losses.csv` and `videos/*.json`; per frame: `videos/*.npz`.",
        "* **Prediction error** (Tables II-IV): distance, px, between a label's prediction (before the frame's "
        "update) and the detection associated with it, over every frame after the first where it had one, pooled "
        "over the videos of the category in which that tracker lost nothing. Interval: Student's t, "
        f"{cfg.confidence:.0%}, of the mean; Shapiro-Wilk on the same sample (scipy).",
        f"* **Cost** (Tables V-VII): wall time of one predict-associate-update step of all markers, over "
        f"{result.cost.n_frames} frames of smooth synthetic paths (`simbench.benchmarks.trackers`), after the videos, "
        "in the same run.", "",
        "## Seed 000's findings, checked", "",
        f"Each finding tested on the bench's videos at the {1 - ALPHA:.0%} level: losses by the exact McNemar test "
        "of two trackers on the same videos (binomial intervals: Clopper-Pearson), prediction errors by Welch's t-test "
        "(frames taken as independent, as the paper's t intervals take them). *Reproduced*: the claim holds "
        "significantly in every part; *not reproduced*: the opposite holds significantly in some part; otherwise "
        "*not decidable at this N*. The last column asks the same of the paper's own figures.", "",
        format_findings(result), "",
        "## Results (bench, with seed 000's numbers in brackets or beside)", "",
        format_tables(result),
        "## Plots", "",
        "![losses](plots/losses.png)", "", "![prediction errors](plots/prediction_errors.png)", "",
        "![cost](plots/cost.png)", "",
    ]
    if frames:
        parts += ["## Rendered frames", "",
                  "First video of each category, at a telling frame: raw, and brightened with the true path (dashed), "
                  "each tracker's search circle (around its prediction) and estimate (dot), like the paper's Figs. 3-5.", ""]
        for c, (raw, ann) in frames.items():
            parts += [f"**{c}**: [raw](frames/{raw})", "", f"![{c}](frames/{ann})", ""]
    parts += ["## Discussion", ""] + _discussion(result) + ["", _STATIC_DISCUSSION]
    return "\n".join(parts) + "\n"
