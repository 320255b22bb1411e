"""The marker capture pipeline end to end: frames -> labelled 3D trajectories -> skeleton.

detection (per camera, per frame) -> label initialisation on the first frame (T-pose
template, no ground truth) -> 2D tracking that keeps labels (any registered tracker)
-> multi-camera reconstruction -> optional skeleton solving. The same function runs on
real webcam video (``mocap markers``) and on the bench's rendered frames
(``simbench run``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Sequence

import numpy as np

from mocap.calibration import Calibration
from mocap.capture_passes import CapturePasses, first_reconstruction
from mocap.correspondence import CorrespondenceParams, UnlabelledPoints, reconstruct_unlabelled
from mocap.detection import DetectionParams, detect_markers
from mocap.errors import MocapInputError, require
from mocap.free_blob_fill import fill_from_free_blobs
from mocap.limb_fill import fill_limbs_from_free_blobs
from mocap.labelling import LabelInit, LabelInitParams, LabelTemplate, Placement, initial_labels
from mocap.cluster_labelling import ClusterMarkerModel
from mocap.model_check import error_limit_mm, model_markers, robust_skeleton_fit, view_limits_mm, without_points
from mocap.model_labelling import ModelLabellingParams, PointLabels, label_points
from mocap.motion_check import MAX_MARKER_SPEED_MPS, lone_markers, motion_outliers, without_motion_outliers
from mocap.skeleton_labelling import SkeletonMarkerModel
from mocap.reassociation import ReassociationParams
from mocap.reconstruction import ReconstructionParams
from mocap.swap_repair import SwapRepairParams
from mocap.synchronisation import ClockSync, SyncParams, estimate_sync, resample_detections
from mocap.tracking import track_cameras
from mocap.types import Detections, Tracks2D, Trajectories


@dataclass
class MarkerPipelineParams:
    """Settings of the marker pipeline.

    ``labelling`` chooses how labels are found: ``"model"`` (default) reconstructs unlabelled 3D
    points from every frame's blobs and labels them with the subject's model from the frame where
    the fit is most confident, forward and backward, re-acquiring markers after gaps
    (:mod:`mocap.model_labelling`); ``"tracker"`` is seed 000's scheme, labels from a T-pose first
    frame kept by a 2D ``tracker`` in every camera (:mod:`mocap.labelling`, :mod:`mocap.tracking`).
    The model path needs a subject (skeleton) or a marker model (rigid clusters); without either
    it falls back to the tracker path.

    ``model_outlier_mm``, ``model_check_rounds`` and ``model_check_max_drops`` set the model
    check after the skeleton fit (:func:`mocap.model_check.robust_skeleton_fit`): points farther
    than ``model_outlier_mm`` from the fitted model are dropped one per frame and refit, for at
    most ``model_check_rounds`` rounds; a frame that needed more than ``model_check_max_drops``
    drops loses every point the first fit missed; there the check takes points back one per
    frame and round for ``model_check_grow_rounds`` rounds. Then, for ``free_blob_fill_rounds``
    rounds (each after a refit), markers still missing are measured from blobs no kept label
    uses within ``free_blob_gate_px`` of the checked model's projection
    (:func:`mocap.free_blob_fill.fill_from_free_blobs`); with ``limb_fill``, limbs the model
    misplaces are then fitted to the free blobs (:func:`mocap.limb_fill.fill_limbs_from_free_blobs`).
    Gaps are filled from the model where the measured markers place the marker within
    ``model_fill_max_spread_mm`` (for 1 mm marker noise). Before the model check, a marker alone
    on its body (which the check cannot judge) loses the points it reached faster than
    ``max_marker_speed_mps`` and did not come back from (:mod:`mocap.motion_check`; 0: off).

    ``marker_radius_m``: the markers' radius (a 14 mm sphere: 0.007), 0 if unknown. With it,
    detections that measured their lit limb (the visible-light detector,
    :func:`mocap.detection.visible.lit_limbs`) are re-centred once the markers are
    triangulated, each by its image radius from its distance (:func:`limb_centroids`); the
    labelled measurements move with their blobs and are triangulated again (labels unchanged).
    """

    detection: DetectionParams = field(default_factory=DetectionParams)
    labelling: str = "model"
    correspondence: CorrespondenceParams = field(default_factory=CorrespondenceParams)
    model_labelling: ModelLabellingParams = field(default_factory=ModelLabellingParams)
    tracker: str = "kalman"
    tracker_params: dict = field(default_factory=dict)
    label_init: LabelInitParams = field(default_factory=LabelInitParams)
    reconstruction: ReconstructionParams = field(default_factory=ReconstructionParams)
    reassociation: ReassociationParams | None = field(default_factory=ReassociationParams)
    reassociation_passes: int = 2
    solve_skeleton: bool = True
    model_guided: bool = True
    model_gate_px: float = 5.0
    model_outlier_mm: float = 10.0
    model_check_rounds: int = 4
    model_check_max_drops: int = 2
    model_check_grow_rounds: int = 6
    free_blob_fill_rounds: int = 1
    free_blob_gate_px: float = 3.0
    limb_fill: bool = True
    model_fill_max_spread_mm: float = 3.0
    swap_repair: SwapRepairParams | None = field(default_factory=SwapRepairParams)
    marker_radius_m: float = 0.0
    max_marker_speed_mps: float = MAX_MARKER_SPEED_MPS

    def __post_init__(self) -> None:
        require(self.max_marker_speed_mps >= 0, self, "max_marker_speed_mps", "must be >= 0 m/s (0: off)")
        require(self.marker_radius_m >= 0, self, "marker_radius_m", "must be >= 0 m (0: markers' size unknown)")
        require(self.model_check_grow_rounds >= 0, self, "model_check_grow_rounds", "must be >= 0 (0: off)")
        require(self.free_blob_fill_rounds >= 0, self, "free_blob_fill_rounds", "must be >= 0 (0: off)")
        require(self.free_blob_gate_px > 0, self, "free_blob_gate_px", "must be > 0 pixels")
        require(self.model_fill_max_spread_mm > 0, self, "model_fill_max_spread_mm", "must be > 0 mm")


@dataclass
class MarkerCapture:
    """Everything the pipeline produced.

    detections : C lists of F :class:`Detections`
    label_init : first-frame labelling
    tracks : labelled 2D tracks ``(F, C, M, 2)``; ``xy`` holds the measurements used for
        triangulation (after 3D-guided re-association), ``predicted_xy``/``status`` the
        2D trackers' own estimates
    trajectories : labelled 3D trajectories ``(F, M, 3)`` metres
    skeleton : solved skeleton (``mocap.skeleton_fit.SkeletonFit``) or None
    timings_ms : stage name -> total milliseconds
    labelling : ``"model"`` (labels from the subject's skeleton or a labelled trial's marker clusters)
        or ``"tracker"`` (seed 000's T-pose first frame kept by 2D trackers)
    """

    detections: list[list[Detections]]
    label_init: LabelInit
    tracks: Tracks2D
    trajectories: Trajectories
    skeleton: object | None
    timings_ms: dict[str, float]
    reassociation: dict[str, int] = field(default_factory=dict)
    labelling: str = "tracker"


class DetectionStream:
    """Detects markers frame by frame as frames arrive (e.g. while they are rendered)."""

    def __init__(self, n_cameras: int, params: DetectionParams | None = None) -> None:
        self.params = params or DetectionParams()
        self.detections: list[list[Detections]] = [[] for _ in range(n_cameras)]
        self.ms = 0.0

    def add(self, images: Sequence[np.ndarray]) -> None:
        """One frame of every camera, ``C`` images ``(H, W)`` or ``(H, W, 3)`` uint8."""
        t0 = time.perf_counter()
        for c, img in enumerate(images):
            self.detections[c].append(detect_markers(img, self.params))
        self.ms += (time.perf_counter() - t0) * 1e3


def capture_from_detections(
    detections: list[list[Detections]],
    calibration: Calibration,
    template: LabelTemplate,
    times: np.ndarray,
    params: MarkerPipelineParams | None = None,
    rng: np.random.Generator | None = None,
    subject=None,
    detection_ms: float = 0.0,
    marker_model: ClusterMarkerModel | None = None,
) -> MarkerCapture:
    """Label, track, reconstruct and (optionally) solve the skeleton.

    Parameters
    ----------
    detections : C lists of F Detections, in calibration order
    calibration : Calibration
    template : LabelTemplate (T-pose marker positions, subject-local frame)
    times : (F,) seconds
    subject : mocap.subject.SubjectModel, needed when ``params.solve_skeleton`` and used by
        model-based labelling
    marker_model : ClusterMarkerModel, optional
        Rigid marker clusters of a subject without a skeleton (from a labelled trial), for
        model-based labelling.
    """
    params = params or MarkerPipelineParams()
    if rng is None:
        raise ValueError("capture_from_detections needs rng=np.random.default_rng(seed)")
    C = len(calibration)
    if len(detections) != C:
        raise MocapInputError(f"got detections of {len(detections)} cameras for a calibration of {C} ({calibration.names})")
    timings = {"detection": detection_ms}
    if params.labelling not in ("model", "tracker"):
        raise MocapInputError(f"labelling={params.labelling!r}: use 'model' or 'tracker'")
    solvers: dict = {}  # the subject's skeleton solvers, built once per capture (_solver)
    use_model, tracks, init = _labelled_tracks(detections, calibration, template, times, params, rng, subject,
                                               marker_model, timings, solvers)
    t0 = time.perf_counter()
    passes = first_reconstruction(tracks, detections, calibration, times, params.reconstruction, params.reassociation,
                                  params.swap_repair, use_model)
    if params.reassociation is not None:
        # 3D-guided correspondence: reproject, re-associate detections, reconstruct again.
        for _ in range(params.reassociation_passes):
            passes.run()
    timings["reconstruction"] = (time.perf_counter() - t0) * 1e3
    if params.marker_radius_m > 0 and _has_limbs(detections):
        # Shaded spheres: the same labelled blobs re-centred on their lit limbs, at the image
        # radius the points just triangulated give them, and triangulated again.
        t0 = time.perf_counter()
        refined, moved = limb_centroids(detections, passes.traj, calibration, params.marker_radius_m)
        passes.recentre(refined)
        passes.stats["limb_centroids"] = moved
        timings["limb_centroids"] = (time.perf_counter() - t0) * 1e3
    fit = None
    if params.solve_skeleton and subject is not None:
        t0 = time.perf_counter()
        fit = _solve_skeleton(passes, subject, params, solvers)
        timings["skeleton"] = (time.perf_counter() - t0) * 1e3
    stats = passes.stats
    stats["swaps_repaired"] = sum(1 for e in passes.swaps if e[0] == "swap")
    stats["jump_samples_removed"] = sum(1 for e in passes.swaps if e[0] == "jump")
    tracks = Tracks2D(tracks.labels, passes.measured.xy, tracks.predicted_xy, tracks.status, tracks.camera_names)
    return MarkerCapture(passes.detections, init, tracks, passes.traj, fit, timings, stats, "model" if use_model else "tracker")


def _has_limbs(detections: list[list[Detections]]) -> bool:
    return any(getattr(d, "limb_dist", None) is not None and np.isfinite(d.limb_dist).any()
               for cam in detections for d in cam)


#: A blob takes the image radius of the reprojected marker nearest to it within this many pixels.
LIMB_MATCH_PX = 2.0
#: Largest move of a blob by its lit limb (px): more is a limb that was not the marker's.
LIMB_MAX_SHIFT_PX = 1.0


def limb_centroids(detections: list[list[Detections]], traj: Trajectories, calibration: Calibration,
                   marker_radius_m: float) -> tuple[list[list[Detections]], int]:
    """Detections re-centred on their lit limbs, and how many blobs moved.

    A marker lit from one side is imaged as a bright cap fading into a dim far side, so its
    centroid lies towards the light (:func:`mocap.detection.visible.lit_limbs`). Its lit
    limb's edge is on the silhouette, ``rho = f * marker_radius_m / depth`` pixels from the
    centre, and that radius is known once the marker is triangulated. Each blob with a
    measured limb and a reprojected marker of ``traj`` within :data:`LIMB_MATCH_PX` moves to
    ``xy + (limb_dist - rho) * limb_dir`` (at most :data:`LIMB_MAX_SHIFT_PX`); other blobs
    keep their centroid. On visible_office (seed 4, office ceiling lights) the centroids'
    mean offset from the true projections goes from (0.005, -0.305) to (0.03, -0.10) px and
    their RMS from 0.43 to 0.30 px (radius from the true depths).
    """
    F = traj.xyz.shape[0]
    out: list[list[Detections]] = []
    moved = 0
    for c, cam in enumerate(calibration):
        fx = float(cam.K[0, 0])
        row: list[Detections] = []
        for f in range(len(detections[c])):
            d = detections[c][f]
            dist = getattr(d, "limb_dist", None)
            if dist is None or len(d) == 0 or f >= F or not np.isfinite(dist).any():
                row.append(d)
                continue
            pts = traj.xyz[f]
            pts = pts[np.isfinite(pts).all(axis=1)]
            if len(pts) == 0:
                row.append(d)
                continue
            uv = cam.project(pts)
            z = cam.to_camera(pts)[:, 2]
            ok = np.isfinite(uv).all(axis=1) & (z > 0)
            uv, z = uv[ok], z[ok]
            if len(uv) == 0:
                row.append(d)
                continue
            gap = np.linalg.norm(d.xy[:, None, :] - uv[None, :, :], axis=2)
            near = np.argmin(gap, axis=1)
            rho = fx * marker_radius_m / z[near]
            shift = dist - rho
            use = (gap[np.arange(len(d)), near] <= LIMB_MATCH_PX) & np.isfinite(shift)
            shift = np.clip(np.where(use, shift, 0.0), -LIMB_MAX_SHIFT_PX, LIMB_MAX_SHIFT_PX)
            moved += int(use.sum())
            row.append(Detections(d.xy + shift[:, None] * d.limb_dir, d.area, d.intensity))
        out.append(row)
    return out, moved


def _labelled_tracks(detections: list[list[Detections]], calibration: Calibration, template: LabelTemplate,
                     times: np.ndarray, params: MarkerPipelineParams, rng: np.random.Generator, subject,
                     marker_model: ClusterMarkerModel | None, timings: dict[str, float],
                     solvers: dict) -> tuple[bool, Tracks2D, LabelInit]:
    """``(use_model, tracks, init)``: labels from the subject's model where it can run, else
    seed 000's T-pose first frame kept by 2D trackers (stage times into ``timings``)."""
    # Two cameras cannot confirm a pairing (every two-view point fits its epipolar line), so the
    # model path needs three or more; two-camera rigs use seed 000's scheme.
    if params.labelling == "model" and (subject is not None or marker_model is not None) and len(calibration) >= 3:
        labelled = _label_with_model(detections, calibration, template, params, subject, marker_model, timings, solvers)
        if labelled is not None:
            tracks, init = labelled
            return True, tracks, init
    t0 = time.perf_counter()
    init = initial_labels([d[0] for d in detections], calibration, template, params.label_init)
    timings["label_init"] = (time.perf_counter() - t0) * 1e3
    t0 = time.perf_counter()
    F = len(times)
    dt = float(np.median(np.diff(times))) if F > 1 else 1 / 30
    tracks = track_cameras(detections, init.xy, list(template.names), calibration.names, tracker=params.tracker,
                           dt=dt, rng=rng, **params.tracker_params)
    timings["tracking"] = (time.perf_counter() - t0) * 1e3
    return False, tracks, init


def _solver(subject, solvers: dict):
    """A :class:`~mocap.skeleton.SkeletonSolver` of ``subject``, kept in ``solvers`` (the capture's):
    the labeller's and the skeleton stage's share the MJCF (their markers are in other orders), so
    the second takes the first's cold-start grids, most of the cost of building one (3 ms a frame
    of the bench's 30)."""
    from mocap.skeleton import SkeletonSolver

    key = (subject.mjcf_text, tuple(subject.markers))  # markers compare by identity
    if key not in solvers:
        same = [v for k, v in solvers.items() if k[0] == subject.mjcf_text]
        solvers[key] = SkeletonSolver(subject, grids_from=same[0] if same else None)
    return solvers[key]


def _solve_skeleton(passes: CapturePasses, subject, params: MarkerPipelineParams, solvers: dict):
    """Fit the subject's skeleton to the trajectories; with re-association and
    ``model_guided``, let the fit guide two more passes, then check and fill the points
    against it (``passes`` is updated). Returns the fit."""
    solver = _solver(subject, solvers)
    if params.reassociation is None or not params.model_guided:
        return solver.solve(passes.traj)
    # The fits that guide the passes and judge the points keep hinges as solved; only the fit
    # returned interpolates the ones the markers leave undetermined (SkeletonSolver.solve's bridge).
    fit = solver.solve(passes.traj, bridge=False)
    _model_guided_passes(passes, solver, fit, params)
    return _check_against_model(passes, solver, subject, params)


def _model_guided_passes(passes: CapturePasses, solver, fit, params: MarkerPipelineParams) -> None:
    """Model-guided labelling: the fitted skeleton predicts every marker, also those the
    cameras' trackers lost; markers that disagree with the fit by more than
    ``model_outlier_mm`` are left out of a second fit first. One pass re-associates with the
    model's markers, one more with the trajectories it gave."""
    fit = solver.solve(_drop_outliers(passes.traj, fit, params.model_outlier_mm), bridge=False)
    predicted = model_markers(solver, fit, passes.traj.labels)
    gate = np.full(predicted.shape[:2], params.model_gate_px)
    passes.run(points=predicted, gate_px=gate, prefix="model_", jumps=False)
    passes.run(jumps=False)


def _measured_only(traj: Trajectories) -> Trajectories:
    """``traj`` without its filled points (NaN there, nothing marked filled)."""
    return Trajectories(list(traj.labels), np.where(traj.filled[..., None], np.nan, traj.xyz),
                        traj.times, np.zeros_like(traj.filled), traj.residual_px, traj.n_views)


def _check_against_model(passes: CapturePasses, solver, subject, params: MarkerPipelineParams):
    """Refit, remove the points the fitted skeleton cannot explain (mislabelled or ghosts:
    :func:`mocap.model_check.robust_skeleton_fit`), and fill gaps from the skeleton fitted to
    the measured points only: in fast motion a spline across a gap is centimetres off, the
    model driven by the segment's other markers is not. Returns the last fit.

    A marker alone on its body is placed by its own point wherever the limb reaches, so the
    check explains a wrong one; its points no limb could have moved to go first
    (:mod:`mocap.motion_check`)."""
    traj = passes.traj
    if params.max_marker_speed_mps > 0:
        veto = motion_outliers(traj, lone_markers(subject, list(traj.labels)), params.max_marker_speed_mps)
        passes.stats["motion_vetoed"] = int(veto.sum())
        if veto.any():
            recon = params.reconstruction
            method = recon.gap_fill if recon.gap_fill != "auto" else ("cubic" if recon.smoothing != "none" else "lsq")
            traj = without_motion_outliers(traj, veto, recon.max_gap_frames, method, recon.gap_context_frames)
    fit, traj = robust_skeleton_fit(traj, solver, params.model_outlier_mm, params.model_check_rounds,
                                    params.model_check_max_drops, params.model_check_grow_rounds)
    limits = view_limits_mm(params.model_outlier_mm)
    added = 0
    for r in range(params.free_blob_fill_rounds):
        if r:
            fit = solver.solve(_measured_only(traj), bridge=False)
        # Each round's fit, with the markers the last one added, predicts a limb's others better,
        # but follows its own mistakes too: on blur_zigzag's streaks a third round took a wrist
        # point 36 mm off (rounds 1 / 2 / 3: 4-camera walk 0.965 / 0.967 / 0.967 reconstructed,
        # blur_zigzag 1.63 / 1.65 / 1.86 mm, largest error 23 / 23 / 36 mm), so one by default.
        traj, xy, n = fill_from_free_blobs(traj, passes.measured.xy, passes.detections, passes.calibration,
                                           model_markers(solver, fit, traj.labels), limits,
                                           params.free_blob_gate_px, params.reconstruction.max_residual_px)
        passes.measured = replace(passes.measured, xy=xy)
        added += n
        if n == 0:
            break
    passes.stats["free_blob_fill"] = added
    if params.limb_fill:
        traj, n_limb, n_free = _fill_limbs(passes, solver, traj, limits, params)
        passes.stats["limb_fill"] = n_limb
        passes.stats["free_blob_fill"] += n_free
    measured_only = _measured_only(traj)
    fit = solver.solve(measured_only)
    body_of = {m.name: m.body for m in subject.markers}
    passes.traj = _fill_from_model(measured_only, model_markers(solver, fit, traj.labels),
                                   params.reconstruction, [body_of.get(n, "") for n in traj.labels],
                                   _constrained(solver, fit, traj.labels, params.model_fill_max_spread_mm))
    passes.stats["missing_after_model_check"] = int(np.isnan(passes.traj.xyz[..., 0]).sum())
    return fit


def _fill_limbs(passes: CapturePasses, solver, traj: Trajectories, limits: tuple[float, float],
                params: MarkerPipelineParams) -> tuple[Trajectories, int, int]:
    """Refit, fit the limbs the model misplaces to the free blobs
    (:func:`mocap.limb_fill.fill_limbs_from_free_blobs`), and, where that added points, refit and
    fill from the free blobs once more (the limbs placed predict their other markers better: on
    the CMU walk seen by 4 cameras 4 more points). Returns ``(traj, limb points, free-blob points)``."""
    fit = solver.solve(_measured_only(traj), bridge=False)
    traj, xy, n_limb = fill_limbs_from_free_blobs(traj, passes.measured.xy, passes.detections, passes.calibration,
                                                  solver, fit, limits, params.correspondence)
    passes.measured = replace(passes.measured, xy=xy)
    if n_limb == 0:
        return traj, 0, 0
    fit = solver.solve(_measured_only(traj), bridge=False)
    traj, xy, n_free = fill_from_free_blobs(traj, passes.measured.xy, passes.detections, passes.calibration,
                                            model_markers(solver, fit, traj.labels), limits,
                                            params.free_blob_gate_px, params.reconstruction.max_residual_px)
    passes.measured = replace(passes.measured, xy=xy)
    return traj, n_limb, n_free


def capture_unsynchronised(
    detections: list[list[Detections]],
    timestamps: list[np.ndarray],
    calibration: Calibration,
    template: LabelTemplate,
    params: MarkerPipelineParams | None = None,
    rng: np.random.Generator | None = None,
    subject=None,
    detection_ms: float = 0.0,
    marker_model: ClusterMarkerModel | None = None,
    reference: int = 0,
    sync_params: SyncParams | None = None,
) -> tuple[MarkerCapture, ClockSync]:
    """The pipeline on cameras with their own clocks (webcams without hardware sync).

    Each camera's offset and drift relative to camera ``reference`` are estimated from the
    markers' motion (:func:`mocap.synchronisation.estimate_sync`); every camera's blobs are
    interpolated to the reference camera's frame instants
    (:func:`mocap.synchronisation.resample_detections`), and :func:`capture_from_detections`
    runs on them with the reference camera's timestamps as the frame times.

    Parameters
    ----------
    detections : C lists of F_c Detections (each camera its own frame count)
    timestamps : C arrays ``(F_c,)`` s from each camera's own clock, strictly increasing
    """
    t0 = time.perf_counter()
    sync = estimate_sync(detections, timestamps, calibration, reference, sync_params)
    resampled = resample_detections(detections, timestamps, sync,
                                    (sync_params or SyncParams()).link_gate_px)
    sync_ms = (time.perf_counter() - t0) * 1e3
    capture = capture_from_detections(resampled, calibration, template, np.asarray(timestamps[reference], float), params,
                                      rng, subject, detection_ms, marker_model)
    capture.timings_ms["synchronisation"] = sync_ms
    return capture, sync


def _label_with_model(detections: list[list[Detections]], calibration: Calibration, template: LabelTemplate,
                      params: MarkerPipelineParams, subject, marker_model: ClusterMarkerModel | None,
                      timings: dict[str, float], solvers: dict) -> tuple[Tracks2D, LabelInit] | None:
    """Unlabelled 3D points of every frame, labelled by the subject's skeleton (or the marker
    model), as labelled 2D measurements; None when the model finds no confident fit anywhere,
    so that the caller falls back to seed 000's scheme rather than return nothing."""
    F = len(detections[0])
    t0 = time.perf_counter()
    frames = [reconstruct_unlabelled([d[f] for d in detections], calibration, params.correspondence) for f in range(F)]
    timings["correspondence"] = (time.perf_counter() - t0) * 1e3
    t0 = time.perf_counter()
    if subject is not None:
        model = SkeletonMarkerModel(_solver(subject.with_markers([n for n in template.names if n in subject.marker_names]), solvers))
    else:
        model = marker_model
    labels = label_points(frames, model, params.model_labelling)
    # The start search runs once per take: kept apart so that per-frame figures are per frame.
    timings["label_start"] = labels.start_search_ms
    timings["labelling"] = (time.perf_counter() - t0) * 1e3 - labels.start_search_ms
    if (labels.point_index >= 0).sum() < 3 * F:
        return None
    timings["label_init"] = 0.0
    timings["tracking"] = 0.0
    return _tracks_from_point_labels(labels, frames, detections, list(template.names), calibration)


def _tracks_from_point_labels(labels: PointLabels, frames: list[UnlabelledPoints], detections: list[list[Detections]],
                              names: list[str], calibration: Calibration) -> tuple[Tracks2D, LabelInit]:
    """Labelled 3D points back to labelled 2D measurements ``(F, C, M, 2)``: each labelled point
    hands its label to the detections it was triangulated from."""
    F, C, M = len(frames), len(calibration), len(names)
    col = {n: i for i, n in enumerate(labels.labels)}
    xy = np.full((F, C, M, 2), np.nan)
    for f, fr in enumerate(frames):
        for m, n in enumerate(names):
            k = col.get(n, -1)
            i = labels.point_index[f, k] if k >= 0 else -1
            if i < 0:
                continue
            for c in range(C):
                j = fr.detection_index[i, c]
                if j >= 0:
                    xy[f, c, m] = detections[c][f].xy[j]
    status = np.where(np.isfinite(xy[..., 0]), Tracks2D.TRACKED, 0).astype(np.int8)
    tracks = Tracks2D(list(names), xy, xy.copy(), status, list(calibration.names))
    s0 = labels.start_frame
    index = np.full((C, M), -1)
    points = np.full((M, 3), np.nan)
    for m, n in enumerate(names):
        k = col.get(n, -1)
        i = labels.point_index[s0, k] if k >= 0 else -1
        if i >= 0:
            index[:, m] = frames[s0].detection_index[i]
            points[m] = frames[s0].xyz[i]
    init = LabelInit(list(names), index, xy[s0].copy(), Placement(0.0, 0.0, 0.0), points, float("nan"))
    return tracks, init


def _drop_outliers(traj: Trajectories, fit, max_mm: float) -> Trajectories:
    """Trajectories without the points that disagree with a skeleton fit by more than the
    model check's limit (``max_mm``, half of it for two-view points:
    :func:`mocap.model_check.error_limit_mm`)."""
    idx = [fit.marker_labels.index(n) if n in fit.marker_labels else -1 for n in traj.labels]
    err = np.full(traj.xyz.shape[:2], np.nan)
    for j, i in enumerate(idx):
        if i >= 0:
            err[:, j] = fit.marker_errors_mm[:, i]
    return without_points(traj, np.nan_to_num(err, nan=0.0) > error_limit_mm(traj, max_mm))


SPLINE_ONLY_MAX_GAP = 0
MODEL_SPLINE_AGREE_M = 0.03


def _constrained(solver, fit, labels: list[str], max_spread_mm: float) -> np.ndarray:
    """``(F, M)`` bool: frames where the measured markers determine a marker's model position,
    within ``max_spread_mm`` for 1 mm marker noise (:meth:`mocap.skeleton.SkeletonSolver.marker_spread_m`).

    The marker's position, not each hinge on its way from the root: the lumbar and thorax hinges
    turn about the same axes and the markers fix only their sum, so each alone stayed over a 2 deg
    limit on most frames (13.5 deg) and no arm or head marker was ever filled (on the CMU walk seen
    by 4 cameras 35 of the 116 points left missing failed this test alone, the model within 1 mm of
    the truth at most of them). Filling them costs blur_zigzag's streaks RMSE: 43 points at 2.5 mm
    (1.63 -> 1.66 mm, reconstructed 0.957 -> 0.968)."""
    out = np.zeros((len(fit.q), len(labels)), bool)
    cols = np.array([solver.marker_labels.index(n) if n in solver.marker_labels else -1 for n in labels])
    known = cols >= 0
    for f in np.flatnonzero(np.isfinite(fit.q).all(axis=1)):
        ok = np.isfinite(fit.marker_errors_mm[f])
        spread_mm = 1e3 * solver.measured_spread_m(fit.q[f], ok)
        out[f, known] = spread_mm[cols[known]] < max_spread_mm
    return out


def _fill_from_model(traj: Trajectories, predicted: np.ndarray, recon: ReconstructionParams,
                     bodies: list[str], constrained: np.ndarray | None = None) -> Trajectories:
    """Fill gaps of up to ``max_gap_frames`` with the fitted model's marker ``(F, M, 3)`` where
    another marker on the same body was measured in that frame (the model is pinned there),
    the hinges leading to it are determined (``constrained (F, M)``), and the model agrees
    with a spline across the gap within ``MODEL_SPLINE_AGREE_M``. Nowhere else: on real motion
    at 30 Hz a spline over even two or three frames of a hand or a heel strike was 3-10 cm off
    (CMU 131_01), and a gap is better than a wrong point (``SPLINE_ONLY_MAX_GAP`` frames may be
    filled by the spline alone; 0)."""
    from mocap.smoothing import fill_gaps

    if recon.max_gap_frames <= 0:
        return traj
    measured = np.isfinite(traj.xyz).all(axis=2)
    method = "cubic" if recon.smoothing != "none" else "lsq"
    xyz, filled = fill_gaps(traj.xyz, traj.times, recon.max_gap_frames, method, recon.gap_context_frames)
    _, short = fill_gaps(traj.xyz, traj.times, min(SPLINE_ONLY_MAX_GAP, recon.max_gap_frames), method,
                         recon.gap_context_frames)
    body_ids = {b: i for i, b in enumerate(dict.fromkeys(bodies))}
    bid = np.array([body_ids[b] for b in bodies])
    for m in range(xyz.shape[1]):
        same_body = (bid == bid[m]) & (np.arange(len(bid)) != m)
        pinned = measured[:, same_body].any(axis=1) if same_body.any() else np.zeros(len(xyz), bool)
        use = filled[:, m] & pinned & np.isfinite(predicted[:, m]).all(axis=1)
        if constrained is not None:
            use &= constrained[:, m]
        # The model and the spline across the gap must roughly agree: where they are far
        # apart one of them is wrong (a wrongly fitted limb, or motion no spline follows), and a
        # gap is better than a wrong point.
        use &= np.linalg.norm(np.nan_to_num(predicted[:, m] - xyz[:, m], nan=np.inf), axis=1) < MODEL_SPLINE_AGREE_M
        xyz[use, m] = predicted[use, m]
        drop = filled[:, m] & ~use & ~short[:, m]
        xyz[drop, m] = np.nan
        filled[drop, m] = False
    return Trajectories(list(traj.labels), xyz, traj.times, filled, traj.residual_px, traj.n_views)


def export_capture(capture: MarkerCapture, out_dir: str | Path, calibration: Calibration, subject=None) -> dict[str, Path]:
    """Write C3D, TRC, CSV (markers), BVH (skeleton) and the calibration (OpenCV YAML)."""
    from mocap.exports import write_bvh, write_c3d, write_csv, write_trc

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = {
        "c3d": write_c3d(out / "markers.c3d", capture.trajectories),
        "trc": write_trc(out / "markers.trc", capture.trajectories),
        "csv": write_csv(out / "markers.csv", capture.trajectories),
    }
    calibration.save_opencv_yaml(out / "calibration.yml")
    paths["calibration"] = out / "calibration.yml"
    if capture.skeleton is not None and subject is not None:
        paths["bvh"] = write_bvh(out / "skeleton.bvh", capture.skeleton, subject)
    return paths
