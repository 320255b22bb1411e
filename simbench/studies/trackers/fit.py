"""The tracker study's difficulty, fitted to seed 000's prediction errors (Tables II-IV).

Seed 000 reports how far its three trackers' predictions fell from the detections
(Tables II-IV: slow and rapid zigzags, motions with acceleration) but not how fast its
markers moved. Those errors are set by the motion: the alpha-beta filter misses at each
zigzag corner by about the change of velocity there, OpenMoCap's Kalman filter a little
more for longer (its velocity is smoother), and OpenMoCap's CONDENSATION, with a
position-only state, trails the marker by about twice its speed. So the three errors pin
down speed, leg length and turn angle of the zigzags, and the top speed and swing
period of the accelerated motions.

:func:`fit_difficulty` finds them: for each category, Nelder-Mead
(``scipy.optimize.minimize``) on the logarithms of the parameters, minimising

    sum over alpha_beta, kalman_openmocap, condensation of log(bench mean / paper mean) ** 2

where a bench mean pools the prediction errors of ``n_videos`` videos (drawn with
:func:`simbench.studies.trackers.videos.plan_video` from a seed other than the study's) without
a loss, as the paper pooled its videos. The videos are not rendered: the detections are
the markers' true mid-exposure positions plus Gaussian noise of the rendered
detector's size (``noise_px``; measured on the study's rendered videos: 0.10 px mean
distance, i.e. about 0.08 px per axis), which makes one evaluation a fraction of a
second. The parameters are drawn per video from a range around each fitted centre:
speed +-15 %, leg length +-30 %, turn +-45 deg; top speed +-15 %, period +-30 %.

``simbench study fit-difficulty`` runs it and prints the values to put into
:data:`simbench.studies.trackers.config.CALIBRATED_DIFFICULTY`; the rendered study then checks
them (its Tables II-IV beside the paper's).

Occlusion and swap videos have no prediction-error table in the paper, so nothing there
can be fitted: their markers move at the fitted *slow* speeds.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import minimize

from eval import tracking_metrics as tm
from mocap.tracking import track_camera
from simbench.stage.renderer import mid_exposure_times
from simbench.studies.trackers.config import AccelerationDifficulty, CALIBRATED_DIFFICULTY, ERROR_CATEGORIES, IMAGE_H, IMAGE_W, PAPER_ERRORS, SEED_TRACKERS, StudyConfig, VideoDifficulty, ZigzagDifficulty
from simbench.studies.trackers.tracking import tracker_rng
from simbench.studies.trackers.videos import plan_video

#: The paper's three trackers, whose errors are fitted.
FIT_TRACKERS = SEED_TRACKERS
FIT_CATEGORIES = ERROR_CATEGORIES
#: Relative half widths of the drawn ranges around a fitted centre.
SPEED_SPREAD = 0.15
LEG_SPREAD = 0.30
TURN_SPREAD_DEG = 45.0
PERIOD_SPREAD = 0.30


@dataclass(frozen=True)
class CategoryFit:
    """The fit of one category.

    category : str
    centre : dict parameter -> fitted centre value
    difficulty : ZigzagDifficulty or AccelerationDifficulty at the fitted centre
    errors : tracker -> mean prediction error (px) at the fit, over the fit videos
    lost : tracker -> fit videos with a loss
    paper : tracker -> the paper's mean, px
    objective : float, the fitted sum of squared log ratios
    evaluations : int
    """

    category: str
    centre: dict[str, float]
    difficulty: ZigzagDifficulty | AccelerationDifficulty
    errors: dict[str, float]
    lost: dict[str, int]
    paper: dict[str, float]
    objective: float
    evaluations: int


@dataclass(frozen=True)
class DifficultyFit:
    """All fitted categories and the difficulty they make (occlusion and swap at the
    fitted slow speeds)."""

    categories: dict[str, CategoryFit]
    difficulty: VideoDifficulty
    n_videos: int
    seed: int
    noise_px: float
    trackers: tuple[str, ...] = field(default=FIT_TRACKERS)


def zigzag_difficulty(speed: float, leg_frames: float, turn_deg: float) -> ZigzagDifficulty:
    """Zigzag ranges around the centres ``speed`` px/frame, ``leg_frames``, ``turn_deg``."""
    lo_t, hi_t = max(0.0, turn_deg - TURN_SPREAD_DEG), min(180.0, turn_deg + TURN_SPREAD_DEG)
    return ZigzagDifficulty(speed_px_per_frame=_spread(speed, SPEED_SPREAD), leg_frames=_spread(leg_frames, LEG_SPREAD),
                               turn_deg=(round(lo_t, 1), round(hi_t, 1)))


def acceleration_difficulty(top_speed: float, period_s: float) -> AccelerationDifficulty:
    """Acceleration ranges around the centres ``top_speed`` px/frame and ``period_s`` s."""
    return AccelerationDifficulty(top_speed_px_per_frame=_spread(top_speed, SPEED_SPREAD),
                                     period_s=_spread(period_s, PERIOD_SPREAD))


def _spread(centre: float, rel: float) -> tuple[float, float]:
    return (round(centre * (1.0 - rel), 2), round(centre * (1.0 + rel), 2))


_BUILDERS = {"slow": (zigzag_difficulty, ("speed_px_per_frame", "leg_frames", "turn_deg")),
             "rapid": (zigzag_difficulty, ("speed_px_per_frame", "leg_frames", "turn_deg")),
             "acceleration": (acceleration_difficulty, ("top_speed_px_per_frame", "period_s"))}
#: Starting points of the fit (from a coarse grid over speed, legs and turns).
START = {"slow": (22.0, 6.0, 90.0), "rapid": (24.0, 4.0, 100.0), "acceleration": (12.0, 1.5)}


def synthetic_video(config: StudyConfig, category: str, index: int, noise_px: float
                    ) -> tuple[np.ndarray, list[np.ndarray]]:
    """A video of the study's plan without rendering: true mid-exposure positions
    (F, M, 2) px and per frame the detections, those positions plus Gaussian noise of
    ``noise_px`` per axis (in a shuffled order)."""
    plan = plan_video(config, category, index)
    times = mid_exposure_times(config.n_frames, config.fps, config.exposure_ms)
    true = plan.xy_at(times)
    rng = np.random.default_rng(np.random.SeedSequence([plan.render_seed, 2]))
    noisy = true + rng.normal(0.0, noise_px, true.shape)
    return true, [noisy[f, rng.permutation(true.shape[1])] for f in range(len(true))]


def mean_errors(config: StudyConfig, category: str, n_videos: int, noise_px: float,
                trackers: tuple[str, ...] = FIT_TRACKERS) -> tuple[dict[str, float], dict[str, int]]:
    """Mean prediction error (px) of each tracker over the ``n_videos`` synthetic videos
    of ``category`` in which it lost nothing, and the number of videos with a loss
    (the study's definitions; every marker in the image counts as visible)."""
    pooled: dict[str, list[np.ndarray]] = {t: [] for t in trackers}
    lost = {t: 0 for t in trackers}
    for k in range(n_videos):
        true, dets = synthetic_video(config, category, k, noise_px)
        visible = (true[..., 0] >= 0) & (true[..., 0] <= IMAGE_W - 1) & (true[..., 1] >= 0) & (true[..., 1] <= IMAGE_H - 1)
        L = true.shape[1]
        for t in trackers:
            tracks = track_camera(dets, true[0], [f"m{m}" for m in range(L)], t, config.dt,
                                  tracker_rng(config, category, k, t))
            losses = tm.label_losses(true, visible, tracks.estimate, tracks.status, tracks.xy, config.loss_radius_px)
            if losses.lost.any():
                lost[t] += 1
            else:
                pooled[t].append(tm.prediction_errors(tracks.predicted, tracks.xy))
    means = {t: float(np.concatenate(v).mean()) if v else float("nan") for t, v in pooled.items()}
    return means, lost


def fit_category(category: str, n_videos: int = 40, seed: int = 1, noise_px: float = 0.08,
                 start: tuple[float, ...] | None = None, max_evaluations: int = 150,
                 paper: dict[str, float] | None = None) -> CategoryFit:
    """Fit one category's motion to the paper's Table II, III or IV (see the module
    docstring); ``seed`` draws the fit videos (the study's own seed is 0); ``paper``
    replaces the paper's means (tracker -> px), e.g. to check that the fit recovers a
    known difficulty."""
    if category not in _BUILDERS:
        raise ValueError(f"category must be one of {', '.join(_BUILDERS)}, got {category!r}")
    build, names = _BUILDERS[category]
    paper = dict(paper) if paper is not None else {t: PAPER_ERRORS[category][t][2] for t in FIT_TRACKERS}
    base = StudyConfig(seed=seed)
    cache: dict[tuple[float, ...], tuple[float, dict, dict]] = {}

    def evaluate(logx: np.ndarray) -> float:
        x = tuple(float(v) for v in np.round(np.exp(logx), 3))
        if x not in cache:
            try:
                d = build(*x)
            except ValueError:
                cache[x] = (1e6, {}, {})
                return 1e6
            cfg = dataclasses.replace(base, difficulty=dataclasses.replace(base.difficulty, **{category: d}))
            try:
                means, lost = mean_errors(cfg, category, n_videos, noise_px)
            except RuntimeError:  # a path that does not fit in the image
                cache[x] = (1e6, {}, {})
                return 1e6
            ratios = np.array([means[t] / paper[t] for t in FIT_TRACKERS])
            obj = float(np.sum(np.log(ratios) ** 2)) if np.all(np.isfinite(ratios)) else 1e6
            cache[x] = (obj, means, lost)
        return cache[x][0]

    x0 = np.log(np.asarray(start or START[category], dtype=float))
    res = minimize(evaluate, x0, method="Nelder-Mead",
                   options={"maxfev": max_evaluations, "xatol": 0.01, "fatol": 1e-4, "initial_simplex": _simplex(x0)})
    x = tuple(float(v) for v in np.round(np.exp(res.x), 3))
    obj, means, lost = cache[x] if x in cache else (evaluate(res.x), *cache[x][1:])
    centre = dict(zip(names, (round(v, 2) for v in x)))
    return CategoryFit(category, centre, build(*x), means, lost, paper, obj, len(cache))


def _simplex(x0: np.ndarray) -> np.ndarray:
    """Starting simplex: each log-parameter moved by 0.15 (about 16 %)."""
    return np.vstack([x0] + [x0 + 0.15 * np.eye(len(x0))[k] for k in range(len(x0))])


def fit_difficulty(n_videos: int = 40, seed: int = 1, noise_px: float = 0.08,
                   categories: tuple[str, ...] = FIT_CATEGORIES, max_evaluations: int = 150) -> DifficultyFit:
    """Fit every error category; occlusion and swap markers move at the fitted slow speeds."""
    fits = {c: fit_category(c, n_videos, seed, noise_px, max_evaluations=max_evaluations) for c in categories}
    d = CALIBRATED_DIFFICULTY
    repl = {c: f.difficulty for c, f in fits.items()}
    if "slow" in fits:
        speed = fits["slow"].difficulty.speed_px_per_frame
        repl["occlusion"] = dataclasses.replace(d.occlusion, speed_px_per_frame=speed)
        repl["swap"] = dataclasses.replace(d.swap, speed_px_per_frame=speed)
    return DifficultyFit(fits, dataclasses.replace(d, **repl), n_videos, seed, noise_px)


def format_fit(fit: DifficultyFit) -> str:
    """The fitted centres, ranges and errors beside the paper's, and the Python literal
    of the difficulty."""
    lines = [f"Fit of the video difficulty to seed 000's Tables II-IV: {fit.n_videos} synthetic videos per category "
             f"(seed {fit.seed}), detection noise {fit.noise_px:g} px per axis.", ""]
    for c, f in fit.categories.items():
        lines.append(f"{c}: " + ", ".join(f"{k} {v:g}" for k, v in f.centre.items())
                     + f"  (objective {f.objective:.4f}, {f.evaluations} evaluations)")
        for t in fit.trackers:
            e, p = f.errors.get(t, float("nan")), f.paper[t]
            lines.append(f"    {t:18s} {e:6.2f} px  paper {p:6.2f}  ratio {e / p:5.2f}  videos lost {f.lost.get(t, 0)}/{fit.n_videos}")
    lines += ["", "CALIBRATED_DIFFICULTY = " + repr(fit.difficulty)]
    return "\n".join(lines)
