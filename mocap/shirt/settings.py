"""What the colour-shirt pipeline is set with and what it returns per frame.

:class:`ShirtPipelineParams` (the paper's values by default, and the baseline's),
:data:`STAGES` (the timed stages of a frame) and :class:`FrameEstimate` with a
:class:`CameraObservation` per camera; :class:`mocap.shirt.pipeline.ShirtTracker` uses them.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, fields, replace
from difflib import get_close_matches

import numpy as np

from mocap.errors import MocapInputError, require
from mocap.shirt.background import BackgroundParams
from mocap.shirt.classify import Classification
from mocap.shirt.histogram_search import HistogramSearchParams, ShirtLocation
from mocap.shirt.ik import Silhouette
from mocap.shirt.pose_database import Neighbours, TinyMap
from mocap.shirt.shirt_model import CropView

__all__ = ["STAGES", "ShirtPipelineParams", "CameraObservation", "FrameEstimate"]

STAGES: tuple[str, ...] = ("background", "histogram_search", "classify", "database", "global_fit", "pose_assisted", "ik",
                           "white_balance")
"""Timed stages of a frame, in order."""

@dataclass(frozen=True)
class ShirtPipelineParams:
    """Settings of the pipeline (defaults: the paper's values where it gives them).

    Attributes
    ----------
    histogram : HistogramSearchParams
    background : BackgroundParams or None
        None: no background subtraction.
    crop_factor : float
        The classified crop (centred where the histogram search found the shirt) is at
        least this many times the search's scale ``s`` ...
    crop_factor_first : float
        ... (this many on a first frame) ...
    crop_margin : float
        ... and large enough to hold the previous pose's shirt, with this margin: the
        search's scale follows the most colourful part (the torso), the crop must hold
        the arms.
    crop_growth : float
        When classified shirt pixels touch the crop's border, the crop grows by this
        factor and step 1 runs again (once).
    crop_growth_min_pixels : int
        Classified pixels in the crop's 2-pixel border band that count as touching: a
        limb crossing the edge covers tens of them; a few clutter or rim pixels that
        classify as shirt colours must not grow the crop on every frame (at 4 pixels the
        crop grew on nearly every frame of the office scene and the arms were lost at a
        coarser working resolution).
    work_size : int
        Working resolution of the crop (pixels per side, at most).
    wb_size : int
        Resolution of the final pose's id map for the white-balance update.
    wb_every : int
        Step 5 runs on every ``wb_every``-th frame, and on every frame where step 1
        classified poorly (a change of light): the paper updates ``W`` on every frame,
        but in steady light consecutive estimates barely differ.
    wb_min_agreement : float
        Step 5 keeps its new ``W`` only if, with it, at least this fraction of the pixels
        the final pose labels classify as their label (and no fewer than with the current
        ``W``, less 0.02).  An addition to the paper: a pose far off (a first lock-on pass)
        labels the trousers and the set, and the ``W`` fitted to them maps every colour
        to black (shirt_jumping_jacks seed 7: ``W = 0.13 I`` after a pass that explained
        29 % of its pixels, and the take was lost, 34 cm RMS).  shirt_walk_lamp's updates
        under the lamp explain 45 % or more; one frame-0 update of shirt_outdoor seed 8 (33 %)
        is refused too.
    wb_smoothing : float
        In steady light (step 1 classified well in that camera) step 5 moves ``W`` this
        fraction of the way to the new fit, ``W <- a W* + (1 - a) W``; after a change of
        light (step 1 poor) it takes ``W*`` whole.  An addition to the paper (1 is its
        per-frame update): the light of a room changes slowly, while the fit from one
        frame's pose carries that pose's errors (shirt_office seed 3 in fixed light:
        ``W`` 1.97 -> 0.52 -> 1.05 -> 0.40 over frames 36-45 while a forearm was lost).
    render_size : int
        Resolution of the blended pose's id map in each crop (step 3's distance
        transforms and the IK's anchors).
    distance_reduce : int
        Step 3's distance transforms (and the patch split's) run on cells of this many
        render pixels per side (2: 48 x 48 cells, a cell 3 working pixels): the prior
        weighs distances of a fraction of the shirt, and a transform costs the square of
        its side.
    gaussian_threshold, assisted_threshold : float
        ``T`` of step 1 (3) and step 3 (5).
    poor_fraction : float
        Step 1 classifying less than this fraction of the foreground triggers the reference
        search (0.4).  The crop here holds the whole upper body with head and hips, not only
        the shirt, so the fraction is taken relative to the one of the first (labelled)
        frame.
    prior_c : float
        ``C = prior_c / s`` (6).
    neighbours : int
        Database neighbours per camera (10).
    pose_prior : bool
        Step 3, the pose-assisted classification: the blended (or previous) pose as a prior on
        each pixel's colour (off in the baseline, seed 001's "pose prior").
    ik_priors : bool
        Step 4's energy terms towards the blended pose and the previous pose, with the lock-on,
        recovery and arm hypotheses that solve with them (both methods: seed 001 trains their
        covariances "similarly to Wang and Popovic [WP09]", whose IK has them too; off, the IK is
        only damped towards the blend by ``baseline_damping_std``).
    adaptive_white_balance : bool
        Step 5 and the reference-illumination search (off in the baseline).
    reference_distance : float
        Frobenius distance for a new reference illumination (0.5).
    ik_iterations, global_iterations : int
        Levenberg-Marquardt iterations of step 4 and of the 6-DoF fit (at most).
    ik_rel_tol : float
        Both stop earlier when an iteration lowers the energy by less than this fraction.
    poor_fit, recovery_passes, recovery_motion_scale, recovery_blend_scale : float, int, float, float
        With ``ik_priors`` (both methods): when step 4's centroid RMS exceeds ``poor_fit`` shirt sizes, up to
        ``recovery_passes`` more split-and-solve passes run with the motion prior's
        spread times ``recovery_motion_scale`` and the blend prior's times
        ``recovery_blend_scale`` (an addition: the previous pose is then likely wrong and
        would hold the estimate near it).
    steady_motion_scale, steady_after_frames : float, int
        The motion prior's spread is multiplied by ``steady_motion_scale`` on frames of steady
        tracking: from frame ``steady_after_frames`` on (past the lock-on), while no camera's
        step 1 classified poorly on the previous frame (the light holds). An addition (session
        23): the trained spread covers the training motions' frame-to-frame change; tightened
        where nothing else moves the estimate, it keeps a limb one camera sees poorly nearer its
        track (office, walk_lamp and the jumping jacks better on held-out seeds); tightened
        through a lock-on or a change of light it holds on to a wrong pose (0.7 on every frame:
        outdoor's worst seed 1.66 -> 3.08 cm, tungsten_off 2.13 -> 2.33). 1 turns it off.
    arm_hypotheses : bool
        With ``ik_priors``, first frame and lost frames: try each arm in the configuration of
        every database neighbour, the blend and the previous pose; solve again from the
        arms that agree best with step 1 and keep the result when it agrees better by more
        than ``hypothesis_margin`` (a fraction of the classified pixels). 0 (session 22, was
        0.01): on the jumping jacks' lock-on frames the true arm agrees better than the tracked
        one by only 0.004-0.016; held-out seeds 11-20 arms within 5 cm 0.930 -> 0.967.
    lock_on_yaws : int
        With ``ik_priors``, first frame: the solved pose is also tried upright at this many
        headings (0: not), each split and solved again, and the one that agrees best with
        step 1 is kept (:meth:`mocap.shirt.pipeline.ShirtTracker._root_hypotheses`).
    lock_on_passes : int
        With ``ik_priors``: the first frame runs this many times, each from the previous pass's
        pose (:meth:`mocap.shirt.pipeline.ShirtTracker.process`).
    arm_search, arm_search_arms, arm_search_margin, arm_search_top : bool, int, float, int
        With ``ik_priors``, every frame: each arm of the solved pose and ``arm_search_arms`` arms
        of the database (and this frame's neighbours) are scored against step 1 by
        projected sample points (:mod:`mocap.shirt.arm_search`, a few ms); when a candidate
        scores ``arm_search_margin`` shirt sizes better than the pose's own arm, the
        ``arm_search_top`` best candidates of that arm are verified and solved as in
        ``arm_hypotheses`` (also on the first frame and lost frames, with the neighbours).
    arm_search_verify_all : bool
        With ``arm_search``: every frame, the ``arm_search_top`` best candidates of each arm are
        verified by render (as in ``arm_hypotheses``) even when none beats the pose's own arm by
        ``arm_search_margin``; the pose is then solved again loosely only from a winning arm, or
        from itself where the margin was met.  An addition: under a 20 ms shutter's blur the
        screen's margin was never met while the motion prior held a wrong forearm for the rest of
        the take (shirt_jumping_jacks, both methods, about half the seeds), and the render
        agreement with step 1 takes the true arm back.
    arm_search_verify_gap : float
        With ``arm_search_verify_all``: only an arm whose best candidate screens this many shirt
        sizes better than the arm itself is verified (0: any candidate better; ``-inf``: every
        frame).  Where the screen ranks the pose's own arm first the render rarely disagrees, and
        those arms were two thirds of the renders (issue 18's 33 ms per frame): at 0 the seed
        tables' full method read the same on every seed of shirt_office, shirt_outdoor,
        shirt_tungsten_off and shirt_jumping_jacks, and on 7 of 10 of shirt_walk_lamp.
    arm_search_alternate : bool
        With ``arm_search``: after the first frame, on frames that are not lost, the screen
        scores one arm a frame, left and right in turn (a third less of the arm checks' cost;
        a wrong arm is put to the render a frame later at most).  Off: it lost forearms under
        the blur of shirt_jumping_jacks (seeds 1-10 median 2.38 -> 2.62 cm, seed 2 3.71 -> 4.86)
        and the office baseline (seeds 2, 9, 12, 14: 2.6-2.9 -> 4.1-4.5 cm).
    min_patch_pixels : int
        A patch needs this many classified working pixels to constrain the IK.
    correspondence_passes : int
        Step 4 solves, each after splitting the colours into patches with the pose of
        the previous solve (the first uses the blended pose, as the paper; more passes
        are an addition for a database far from the pose).
    patch_gate : float
        Classified pixels farther than this fraction of the shirt's size from every
        rendered patch of their colour do not count towards a centroid.
    absence_constraints : bool
        Add, for each patch the pose shows in a camera that does not see it at all, a
        term pulling it inside the seen shirt (where it can be hidden).  An addition to
        the paper's centroid constraints: without it a limb seen by one camera only can
        swing along that camera's rays.
    thin_bits_out : bool
        Leave out of the patch split each colour's connected pieces (8-connected) that
        are thinner than 3 working pixels throughout: none of their pixels survives a
        morphological opening of the classified mask, all colours together (both
        methods).  An addition to the paper: in shirt_office seeds 3 and 19 the mixed
        pixels along a racket's outline against a yellow box of the set were classified as
        the left forearm's yellow, within its gate, and pulled its centroid 30-80 px off;
        the IK laid the forearm along the other camera's ray (up to 45 cm off for 13
        frames).  A forearm seen 1-2 pixels wide at its end (a wide crop) stays: it joins
        the thicker part of its colour.
    global_fit_std : float
        Assumed error of the blended pose's centroids, in shirt sizes (6-DoF fit weights).
    baseline_damping_std : float
        Without ``ik_priors`` only (the baseline before session 15): weak pull (rad / m) towards
        the blended pose that keeps the unconstrained directions of the IK determined (plain damping).
    keep_classification : bool
        Keep per-camera classification maps in the results (for ROC curves).
    hand_constraints, hand_std, hand_gate, hand_min_pixels, skin_threshold, head_sample
        Both methods, from the second frame on (:mod:`mocap.shirt.hands`): the skin colour is
        fitted once to the unclassified pixels within ``head_sample`` shirt sizes of the first
        frame's head; then each hand is the skin piece (``skin_threshold`` Mahalanobis units;
        ``hand_min_pixels`` working pixels or more) that borders its forearm's pixels of the patch
        split, nearest to where the pose puts the hand within ``hand_gate`` shirt sizes, and its
        centroid a step-4 target with an SD of ``hand_std`` shirt sizes.  0.015 on cached frames of
        the seed tables (medians, shirt_jumping_jacks / shirt_walk_lamp / shirt_tungsten_off seeds
        1-10): 0.01 1.97 / 5.11 / 2.17 cm, 0.015 1.71 / 4.51 / 2.05, 0.025 1.84 / 5.04 / 2.02.
    skin_shading, skin_floor
        The skin colour as a not-shirt colour of steps 1 and 3 (:func:`mocap.shirt.hands.widened_skin`): its
        covariance widened along its mean by ``skin_shading`` of the mean (shading scales a colour) and floored
        at ``skin_floor`` of the mean's norm in every direction; the hands' own test keeps the fitted colour.
    """

    histogram: HistogramSearchParams = HistogramSearchParams()
    background: BackgroundParams | None = BackgroundParams()
    crop_factor: float = 4.5
    crop_factor_first: float = 6.0
    crop_margin: float = 1.2
    crop_growth: float = 1.5
    crop_growth_min_pixels: int = 20
    work_size: int = 144
    wb_size: int = 64
    wb_every: int = 1
    wb_min_agreement: float = 0.35
    wb_smoothing: float = 0.3
    render_size: int = 96
    distance_reduce: int = 2
    gaussian_threshold: float = 3.0
    assisted_threshold: float = 5.0
    poor_fraction: float = 0.4
    prior_c: float = 6.0
    neighbours: int = 10
    pose_prior: bool = True
    ik_priors: bool = True
    adaptive_white_balance: bool = True
    reference_distance: float = 0.5
    ik_iterations: int = 8
    global_iterations: int = 10
    ik_rel_tol: float = 1e-5
    poor_fit: float = 0.12
    recovery_passes: int = 3
    recovery_motion_scale: float = 4.0
    recovery_blend_scale: float = 1.0
    steady_motion_scale: float = 0.7
    steady_after_frames: int = 15
    arm_hypotheses: bool = True
    hypothesis_margin: float = 0.0
    lock_on_yaws: int = 8
    lock_on_passes: int = 2
    arm_search: bool = True
    arm_search_arms: int = 400
    arm_search_margin: float = 0.03
    arm_search_top: int = 3
    arm_search_verify_all: bool = True
    arm_search_verify_gap: float = 0.0
    arm_search_alternate: bool = False
    min_patch_pixels: int = 5
    correspondence_passes: int = 2
    absence_constraints: bool = True
    thin_bits_out: bool = True
    patch_gate: float = 0.2
    global_fit_std: float = 0.03
    baseline_damping_std: float = 3.0
    baseline_previous_start: bool = True
    keep_classification: bool = False
    hand_constraints: bool = True
    hand_std: float = 0.015
    hand_gate: float = 0.35
    hand_min_pixels: int = 8
    skin_threshold: float = 3.0
    head_sample: float = 0.08
    skin_shading: float = 0.5
    skin_floor: float = 0.05

    def __post_init__(self) -> None:
        least = {"wb_every": 1, "distance_reduce": 1, "render_size": 8 * self.distance_reduce, "work_size": 16, "wb_size": 8,
                 "neighbours": 1}
        for name, n in least.items():
            cells = " (8 cells of distance_reduce pixels)" if name == "render_size" else ""
            require(getattr(self, name) >= n, self, name, f"must be at least {n}{cells}", error=MocapInputError)
        require(not self.crop_factor <= 0, self, "crop_factor", "must be positive", error=MocapInputError)  # (NaN passes, as before)
        require(0.0 <= self.wb_min_agreement < 1.0, self, "wb_min_agreement", "must be in [0, 1)", error=MocapInputError)
        require(0.0 < self.wb_smoothing <= 1.0, self, "wb_smoothing", "must be in (0, 1] (1: the paper's per-frame update)",
                error=MocapInputError)
        for name in ("hand_std", "hand_gate", "skin_threshold", "head_sample"):
            require(getattr(self, name) > 0, self, name, "must be positive", error=MocapInputError)
        require(self.hand_min_pixels >= 1, self, "hand_min_pixels", "must be at least 1", error=MocapInputError)
        for name in ("skin_shading", "skin_floor"):
            require(getattr(self, name) >= 0, self, name, "must be at least 0 (0: the fitted skin colour as it is)", error=MocapInputError)
        require(0.0 < self.steady_motion_scale <= 10.0, self, "steady_motion_scale",
                "must be in (0, 10] (1: the trained motion prior on every frame)", error=MocapInputError)
        require(self.steady_after_frames >= 0, self, "steady_after_frames", "must be at least 0", error=MocapInputError)

    def baseline(self) -> "ShirtPipelineParams":
        """The baseline's settings: no pose prior (step 3), no adaptive white balance (step 5); the rest as the method's."""
        return replace(self, pose_prior=False, adaptive_white_balance=False)

    def with_settings(self, settings: Mapping[str, object], where: str = "settings") -> "ShirtPipelineParams":
        """These settings with some of the scalar fields (bool, int, float) replaced: an ablation such as
        ``{"pose_prior": False}``. ``where`` names the mapping in the errors.

        An unknown name, or a value of another type (an int is taken for a float, never a bool for a
        number), raises :class:`MocapInputError` in one line naming it; the values are then checked as
        every construction checks them.
        """
        kinds = {f.name: type(f.default) for f in fields(self) if type(f.default) in (bool, int, float)}
        changes = {}
        for name, value in settings.items():
            kind = kinds.get(name)
            if kind is None:
                close = get_close_matches(name, kinds, n=1)
                hint = f"did you mean {close[0]!r}?" if close else "see ShirtPipelineParams in mocap/shirt/settings.py"
                raise MocapInputError(f"{where}.{name}: not a setting of the shirt tracker; {hint}")
            if kind is bool:
                ok, wanted = isinstance(value, bool), "true or false"
            elif kind is int:
                ok, wanted = isinstance(value, int) and not isinstance(value, bool), "a whole number"
            else:
                ok, wanted = isinstance(value, (int, float)) and not isinstance(value, bool), "a number"
            if not ok:
                raise MocapInputError(f"{where}.{name}={value!r}: must be {wanted}")
            changes[name] = float(value) if kind is float else value
        return replace(self, **changes)


@dataclass
class CameraObservation:
    """What one camera contributed to a frame (kept with ``keep_classification``)."""

    location: ShirtLocation | None = None
    view: CropView | None = None
    step1: Classification | None = None
    final: Classification | None = None
    tiny: TinyMap | None = None
    neighbours: Neighbours | None = None
    ray_rotation: np.ndarray | None = None
    W: np.ndarray | None = None
    foreground: np.ndarray | None = None
    pixels: tuple[np.ndarray, np.ndarray] | None = None  # flat indices and linear RGB of the crop's foreground pixels
    silhouette: Silhouette | None = None
    n_constraints: int = 0


@dataclass
class FrameEstimate:
    """The pipeline's output for one frame.

    Attributes
    ----------
    q : (18,) float
        Upper-body configuration (:mod:`mocap.shirt.shirt_model`); NaN when the frame failed.
    q_blend : (18,) float
        The blended database pose after the 6-DoF fit (NaN if none).
    q_prior : (18,) float or None
        The pose whose id map steps 3 and 4 used (the blend, or the previous pose).
    classified_fraction : (C,) float
        Final classification: classified over foreground pixels of each camera's crop.
    timings_ms : dict[str, float]
        Milliseconds per stage (:data:`STAGES`).
    cameras : list[CameraObservation]
    """

    q: np.ndarray
    q_blend: np.ndarray
    classified_fraction: np.ndarray
    timings_ms: dict[str, float]
    cameras: list[CameraObservation] = field(default_factory=list)
    q_prior: np.ndarray | None = None
