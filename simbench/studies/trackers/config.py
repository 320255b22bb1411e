"""The tracker study's configuration: seed 000's numbers (Tables I-VII), the video difficulty
(fitted to the paper's prediction errors, :data:`CALIBRATED_DIFFICULTY`), :class:`StudyConfig`
and the trackers compared."""

from __future__ import annotations

from dataclasses import dataclass

from mocap.tracker_trials import CATEGORIES
from mocap.trackers import available_trackers, get_tracker


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


_INF = float("inf")


def _check_range(owner: str, name: str, r: Range, lo: float = 0.0, hi: float = _INF) -> None:
    if len(r) != 2 or not (lo <= r[0] <= r[1] <= hi):
        raise ValueError(f"{owner}.{name} must be a range (low, high) with {lo:g} <= low <= high <= {hi:g}, got {r!r}")


class _RangeChecks:
    """The check of a difficulty class: each field named in ``_bounds`` is a range
    ``(low, high)`` with ``lo <= low <= high <= hi`` (errors name ``<_kind>.<field>``)."""

    _kind: str
    _bounds: dict[str, tuple[float, float]]

    def __post_init__(self) -> None:
        for name, (lo, hi) in self._bounds.items():
            _check_range(self._kind, name, getattr(self, name), lo, hi)


@dataclass(frozen=True)
class ZigzagDifficulty(_RangeChecks):
    """A zigzag in several directions: straight legs at one drawn speed, turning left or
    right by a drawn angle at each corner (a leg that would leave the image is cut short).

    speed_px_per_frame : (low, high) image speed, px/frame; leg_frames : (low, high)
    frames per leg; turn_deg : (low, high) turn at a corner, deg.
    """

    speed_px_per_frame: Range
    leg_frames: Range
    turn_deg: Range

    _kind = "zigzag"
    _bounds = {"speed_px_per_frame": (0.1, _INF), "leg_frames": (1.0, _INF), "turn_deg": (0.0, 180.0)}


@dataclass(frozen=True)
class AccelerationDifficulty(_RangeChecks):
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

    _kind = "acceleration"
    _bounds = {"top_speed_px_per_frame": (0.1, _INF), "period_s": (0.1, _INF), "start_speed_px_per_frame": (0.0, _INF),
               "ramp_power": (0.1, _INF)}


@dataclass(frozen=True)
class OcclusionDifficulty(_RangeChecks):
    """A marker crossing a barrier on a straight, arc or wavy path.

    speed_px_per_frame : (low, high) px/frame; barrier_width_px, barrier_height_px :
    (low, high) size of the barrier in the image, px (it hides the marker for at least
    one frame).
    """

    speed_px_per_frame: Range
    barrier_width_px: Range = (30.0, 120.0)
    barrier_height_px: Range = (100.0, 220.0)

    _kind = "occlusion"
    _bounds = {"speed_px_per_frame": (0.1, _INF), "barrier_width_px": (1.0, _INF), "barrier_height_px": (10.0, _INF)}


@dataclass(frozen=True)
class SwapDifficulty(_RangeChecks):
    """Two markers whose straight paths cross at a small angle, passing ``miss_px`` apart.

    speed_px_per_frame : (low, high) px/frame, each marker; crossing_angle_deg : (low,
    high); miss_px : (low, high) closest distance of the paths, px; labelled : 1 (seed
    000: a labelled marker and an unlabelled "NULL" one) or 2 (both labelled).
    """

    speed_px_per_frame: Range
    crossing_angle_deg: Range = (8.0, 30.0)
    miss_px: Range = (0.0, 5.0)
    labelled: int = 1

    _kind = "swap"
    _bounds = {"speed_px_per_frame": (0.1, _INF), "crossing_angle_deg": (0.0, 90.0), "miss_px": (0.0, _INF)}

    def __post_init__(self) -> None:
        super().__post_init__()
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
#: per category from seed 1, 0.08 px detection noise; :mod:`simbench.studies.trackers.fit`)
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

#: The study's webcam image (px).
IMAGE_W, IMAGE_H = 640, 480
