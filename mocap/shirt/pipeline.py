"""The colour-shirt capture pipeline of seed 001, frame by frame, and the simpler baseline.

Per synchronised frame of all cameras (Fig. 4 of the paper):

0. background subtraction (MOG2, coarse; :mod:`mocap.shirt.background`);
1. histogram search for the shirt (:mod:`mocap.shirt.histogram_search`), crop, white
   balance with ``W`` and Gaussian classification, ``T = 3``; under 40 % classified
   foreground, search the reference illuminations (:mod:`mocap.shirt.classify`);
2. the classified region as a tiny 40x40 map, its 10 nearest database poses in every
   camera (:mod:`mocap.shirt.pose_database`), blended; the root's position and
   orientation by a 6-DoF fit of the blended pose's patch centroids in every camera;
3. pose-assisted classification: the blended pose rasterised in every camera is a
   prior (distance transform per colour, ``C = 6 / s``, ``T = 5``);
4. inverse kinematics on the patch centroids with priors towards the blended and the
   previous pose (:mod:`mocap.shirt.ik`);
5. white balance ``W*`` re-estimated under the final pose's id map; added to the
   reference illuminations when farther than 0.5 (Frobenius) from all of them.

The *baseline* (akin to Wang & Popovic 2009, as the paper compares): steps 0-2 and
centroid IK started from the blended pose, but no pose prior (no step 3, no prior
terms in the IK) and no adaptive white balance (``W`` stays the one of the labelled
first frame; no reference search, no step 5).

Additions to the paper, each with its reason where it is made (the baseline has every
one but those of the pose prior, steps 3-4, and of step 5):

* not-shirt colours of the session (trousers, skin, the set next to the subject) from
  the labelled first frame keep dark trousers and grey walls out of the black and
  light-grey patches (:func:`mocap.shirt.colour_model.train_other_colours`);
* the crop holds the previous pose's shirt (the search's scale follows the torso);
* the colours are split into patches a second time with the solved pose, and the IK
  solved again (``correspondence_passes``);
* patches the pose shows where a camera sees none are pulled inside the seen shirt
  (``absence_constraints``);
* the pose prior of steps 3-4 is the blend or the previous pose, whichever agrees
  better with step 1 (the database here samples the joint ranges uniformly, so its
  blends can be far off); step 4 also starts from the previous pose;
* the 40 % trigger of the reference search is relative to the first frame's fraction;
* when step 4's centroids stay far from the solved pose (``poor_fit``), a few more
  split-and-solve passes run with a looser motion prior (``recovery_passes``): the
  previous pose is then likely wrong (e.g. while locking on from a far-off first blend);
  in steady tracking the motion prior is tighter (``steady_motion_scale``): a limb one
  camera sees poorly stays nearer its track;
* on the first frame and on such lost frames, each arm is also tried in the
  configuration of every database neighbour, the blend and the previous pose, and the
  arms that agree best with step 1 are solved again (``arm_hypotheses``): centroid IK
  alone can settle with an arm pointing at a camera, hidden in front of the torso;
* the first frame runs twice, the second pass tracking from the first's pose
  (``lock_on_passes``);
* without a previous pose (the first pass), step 4 is also solved from step 1's classification, and the pose
  that agrees better with step 1 is kept: step 3's only prior is then the blend, and a blend far off
  classifies the shirt after itself;
* step 0's coarse mask loses the crop pixels that look as in the empty scene
  (:meth:`mocap.shirt.background.BackgroundModel.empty_match`);
* the patch split leaves out each colour's classified pieces thinner than 3 working
  pixels throughout (``thin_bits_out``): a one-pixel rim of mixed colours along a prop
  against the set passed as a forearm's colour and pulled its centroid;
* the white balance (section 5.1 and step 5) is least squares in each colour's
  Mahalanobis metric (:func:`mocap.shirt.colour_model.solve_white_balance`), the metric
  the classifier thresholds.
* step 5 keeps a new ``W`` only if it explains a fair share of the pixels the pose labels
  (``wb_min_agreement``: a pose far off otherwise turns every colour black), and in steady
  light moves ``W`` only part of the way to it (``wb_smoothing``: one frame's fit carries
  that pose's errors); after a change of light it takes the new ``W`` whole.
* the bare hands are two more centroid targets of step 4 (:mod:`mocap.shirt.hands`, both methods): the
  skin beyond each sleeve, told apart by the sleeve it borders; the wrists were most of the error.

The histogram search runs on every frame, as in the paper (a crop taken from the
previous pose instead lets a wrong pose steer its own crop: tried, and it lost the arm
for good in shirt_office).  Step 3's distance transforms run on 2 x 2-pixel cells of the
rendered id map (``distance_reduce``).

Stages are timed (``FrameEstimate.timings_ms``); settings, :data:`STAGES` and the output are in
:mod:`mocap.shirt.settings`.  :class:`ShirtTracker`'s parts: :mod:`mocap.shirt.global_fit` (step 2b),
:mod:`mocap.shirt.hypotheses` (lock-on, recovery), :mod:`mocap.shirt.hands`, :mod:`mocap.shirt.white_balance_update`
(step 5); id-map helpers: :mod:`mocap.shirt.id_maps`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from mocap.calibration import Calibration
from mocap.errors import MocapInputError
from mocap.shirt.arm_search import ArmSearch
from mocap.shirt.background import BackgroundModel
from mocap.shirt.classify import (PatchDistances, assign_patches, best_reference, classify_gaussian, classify_pose_assisted, crop_image,
                                  crop_reduced_mask, crop_view, foreground_pixels, other_distance, patch_centroids,
                                  patch_distances)
from mocap.shirt.colour_model import ColourModel, ReferenceIlluminations, initial_white_balance, linear_lookup
from mocap.shirt.global_fit import GlobalFit
from mocap.shirt.hands import HandTracking
from mocap.shirt.histogram_search import search_shirt
from mocap.shirt.hypotheses import TrackerHypotheses
from mocap.shirt.id_maps import border_band, reduced_view, silhouette, touches_border, without_stray_thin_bits, without_thin_bits
from mocap.shirt.ik import Constraints, IKPriors, ShirtIK
from mocap.shirt.pose_database import PoseDatabase, tiny_id_map
from mocap.shirt.kernels import load_kernels
from mocap.shirt.kinematics import UPPER_NQ, UPPER_NV
from mocap.shirt.settings import STAGES, CameraObservation, FrameEstimate, ShirtPipelineParams
from mocap.shirt.shirt_model import ShirtModel
from mocap.shirt.white_balance_update import WhiteBalanceUpdate

__all__ = ["STAGES", "ShirtPipelineParams", "CameraObservation", "FrameEstimate", "ShirtTracker", "initial_white_balance"]


@dataclass(frozen=True)
class _Crop:
    """One camera's crop after step 1: linear RGB ``(h, w, 3)``, foreground mask ``(h, w)`` (or
    None), and its foreground pixels' distances to the shirt colours and to the other colours."""

    linear: np.ndarray
    foreground: np.ndarray | None
    distances: np.ndarray
    other_distances: np.ndarray | None


class ShirtTracker(GlobalFit, TrackerHypotheses, HandTracking, WhiteBalanceUpdate):
    """Runs the pipeline frame after frame for a rig of calibrated cameras.

    Parameters
    ----------
    database : PoseDatabase
        Poses and the shirt model (geometry, MJCF).
    colour_model : ColourModel
    priors : IKPriors
    calibration : Calibration
    white_balance : list of (3, 3) float
        Initial ``W`` of every camera (:func:`initial_white_balance`).
    params : ShirtPipelineParams
    empty_frames : list of list of (H, W, 3) uint8, optional
        Frames of the empty scene per camera to prime the background model.
    other_colours : ColourModel, optional
        The session's not-shirt colours (:func:`mocap.shirt.colour_model.train_other_colours`).
    """

    def __init__(self, database: PoseDatabase, colour_model: ColourModel, priors: IKPriors, calibration: Calibration,
                 white_balance: list[np.ndarray], params: ShirtPipelineParams = ShirtPipelineParams(),
                 empty_frames: list[list[np.ndarray]] | None = None, other_colours: ColourModel | None = None) -> None:
        self.db = database
        self.colours = colour_model
        self.other = other_colours
        self.priors = priors
        self.params = params
        self.cameras = list(calibration)
        C = len(self.cameras)
        if len(white_balance) != C:
            raise MocapInputError(f"ShirtTracker: {len(white_balance)} white-balance matrices for {C} cameras; give one per camera")
        if colour_model.n_colours != database.n_colours:
            raise MocapInputError(f"ShirtTracker: colour model has {colour_model.n_colours} colours, the database's shirt {database.n_colours}")
        load_kernels()  # before the first frame, not on it
        self.model = ShirtModel(database.mjcf_text, database.geometry)
        self.kin = self.model.kin
        self.ik = ShirtIK(self.kin, database.geometry.body_names, self.cameras)
        self.W = [np.asarray(w, float).copy() for w in white_balance]
        self.references = [ReferenceIlluminations(w, params.reference_distance) for w in self.W]
        self.backgrounds: list[BackgroundModel | None] = [None] * C
        if params.background is not None:
            self.backgrounds = [BackgroundModel(params.background) for _ in range(C)]
            if empty_frames is not None:
                if len(empty_frames) != C:
                    raise MocapInputError(f"ShirtTracker: empty_frames for {len(empty_frames)} cameras, the rig has {C}")
                for bg, frames in zip(self.backgrounds, empty_frames):
                    bg.learn_empty(frames)
        self._arm_search = None
        if params.ik_priors and params.arm_search:
            # a fixed generator: the candidate arms are part of the tracker's configuration
            self._arm_search = ArmSearch(self.model, database.hinges, params.arm_search_arms, 6, np.random.default_rng(18))
        self.q_prev: np.ndarray | None = None
        self._prev_world: np.ndarray | None = None  # the previous pose's vertices (ShirtModel.world_vertices)
        self._prev_box: list[tuple[np.ndarray, np.ndarray] | None] = [None] * C
        self._first_fraction: list[float | None] = [None] * C
        self._poor = [False] * C  # step 1 of the current frame classified poorly in this camera
        self._motion_scale = 1.0  # the motion prior's spread on this frame, times the trained one (_process)
        self._frames = 0  # frames finished
        self._thin_out: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # camera -> (classified map, it without stray thin bits)
        self._cells: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # camera -> (foreground pixels, their cells in step 3's maps)
        self._init_hands()
        self._root_active = np.arange(UPPER_NV) < 6  # the free joint's 6 velocities
        K = colour_model.n_colours
        self._colour_members = [np.flatnonzero(self.model.patch_colour == k) for k in range(K)]
        self._colour_order = np.argsort(self.model.patch_colour, kind="stable")
        counts = np.array([len(m) for m in self._colour_members])
        self._colour_starts = np.concatenate([[0], np.cumsum(counts)[:-1]]) if np.all(counts > 0) else None
        self._colour_ends = np.cumsum(counts)

    # ------------------------------------------------------------------ helpers
    def _constraints(self, ci: int, targets_px: np.ndarray, ok: np.ndarray, anchors, sqrt_info: np.ndarray,
                     size_px: float, absent: np.ndarray | None = None) -> Constraints:
        """Constraints of camera ``ci`` for the patches that are measured (``ok``) and rendered (have anchors),
        and absence constraints for rendered patches flagged ``absent``.

        ``targets_px`` and ``sqrt_info`` are per patch: ``(P, 2)`` and ``(P, 2, 2)``.
        """
        patch_a, body_a, point_a, weight_a = anchors
        P = self.model.n_patches
        has = np.zeros(P, bool)
        has[patch_a] = True
        seen = ok & has & np.all(np.isfinite(targets_px), axis=1)
        miss = has & ~seen & (np.zeros(P, bool) if absent is None else absent)
        use = np.flatnonzero(seen | miss)
        if use.size == 0:
            return Constraints.empty()
        index = -np.ones(P, int)
        index[use] = np.arange(use.size)
        a = index[patch_a] >= 0
        # (seen targets are finite: np.nan_to_num, which only the zeroed rows needed, is left out)
        return Constraints(np.full(use.size, ci), use, np.where(seen[use, None], targets_px[use], 0.0), sqrt_info[use],
                           np.full(use.size, float(size_px)), miss[use], index[patch_a[a]], body_a[a], point_a[a], weight_a[a])

    # ------------------------------------------------------------------ one frame
    def process(self, images: list[np.ndarray]) -> FrameEstimate:
        """Run the pipeline on one synchronised frame ``[(H, W, 3) uint8 RGB per camera]``.

        The first frame runs ``lock_on_passes`` times, each pass tracking from the previous
        one's pose (the stage times are their sums): the first pass starts from the blend
        alone, and where that is far off (shirt_outdoor seed 15: all 9 headings 60-75 cm off,
        the root with them) the next pass, with a previous pose, a crop that holds it and
        the recovery of a lost frame, locks on as the second frame of the take did.
        """
        p = self.params
        if self._frames == 0 and p.ik_priors and p.lock_on_passes > 1:
            first = self._process(images)
            if not np.all(np.isfinite(first.q)):
                return first
            est = first
            for _ in range(p.lock_on_passes - 1):
                previous, est = est, self._process(images)
                for s, v in previous.timings_ms.items():  # the passes' times so far
                    est.timings_ms[s] += v
            return est
        return self._process(images)

    def motion_std(self) -> np.ndarray:
        """``(17,)``: the motion prior's spread on this frame (the trained one, tightened in steady tracking)."""
        return self.priors.motion_std * self._motion_scale

    def _process(self, images: list[np.ndarray]) -> FrameEstimate:
        p = self.params
        # steady tracking (past the lock-on, the light holding on the previous frame): a tighter motion prior
        steady = self._frames >= p.steady_after_frames and not any(self._poor)
        self._motion_scale = p.steady_motion_scale if steady else 1.0
        est, cons, lin = self.observe(images)
        if not np.all(np.isfinite(est.q_blend)):
            if not p.keep_classification:
                est.cameras = []
            return est
        q_b = est.q_blend
        T = est.timings_ms

        # 4. inverse kinematics
        t = time.perf_counter()
        if len(cons):
            q = self._solve(est, cons, lin)
            if p.pose_prior and p.ik_priors and self.q_prev is None:
                q = self._lock_on_step_1(q, est, lin)
        else:
            q = q_b.copy()
        T["ik"] = (time.perf_counter() - t) * 1e3

        # 5. white balance for the next frame
        t = time.perf_counter()
        self.finish(q, est.cameras, lin)
        T["white_balance"] = (time.perf_counter() - t) * 1e3
        est.q = q
        if not p.keep_classification:
            est.cameras = []
        return est

    def _solve(self, est: FrameEstimate, cons: Constraints, lin: list[np.ndarray | None]) -> np.ndarray:
        """Step 4 of a frame from its constraints ``cons`` (steps 1-3 in ``est``): the solved pose, after
        the recovery of a lost frame, the lock-on's headings and the arm checks (:mod:`mocap.shirt.hypotheses`)."""
        p = self.params
        q_b = est.q_blend
        if p.ik_priors:
            priors = [(q_b, self.priors.blend_std)]
            if self.q_prev is not None:
                priors.append((self.q_prev, self.motion_std()))
        else:
            priors = [(q_b, np.full(UPPER_NV, p.baseline_damping_std))]
        sil = {ci: o.silhouette for ci, o in enumerate(est.cameras) if o.silhouette is not None}
        res = self.ik.solve(est.q_prior if est.q_prior is not None else q_b, cons, priors, iterations=p.ik_iterations,
                            silhouettes=sil, rel_tol=p.ik_rel_tol)
        if (p.ik_priors or p.baseline_previous_start) and self.q_prev is not None and est.q_prior is not self.q_prev:
            # also start from the previous pose (a blend far off can hold the solver in a
            # local minimum); keep the lower energy.  The baseline does this too: a start
            # is not a prior term (its energy has none towards the previous pose)
            alt = self.ik.solve(self.q_prev, cons, priors, iterations=p.ik_iterations, silhouettes=sil, rel_tol=p.ik_rel_tol)
            res = alt if alt.cost < res.cost else res
        for _ in range(p.correspondence_passes - 1):
            # the two patches of a colour were told apart (and anchored) by the blended
            # pose; a blend far off swaps them: split again with the solved pose
            cons2 = self.reassign(res.q, est.cameras, lin)
            if len(cons2):
                res = self.ik.solve(res.q, cons2, priors, iterations=p.ik_iterations, silhouettes=sil, rel_tol=p.ik_rel_tol)
                cons = cons2
        lost = res.centroid_rms_px > p.poor_fit * float(np.mean(cons.size_px))
        if p.ik_priors and p.recovery_passes and lost:
            # the centroids are far from the pose: the previous pose (which the motion prior
            # holds on to) is probably wrong, e.g. while the tracker is still locking on
            # from a far-off first blend; loosen that prior and split and solve again
            q = self._loose_solve(res.q, est, lin, sil, self._loose_priors(q_b), p.recovery_passes)
        else:
            q = res.q
        if p.ik_priors and p.lock_on_yaws and self._frames == 0:
            q = self._root_hypotheses(q, est, lin, sil)
        if p.ik_priors and p.arm_hypotheses:
            q = self._check_arms(q, est, lin, sil, lost)
        return q

    def finish(self, q: np.ndarray, obs: list[CameraObservation], lin: list[np.ndarray | None]) -> None:
        """Close a frame with pose ``q``: step 5 (if adaptive) and remember ``q`` as the previous pose."""
        p = self.params
        self.q_prev = np.asarray(q, float).copy()
        # the pose's vertices, once for step 5's render and the next crop
        world = self.model.world_vertices(self.q_prev) if np.all(np.isfinite(self.q_prev)) else None
        self._prev_world = world
        # step 5 every wb_every-th frame in steady light, and on every frame whose step 1
        # classified poorly in a camera (the light changed)
        if p.adaptive_white_balance and (self._frames % p.wb_every == 0 or any(self._poor)):
            cams = [ci for ci, o in enumerate(obs) if o.tiny is not None and lin[ci] is not None]
            rends = self.model.render_cameras(q, [(self.cameras[ci], reduced_view(obs[ci].view, p.wb_size)) for ci in cams], world)
            for ci, rend in zip(cams, rends):
                self._update_white_balance(ci, q, obs[ci], lin[ci], rend)
        if self._frames == 0:
            self._learn_skin(self.q_prev, obs)
        self._frames += 1
        # where the shirt of this pose is in every image (the next crop must hold it)
        P = self.model.shirt_vertices(self.q_prev) if world is None else world[self.model.shirt_vertex_index]
        self._prev_box = [self.model.shirt_image_box(P, cam) for cam in self.cameras]

    def observe(self, images: list[np.ndarray]) -> tuple[FrameEstimate, Constraints, list[np.ndarray | None]]:
        """Steps 0-3 of a frame: the blended pose (``q_blend``) and the centroid constraints of step 4.

        Returns the estimate (``q`` still NaN), the constraints and the crops' linear RGB.
        """
        p = self.params
        C = len(self.cameras)
        if len(images) != C:
            raise MocapInputError(f"ShirtTracker.process: {len(images)} images for {C} cameras")
        T = {s: 0.0 for s in STAGES}
        clock = time.perf_counter
        self._thin_out = {}
        self._cells = {}
        obs = [CameraObservation() for _ in range(C)]

        # 0. background subtraction
        t = clock()
        masks = [bg.apply(img, box) if bg is not None else None for bg, img, box in zip(self.backgrounds, images, self._prev_box)]
        T["background"] = (clock() - t) * 1e3

        # histogram search
        t = clock()
        for ci, img in enumerate(images):
            obs[ci].location = search_shirt(img, p.histogram, masks[ci])
        T["histogram_search"] = (clock() - t) * 1e3

        # 1. crop, white balance, Gaussian classification (+ reference illuminations)
        t = clock()
        self._poor = [False] * C
        crops = [self._classify_gaussian(ci, img, masks[ci], obs[ci]) for ci, img in enumerate(images)]
        lin = [c.linear if c is not None else None for c in crops]
        T["classify"] = (clock() - t) * 1e3

        # 2a. database search per camera
        t = clock()
        self._search_database(obs)
        T["database"] = (clock() - t) * 1e3

        # 2b. blend across cameras and fit the root (6 DoF)
        t = clock()
        seen = [ci for ci in range(C) if obs[ci].neighbours is not None]
        q_b = self._blend_and_fit(obs, seen) if seen else None
        T["global_fit"] = (clock() - t) * 1e3
        if q_b is None:
            return self._failed(T, obs, lin)

        # 3. pose-assisted classification, patch centroids, constraints
        t = clock()
        prior_pose, cons, fractions = self._classify_pose_assisted(q_b, obs, seen, crops)
        T["pose_assisted"] = (clock() - t) * 1e3
        est = FrameEstimate(np.full(UPPER_NQ, np.nan), q_b, fractions, T, obs)
        est.q_prior = prior_pose
        return est, cons, lin

    def _classify_gaussian(self, ci: int, img: np.ndarray, mask: np.ndarray | None, o: CameraObservation) -> _Crop | None:
        """Step 1 in camera ``ci``: crop around the shirt (grown once when the shirt touches the
        crop's border), white-balance, classify; with a poor classification (the light changed)
        try the reference illuminations. Fills ``o``; None when the shirt was not found."""
        p = self.params
        loc = o.location
        if loc is None:
            return None
        side = (p.crop_factor if self.q_prev is not None else p.crop_factor_first) * loc.s
        if self._prev_box[ci] is not None:
            lo, hi = self._prev_box[ci]
            reach = np.max(np.abs(np.array([lo, hi]) - [loc.x, loc.y]))
            side = max(side, 2.0 * reach * p.crop_margin)
        limit = 2.0 * max(img.shape[:2])
        side = min(side, limit)
        fg = None
        for attempt in range(2):
            view = crop_view(loc.x, loc.y, side, p.work_size)
            raw = crop_image(img, view)
            lin = linear_lookup(raw)
            if mask is not None:
                fg = crop_reduced_mask(mask, img.shape[1], img.shape[0], view)
                bg = self.backgrounds[ci]
                if bg.empty is not None and bg.empty.shape == img.shape:
                    # the coarse mask's ring of the set: pixels as in the empty scene are background
                    fg &= ~bg.empty_match(raw, crop_image(bg.empty, view))
            if attempt == 0 and side < limit:
                # shirt touching the crop's border: a limb reaches out of it (e.g. one the
                # previous pose lost); look again over a larger square, once.  Only the
                # border band decides this, and only it is classified here
                band = border_band(view.size) if fg is None else border_band(view.size) & fg
                probe = classify_gaussian(lin, self.colours, self.W[ci], band, p.gaussian_threshold, None, self.other)
                if touches_border(probe.colour, min_pixels=p.crop_growth_min_pixels):
                    side = min(side * p.crop_growth, limit)
                    continue
            o.pixels = foreground_pixels(lin, fg)
            dist = self.colours.distances(o.pixels[1], self.W[ci])
            other = other_distance(o.pixels[1], self.other, self.W[ci])
            cls = classify_gaussian(lin, self.colours, self.W[ci], fg, p.gaussian_threshold, dist, self.other, o.pixels, other)
            break
        if self._first_fraction[ci] is None:
            self._first_fraction[ci] = max(cls.classified_fraction, 1e-3)
        poor = cls.classified_fraction < p.poor_fraction * self._first_fraction[ci]
        self._poor[ci] = poor
        if p.adaptive_white_balance and poor and len(self.references[ci]) > 1:
            i, alt = best_reference(lin, self.colours, self.references[ci].matrices, fg, p.gaussian_threshold, self.other)
            if alt.classified_fraction > cls.classified_fraction:
                self.W[ci] = self.references[ci].matrices[i].copy()
                cls = alt
                dist = self.colours.distances(o.pixels[1], self.W[ci])
                other = other_distance(o.pixels[1], self.other, self.W[ci])
        o.view, o.step1, o.W, o.foreground = view, cls, self.W[ci].copy(), fg
        return _Crop(lin, fg, dist, other)

    def _search_database(self, obs: list[CameraObservation]) -> None:
        """Step 2a: each camera's tiny id map and its nearest database entries."""
        for ci, o in enumerate(obs):
            if o.step1 is None:
                continue
            o.tiny = tiny_id_map(without_thin_bits(o.step1.colour), self.colours.n_colours)
            if o.tiny is None:
                continue
            o.neighbours = self.db.search(o.tiny.ids, self.params.neighbours)
            o.ray_rotation = self._ray_rotation(ci, o.view.to_image(o.tiny.centre))


    def _classify_pose_assisted(self, q_b: np.ndarray, obs: list[CameraObservation], seen: list[int],
                                crops: list[_Crop | None]) -> tuple[np.ndarray, Constraints, np.ndarray]:
        """Step 3: the prior pose, each camera's pose-assisted classification, silhouette and
        patch-centroid constraints; returns the prior pose, the constraints and the classified fractions ``(C,)``."""
        p = self.params
        lin = [c.linear if c is not None else None for c in crops]
        fgs = [c.foreground if c is not None else None for c in crops]
        # the pose whose id map splits the colours into patches: the blend or the previous pose
        # (the baseline too, which then uses it for that alone: its classification stays step 1's)
        use_prev = p.pose_prior or p.baseline_previous_start
        prior_pose, renders = self._prior_pose(q_b, obs, seen, lin, fgs) if use_prev else (q_b, {})
        parts = []
        fractions = np.zeros(len(obs))
        for ci in seen:
            o, crop = obs[ci], crops[ci]
            # the prior pose's id map at a reduced resolution: distance transforms and anchors
            rend, idx, pdist = renders[ci] if ci in renders else self._render_distances(prior_pose, ci, o, crop.linear, crop.foreground)
            if p.pose_prior:
                # each colour's distance: the least over its patches (patches sorted by colour)
                # (per map cell, then gathered for the pixels: a minimum commutes with the gather)
                cells = pdist.cells
                if self._colour_starts is not None:
                    # (slices of the patches sorted by colour: np.minimum.reduceat over axis 0 is ten times slower)
                    by_colour = cells[self._colour_order]
                    cmin = np.empty((len(self._colour_starts), cells.shape[1]), np.float32)
                    for k, (a, b) in enumerate(zip(self._colour_starts, self._colour_ends)):
                        np.minimum.reduce(by_colour[a:b], axis=0, out=cmin[k])
                else:
                    cmin = np.stack([cells[m].min(axis=0) if m.size else np.full(cells.shape[1:], np.inf, np.float32)
                                     for m in self._colour_members])
                cdist = cmin[:, pdist.cell] * np.float32(o.view.scale)
                # C = 6 / s, s the side of the shirt's square (image pixels)
                final = classify_pose_assisted(crop.linear, self.colours, self.W[ci], cdist, p.prior_c / (o.tiny.side * o.view.scale),
                                               crop.foreground, p.assisted_threshold, crop.distances, self.other, o.pixels,
                                               crop.other_distances)
            else:
                final = o.step1
            o.final = final
            o.silhouette = silhouette(final.colour, o.view)
            fractions[ci] = final.classified_fraction
            cons = self._camera_constraints(ci, o, final.colour, idx, pdist, rend, prior_pose)
            o.n_constraints = len(cons)
            parts.append(cons)
        return prior_pose, Constraints.concatenate(parts), fractions

    def _render_distances(self, q: np.ndarray, ci: int, o: CameraObservation, lin: np.ndarray, fg: np.ndarray | None):
        """Id map of pose ``q`` in camera ``ci``'s crop (reduced) and distances of the foreground pixels to its patches."""
        rend = self.model.render_camera(q, self.cameras[ci], reduced_view(o.view, self.params.render_size))
        idx = o.pixels[0]
        return rend, idx, self._patch_distances(ci, o, rend)

    def _patch_distances(self, ci: int, o: CameraObservation, rend) -> PatchDistances:
        """Distances from camera ``ci``'s foreground pixels to the patches of the id map ``rend`` (the pixels'
        cells computed once a frame)."""
        kept = self._cells.get(ci)
        cell = kept[1] if kept is not None and kept[0] is o.pixels[0] else None
        pd = patch_distances(rend.patch, self.model.n_patches, o.pixels[0], o.view.size, self.params.distance_reduce, cell)
        self._cells[ci] = (o.pixels[0], pd.cell)
        return pd

    def _prior_pose(self, q_b: np.ndarray, obs: list[CameraObservation], seen: list[int], lin: list, fgs: list):
        """The pose whose id map steps 3 and 4 use: the blended pose, or the previous frame's when that one agrees
        better with the step-1 classification (:meth:`_agreement`).

        Not in seed 001, whose database covers realistic poses densely; a database sampled
        uniformly over the joint ranges gives blends that can be far off, while the
        previous pose of a tracked sequence is usually a few centimetres away.

        Returns the pose and its renders ``{camera: (rendered, pixel indices, patch distances)}``.
        """
        p = self.params
        if self.q_prev is None:
            return q_b, {}
        scores, renders = self._agreement([q_b, self.q_prev], obs, seen)
        best = 1 if scores[1] > scores[0] else 0
        out = {}
        for ci, rend in renders[best].items():
            idx = obs[ci].pixels[0]
            out[ci] = (rend, idx, self._patch_distances(ci, obs[ci], rend))
        return (self.q_prev if best else q_b), out


    def _camera_constraints(self, ci: int, o: CameraObservation, colour: np.ndarray, idx: np.ndarray, pdist: PatchDistances,
                            rend, q: np.ndarray) -> Constraints:
        """Centroid constraints of one camera: classified colours split into patches by the pose ``q`` rendered in
        ``rend``; absence constraints for patches the pose shows (8+ pixels of its id map) that are not seen (fewer
        than min_patch_pixels); the hands' (:mod:`mocap.shirt.hands`)."""
        p = self.params
        if p.thin_bits_out:
            # mixed pixels along an outline (a prop held against a box of the set's colour) can pass as a
            # patch's colour within its gate and pull its centroid (issue 18: shirt_office seeds 3 and 19)
            # (once per classification: the passes of a frame split the same one again)
            kept = self._thin_out.get(ci)
            if kept is None or kept[0] is not colour:
                kept = self._thin_out[ci] = (colour, without_stray_thin_bits(colour))
            colour = kept[1]
        # pdist is in working pixels; the gate is a fraction of the shirt's size
        pm = assign_patches(colour, idx, pdist, self.model.patch_colour, gate=p.patch_gate * o.tiny.side)
        cents, counts = patch_centroids(pm, self.model.n_patches)
        size_px = o.tiny.side * o.view.scale
        info = self.priors.centroid_sqrt_info(np.arange(self.model.n_patches), size_px)
        absent = None
        if p.absence_constraints:
            shown = np.bincount(rend.patch[rend.patch >= 0].ravel().astype(np.int64), minlength=self.model.n_patches)
            absent = (counts < p.min_patch_pixels) & (shown >= 8)
        cons = self._constraints(ci, o.view.to_image(cents), counts >= p.min_patch_pixels, self.model.patch_anchors(rend),
                                 info, size_px, absent)
        return Constraints.concatenate([cons, self._hand_constraints(ci, o, q, rend, pm)]) if self.skin is not None else cons

    def reassign(self, q: np.ndarray, obs: list[CameraObservation], lin: list[np.ndarray | None]) -> Constraints:
        """Constraints again with patches split and anchored by the id map of pose ``q`` (a second pass)."""
        parts = []
        cams = [ci for ci, o in enumerate(obs) if o.final is not None and lin[ci] is not None]
        rends = self.model.render_cameras(q, [(self.cameras[ci], reduced_view(obs[ci].view, self.params.render_size)) for ci in cams])
        for ci, rend in zip(cams, rends):
            o = obs[ci]
            idx = o.pixels[0]
            pdist = self._patch_distances(ci, o, rend)
            parts.append(self._camera_constraints(ci, o, o.final.colour, idx, pdist, rend, q))
        return Constraints.concatenate(parts)

    def _failed(self, T: dict, obs: list[CameraObservation], lin: list):
        C = len(self.cameras)
        return FrameEstimate(np.full(UPPER_NQ, np.nan), np.full(UPPER_NQ, np.nan), np.zeros(C), T, obs), Constraints.empty(), lin
