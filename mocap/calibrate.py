"""``mocap calibrate``: images or videos of a board (and optionally a wand) in, calibration out.

Pipeline (each step in :mod:`mocap.calib`):

1. find the board in every image / video frame of every camera (:mod:`mocap.calib.views`
   reads them, :func:`mocap.calib.board_detection.detect_board`), keeping why each failed;
2. per camera, Zhang's method (:func:`mocap.calib.intrinsics.calibrate_intrinsics`),
   after checking the views are not all parallel, dropping outlier views;
3. extrinsics from views that cameras share, chained over a maximum spanning tree of
   the camera graph (:mod:`mocap.calib.extrinsics`) -- or, without shared board views,
   from a wand (:mod:`mocap.calib.wand`);
4. bundle adjustment of all cameras, board poses and wand points together
   (:mod:`mocap.calib.bundle_adjustment`);
5. world frame from a board lying on the floor, or a camera
   (:mod:`mocap.calib.world_frame`);
6. write OpenCV YAML and anipose-style TOML.

Views are synchronised by index: the ``i``-th image of every camera (or frame ``i`` of
every video) must be the same moment.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping, Sequence

import cv2
import numpy as np

from mocap.calib.board_detection import BoardDetection, DetectionSettings
from mocap.calib.boards import BoardSpec
from mocap.calib.bundle_adjustment import BundleAdjustmentOptions, bundle_adjust
from mocap.calib.errors import BoardNotFoundError, CalibrationError, DisconnectedCamerasError, ViewFailure
from mocap.calib.extrinsics import board_poses_pnp, initial_rig
from mocap.calib.geometry import intrinsics_from_vector, intrinsics_vector
from mocap.calib.intrinsics import IntrinsicsOptions, calibrate_intrinsics
from mocap.calib.observations import BoardObservations, WandObservations
from mocap.calib.views import IMAGE_SUFFIXES, VIDEO_SUFFIXES, ViewSource, detect_board_views, iter_views
from mocap.calib.wand import WandSpec, label_collinear_wand, triangulate_wand, wand_initial_rig
from mocap.calib.world_frame import camera_transform, floor_transform, transform_cameras, transform_points, transform_poses
from mocap.atomic_files import atomic_write_text, check_output_file
from mocap.calibration import Calibration, Camera
from mocap.errors import InputFileError

__all__ = [
    "CalibrationResult", "calibrate_from_observations", "calibrate_cameras", "write_calibration", "run_calibrate_cli",
    # reading the views, public here too (mocap.calib.views)
    "ViewSource", "IMAGE_SUFFIXES", "VIDEO_SUFFIXES", "iter_views", "detect_board_views",
]


@dataclass
class CalibrationResult:
    """What :func:`calibrate_cameras` found.

    Attributes
    ----------
    calibration : Calibration
        The rig, in the chosen world frame.
    reprojection_rms_px : dict[str, float]
        Final reprojection RMS per camera (after bundle adjustment; Zhang's for a single
        camera).
    intrinsics_rms_px : dict[str, float]
        Zhang's per-camera RMS (NaN for cameras with given intrinsics).
    view_rms_px : dict[str, ndarray (V,)]
        Final RMS per view (NaN where the view was not used).
    views_used : dict[str, list[str]]
    views_rejected : dict[str, dict[str, str]]
        Per camera: view label -> why it was not used.
    board_poses_world : (V, 4, 4) float
        World-from-board transform of each view (NaN where unknown), metres.
    wand_points_world : (F, 3, 3) float or None
        Wand markers per frame, metres.
    wand_distance_rms_mm : float or None
        RMS of (estimated - known) wand distances.
    world_frame : str
        How the world frame was chosen.
    bundle_adjustment : dict
        ``cost``, ``initial_cost``, ``evaluations``, ``status``, ``message``.
    written : list[Path]
        Files written.
    """

    calibration: Calibration
    reprojection_rms_px: dict[str, float]
    intrinsics_rms_px: dict[str, float]
    view_rms_px: dict[str, np.ndarray]
    views_used: dict[str, list[str]]
    views_rejected: dict[str, dict[str, str]]
    board_poses_world: np.ndarray
    wand_points_world: np.ndarray | None = None
    wand_distance_rms_mm: float | None = None
    world_frame: str = ""
    bundle_adjustment: dict = field(default_factory=dict)
    written: list[Path] = field(default_factory=list)

    def summary(self) -> str:
        """A per-camera table for the terminal."""
        lines = [f"{'camera':<16}{'fx':>9}{'fy':>9}{'cx':>8}{'cy':>8}{'views':>7}{'Zhang px':>10}{'final px':>10}"]
        for cam in self.calibration:
            n = cam.name
            lines.append(f"{n:<16}{cam.K[0, 0]:9.1f}{cam.K[1, 1]:9.1f}{cam.K[0, 2]:8.1f}{cam.K[1, 2]:8.1f}"
                         f"{len(self.views_used.get(n, [])):7d}{self.intrinsics_rms_px.get(n, np.nan):10.3f}"
                         f"{self.reprojection_rms_px.get(n, np.nan):10.3f}")
        if self.wand_distance_rms_mm is not None:
            lines.append(f"wand distance RMS {self.wand_distance_rms_mm:.2f} mm")
        lines.append(f"world frame: {self.world_frame}")
        for n, rej in self.views_rejected.items():
            if rej:
                lines.append(f"{n}: {len(rej)} views not used")
        return "\n".join(lines)

    def to_dict(self) -> dict:
        """JSON-ready numbers (no arrays of views)."""
        return {
            "cameras": self.calibration.names,
            "reprojection_rms_px": {k: float(v) for k, v in self.reprojection_rms_px.items()},
            "intrinsics_rms_px": {k: float(v) for k, v in self.intrinsics_rms_px.items()},
            "views_used": {k: len(v) for k, v in self.views_used.items()},
            "views_rejected": self.views_rejected,
            "wand_distance_rms_mm": self.wand_distance_rms_mm,
            "world_frame": self.world_frame,
            "bundle_adjustment": self.bundle_adjustment,
            "written": [str(p) for p in self.written],
        }


# ---------------------------------------------------------------------- calibration
def _resolve_view(floor_view: int | str, obs: BoardObservations) -> int:
    if isinstance(floor_view, (int, np.integer)):
        if not 0 <= int(floor_view) < obs.n_views:
            raise CalibrationError(f"floor view {floor_view} is out of range: there are {obs.n_views} views (0..{obs.n_views - 1})")
        return int(floor_view)
    for labs in obs.view_labels:
        for v, lab in enumerate(labs):
            if lab == floor_view or Path(lab).name == Path(str(floor_view)).name:
                return v
    raise CalibrationError(f"floor view {floor_view!r} is not one of the views; give its index or its file name "
                           f"(e.g. {obs.view_labels[0][0]!r})")


def _detection_rejections(obs: BoardObservations, usable: np.ndarray,
                          detections: Mapping[str, Sequence[BoardDetection]] | None) -> dict[str, dict[str, str]]:
    """Per camera: label -> why the view has no usable board."""
    rejected: dict[str, dict[str, str]] = {n: {} for n in obs.camera_names}
    for c, n in enumerate(obs.camera_names):
        dl = detections.get(n) if detections is not None else None
        for v in np.flatnonzero(~usable[c]):
            if dl is not None and not dl[v].found:
                rejected[n][obs.view_labels[c][v]] = f"{dl[v].problem}: {dl[v].detail}"
            else:
                rejected[n][obs.view_labels[c][v]] = f"board not found ({int(obs.seen[c, v].sum())} corners)"
    return rejected


def _intrinsics_per_camera(obs: BoardObservations, usable: np.ndarray, iopt: IntrinsicsOptions,
                           known: Calibration | None, detections: Mapping[str, Sequence[BoardDetection]] | None,
                           rejected: dict[str, dict[str, str]]):
    """Zhang per camera (or the known intrinsics).

    Returns ``intr (C, 9)``, ``k3_free (C,)``, ``zhang_rms {name: px}`` and ``use (C, V)``
    (views kept); ``rejected`` gains the outlier views.
    """
    C = obs.n_cameras
    intr = np.zeros((C, 9))
    k3_free = np.zeros(C, dtype=bool)
    zhang_rms: dict[str, float] = {}
    use = usable.copy()
    for c, n in enumerate(obs.camera_names):
        if known is not None and n in known.names:
            cam = known[n]
            intr[c] = intrinsics_vector(cam.K, cam.dist)
            k3_free[c] = bool(cam.dist[4] != 0)
            zhang_rms[n] = float("nan")
            continue
        if usable[c].sum() < iopt.min_views:
            dl = detections.get(n) if detections is not None else None
            failures = []
            for v in np.flatnonzero(~usable[c]):
                if dl is not None and not dl[v].found:
                    failures.append(ViewFailure(obs.view_labels[c][v], dl[v].problem, dl[v].detail, dl[v].fix))
                else:
                    failures.append(ViewFailure(obs.view_labels[c][v], "not found",
                                                f"{int(obs.seen[c, v].sum())} of {obs.board.n_corners} corners seen"))
            raise BoardNotFoundError(n, int(usable[c].sum()), obs.n_views, iopt.min_views, failures, obs.board.describe())
        res = calibrate_intrinsics(obs.corners_px[c], obs.object_points, obs.image_sizes[c], n, iopt,
                                   obs.view_labels[c], obs.board.kind == "checkerboard")
        intr[c] = intrinsics_vector(res.K, res.dist)
        k3_free[c] = res.k3_free
        zhang_rms[n] = res.rms_px
        use[c] &= res.used
        for v, why in res.rejected.items():
            rejected[n][obs.view_labels[c][v]] = why
    return intr, k3_free, zhang_rms, use


def _initial_extrinsics(poses, names: list[str], ref: int, intr: np.ndarray, wand: WandSpec | None,
                        wand_px: np.ndarray | None):
    """First guess of ``R_cw, t_cw (C, ...)`` and ``R_wb, t_wb (V, ...)`` in the reference camera's frame.

    Board views shared between cameras first; if they leave cameras unconnected, the
    wand (when given) places the cameras and each board view is placed by a camera that
    saw it.
    """
    C, V = poses.valid.shape
    if C == 1:
        ok = poses.valid[0]
        return (np.eye(3)[None], np.zeros((1, 3)),
                np.where(ok[:, None, None], poses.R[0], np.nan), np.where(ok[:, None], poses.t[0], np.nan))
    try:
        rig = initial_rig(poses, names, ref)
        return rig.R_cw, rig.t_cw, rig.R_wb, rig.t_wb
    except DisconnectedCamerasError:
        if wand_px is None:
            raise
    R_cw, t_cw, _ = wand_initial_rig(intr, wand_px, wand, names, ref)
    R_wb = np.full((V, 3, 3), np.nan)
    t_wb = np.full((V, 3), np.nan)
    for v in range(V):
        cams = np.flatnonzero(poses.valid[:, v])
        if len(cams):
            c0 = cams[0]
            R_wb[v] = R_cw[c0].T @ poses.R[c0, v]
            t_wb[v] = R_cw[c0].T @ (poses.t[c0, v] - t_cw[c0])
    return R_cw, t_cw, R_wb, t_wb


def _single_camera_view_rms(obs: BoardObservations, poses, intr: np.ndarray, use: np.ndarray) -> np.ndarray:
    """Per-view reprojection RMS ``(V,)`` of a lone camera at its PnP board poses."""
    out = np.full(obs.n_views, np.nan)
    K, d = intrinsics_from_vector(intr)
    for v in np.flatnonzero(use):
        ok = np.isfinite(obs.corners_px[0, v]).all(axis=1)
        proj, _ = cv2.projectPoints(obs.object_points[ok], cv2.Rodrigues(poses.R[0, v])[0], poses.t[0, v], K, d)
        out[v] = np.sqrt(np.mean(np.sum((proj.reshape(-1, 2) - obs.corners_px[0, v, ok]) ** 2, axis=1)))
    return out


def calibrate_from_observations(observations: BoardObservations, *, wand: WandSpec | None = None,
                                wand_observations: WandObservations | None = None,
                                known_intrinsics: Calibration | None = None,
                                reference_camera: str | None = None,
                                floor_view: int | str | None = None,
                                world_camera: str | None = None,
                                intrinsics_options: IntrinsicsOptions | None = None,
                                ba_options: BundleAdjustmentOptions | None = None,
                                detections: Mapping[str, Sequence[BoardDetection]] | None = None) -> CalibrationResult:
    """Calibrate a rig from detected board corners (and optionally wand markers).

    Parameters
    ----------
    observations : BoardObservations
        Board corners ``(C, V, N, 2)`` per camera and synchronised view.
    wand, wand_observations : WandSpec, WandObservations, optional
        A wand and its labelled markers ``(C, F, 3, 2)`` per camera and frame.
    known_intrinsics : Calibration, optional
        Cameras (by name) whose K and distortion are already known: Zhang's step is
        skipped for them (bundle adjustment still refines them if enabled).
    reference_camera : str, optional
        Camera fixed during bundle adjustment (default: the first).
    floor_view : int or str, optional
        Index or file name of a view in which the board lies on the floor: it defines
        the world (origin at the board origin, z up).
    world_camera : str, optional
        Without ``floor_view``: the camera whose frame is the world (default: reference).
    intrinsics_options : IntrinsicsOptions, optional
        Zhang's step per camera (default: ``IntrinsicsOptions()``).
    ba_options : BundleAdjustmentOptions, optional
        The bundle adjustment (default: ``BundleAdjustmentOptions()`` with the intrinsics
        options' ``fix_aspect_ratio``, ``fix_principal_point`` and ``zero_tangent``).
    detections : mapping, optional
        Per camera, the :class:`BoardDetection` of each view, to explain failures.
    """
    obs = observations
    iopt = intrinsics_options if intrinsics_options is not None else IntrinsicsOptions()
    bopt = ba_options if ba_options is not None else BundleAdjustmentOptions(
        fix_aspect_ratio=iopt.fix_aspect_ratio, fix_principal_point=iopt.fix_principal_point, zero_tangent=iopt.zero_tangent)
    names = obs.camera_names
    ref, floor_index, wand_px = _check_setup(obs, wand, wand_observations, reference_camera, floor_view, world_camera)
    usable = obs.usable(iopt.min_corners)
    rejected = _detection_rejections(obs, usable, detections)

    # 1. intrinsics -------------------------------------------------------------
    intr, k3_free, zhang_rms, use = _intrinsics_per_camera(obs, usable, iopt, known_intrinsics, detections, rejected)
    Ks = np.stack([intrinsics_from_vector(p)[0] for p in intr])
    dists = np.stack([intrinsics_from_vector(p)[1] for p in intr])
    poses = board_poses_pnp(obs.corners_px, obs.object_points, Ks, dists, use)
    use &= poses.valid

    # 2. extrinsics ----------------------------------------------------------------
    R_cw, t_cw, R_wb, t_wb = _initial_extrinsics(poses, names, ref, intr, wand, wand_px)

    # 3. bundle adjustment -----------------------------------------------------------
    rig = _Rig(intr, R_cw, t_cw, R_wb, t_wb, final_rms=dict(zhang_rms))
    if obs.n_cameras > 1 or wand_px is not None:
        rig = _refine(obs, rig, ref, k3_free, use, wand, wand_px, bopt)
    else:
        rig.view_rms = {names[0]: _single_camera_view_rms(obs, poses, intr[0], use[0])}

    # 4. world frame ---------------------------------------------------------------
    world = _to_world_frame(obs, rig, floor_index, world_camera, ref)
    return CalibrationResult(
        calibration=Calibration(tuple(Camera(n, obs.image_sizes[c], *intrinsics_from_vector(rig.intr[c]), rig.R_cw[c], rig.t_cw[c])
                                      for c, n in enumerate(names))),
        reprojection_rms_px=rig.final_rms,
        intrinsics_rms_px=zhang_rms,
        view_rms_px=rig.view_rms if rig.view_rms is not None else {n: np.full(obs.n_views, np.nan) for n in names},
        views_used={n: [obs.view_labels[c][v] for v in np.flatnonzero(use[c])] for c, n in enumerate(names)},
        views_rejected=rejected,
        board_poses_world=_homogeneous(rig.R_wb, rig.t_wb),
        wand_points_world=rig.wand_pts,
        wand_distance_rms_mm=rig.wand_rms_mm,
        world_frame=world,
        bundle_adjustment=rig.ba_info,
    )


def _check_setup(obs: BoardObservations, wand: WandSpec | None, wand_observations: WandObservations | None,
                 reference_camera: str | None, floor_view: int | str | None,
                 world_camera: str | None) -> tuple[int, int | None, np.ndarray | None]:
    """Refuse what cannot work before any work; the indices the calibration needs.

    Returns
    -------
    ref : int
        Index of the reference camera (default 0).
    floor_index : int or None
        View index of ``floor_view``.
    wand_px : (C, F, 3, 2) float or None
        The wand's markers in ``obs``' camera order, pixels.
    """
    if obs.n_cameras > 1 and not obs.board.orientation_unique:
        w, h = obs.board.squares
        raise CalibrationError(
            f"the {obs.board.describe()} has {w}x{h} squares and looks the same turned by 180 deg, so cameras may "
            f"number its corners differently; for several cameras use a checkerboard with an even number of squares "
            f"along one side and an odd number along the other (e.g. 9x6 inner corners = 10x7 squares) or a ChArUco board")
    ref = obs.camera_index(reference_camera) if reference_camera is not None else 0
    floor_index = _resolve_view(floor_view, obs) if floor_view is not None else None  # fail before the work
    if world_camera is not None:
        obs.camera_index(world_camera)
    wand_px = None
    if wand is not None and wand_observations is not None:
        wand_px = wand_observations.reordered(obs.camera_names).markers_px
    elif (wand is None) != (wand_observations is None):
        raise CalibrationError("wand refinement needs both the wand's distances (WandSpec / --wand-distances-mm) and its "
                               "2D marker observations (--wand-file)")
    return ref, floor_index, wand_px


@dataclass
class _Rig:
    """The rig as the calibration's steps refine it (reference camera's frame until the world frame is set).

    ``intr (C, 9)`` intrinsics vectors; ``R_cw (C, 3, 3)``, ``t_cw (C, 3)`` metres camera from
    world; ``R_wb (V, 3, 3)``, ``t_wb (V, 3)`` world from board (NaN where unknown);
    ``final_rms`` px per camera; ``view_rms`` per camera ``(V,)`` px (None: not computed);
    ``wand_pts (F, 3, 3)`` metres; ``wand_rms_mm``; ``ba_info`` the bundle adjustment's figures.
    """

    intr: np.ndarray
    R_cw: np.ndarray
    t_cw: np.ndarray
    R_wb: np.ndarray
    t_wb: np.ndarray
    final_rms: dict[str, float]
    view_rms: dict[str, np.ndarray] | None = None
    wand_pts: np.ndarray | None = None
    wand_rms_mm: float | None = None
    ba_info: dict = field(default_factory=dict)


def _refine(obs: BoardObservations, rig: _Rig, ref: int, k3_free: np.ndarray, use: np.ndarray, wand: WandSpec | None,
            wand_px: np.ndarray | None, bopt: BundleAdjustmentOptions) -> _Rig:
    """Bundle adjustment of cameras, board poses (views ``use (C, V)``) and wand points together.

    ``wand_px (C, F, 3, 2)`` pixels (or None). Returns the refined :class:`_Rig` with its final
    per-camera and per-view RMS (px), wand points (m) and wand distance RMS (mm).
    """
    names = obs.camera_names
    wand_pts = triangulate_wand(rig.intr, rig.R_cw, rig.t_cw, wand_px) if wand_px is not None else None
    ba = bundle_adjust(rig.intr, rig.R_cw, rig.t_cw, camera_names=names, reference=ref, k3_free=k3_free,
                       board_corners_px=obs.corners_px, object_points=obs.object_points, board_use=use, R_wb=rig.R_wb,
                       t_wb=rig.t_wb, wand_px=wand_px, wand_points=wand_pts,
                       wand_distances_m=None if wand is None else wand.distances, options=bopt)
    wand_rms_mm = None
    if wand_px is not None:
        wand_pts = ba.wand_points
        err = ba.wand_distance_error_m[np.isfinite(ba.wand_distance_error_m)]
        wand_rms_mm = float(np.sqrt(np.mean(err ** 2)) * 1000) if err.size else None
    return _Rig(ba.intrinsics, ba.R_cw, ba.t_cw, ba.R_wb, ba.t_wb,
                final_rms={n: float(ba.rms_px[c]) for c, n in enumerate(names)},
                view_rms={n: ba.view_rms_px[c] for c, n in enumerate(names)},
                wand_pts=wand_pts, wand_rms_mm=wand_rms_mm,
                ba_info=dict(cost=ba.cost, initial_cost=ba.initial_cost, evaluations=ba.evaluations, status=ba.status,
                             message=ba.message, n_parameters=ba.n_parameters, n_residuals=ba.n_residuals))


def _to_world_frame(obs: BoardObservations, rig: _Rig, floor_index: int | None, world_camera: str | None, ref: int) -> str:
    """Move ``rig``'s cameras, board poses and wand points (in place) into the world frame; say which frame.

    The world is the board lying on the floor in view ``floor_index`` (origin at the board
    origin, z up), else the frame of ``world_camera`` (default: the reference camera ``ref``).
    """
    if floor_index is not None:
        v = floor_index
        if not np.isfinite(rig.t_wb[v]).all():
            raise CalibrationError(f"floor view {obs.view_labels[0][v]!r} (index {v}): no camera saw enough of the board in "
                                   f"it; take a picture of the board lying on the floor that at least one camera sees "
                                   f"entirely")
        R_a, t_a = floor_transform(rig.R_wb[v], rig.t_wb[v])
        world = f"floor board in view {v} ({obs.view_labels[0][v]}): origin at the board origin, x along its rows, z up"
    else:
        wc = obs.camera_index(world_camera) if world_camera is not None else ref
        R_a, t_a = camera_transform(rig.R_cw[wc], rig.t_cw[wc])
        world = f"camera {obs.camera_names[wc]!r} frame (x right, y down, z forward)"
    rig.R_cw, rig.t_cw = transform_cameras(rig.R_cw, rig.t_cw, R_a, t_a)
    rig.R_wb, rig.t_wb = transform_poses(rig.R_wb, rig.t_wb, R_a, t_a)
    if rig.wand_pts is not None:
        rig.wand_pts = transform_points(rig.wand_pts, R_a, t_a)
    return world


def _homogeneous(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """``(V, 4, 4)`` transforms from ``R (V, 3, 3)`` and ``t (V, 3)`` (NaN rows stay NaN)."""
    out = np.full((len(R), 4, 4), np.nan)
    out[:, :3, :3] = R
    out[:, :3, 3] = t
    out[:, 3] = [0, 0, 0, 1]
    return out


def calibration_paths(out: str | os.PathLike) -> tuple[Path, Path, Path]:
    """The ``<out>.toml`` (anipose), ``<out>.yml`` (OpenCV) and ``<out>.report.json`` of output stem ``out``."""
    out = Path(out)
    stem = out.with_suffix("") if out.suffix.lower() in (".toml", ".yml", ".yaml", ".json") else out
    return stem.with_suffix(".toml"), stem.with_suffix(".yml"), stem.with_name(stem.name + ".report.json")


# what each file of write_calibration holds (a rerun replaces its own files, never others)
_OWN_MARKS = (b'convention = "x_cam = R(rotation) @ x_world + translation"', b"camera_count:", b'"reprojection_rms_px"')


def check_calibration_outputs(out: str | os.PathLike) -> None:
    """Before calibrating: each file :func:`write_calibration` would write at ``out`` is absent or one it wrote."""
    for path, mark in zip(calibration_paths(out), _OWN_MARKS):
        check_output_file(path, lambda p, mark=mark: mark in p.read_bytes(), "a file written by mocap calibrate",
                          error=CalibrationError, how="choose another --out, or move or remove it yourself")


def write_calibration(result: CalibrationResult, out: str | os.PathLike) -> list[Path]:
    """Write ``<out>.toml`` (anipose), ``<out>.yml`` (OpenCV) and ``<out>.report.json``."""
    toml_path, yml_path, report_path = calibration_paths(out)
    toml_path.parent.mkdir(parents=True, exist_ok=True)
    result.calibration.save_toml(toml_path)
    result.calibration.save_opencv_yaml(yml_path)
    result.written = [toml_path, yml_path, report_path]
    atomic_write_text(report_path, json.dumps(result.to_dict(), indent=2, default=float))
    return result.written


def calibrate_cameras(inputs: Mapping[str, ViewSource], board: BoardSpec, wand: WandSpec | None = None, *,
                      wand_observations: WandObservations | np.ndarray | None = None,
                      out: str | os.PathLike | None = None,
                      known_intrinsics: Calibration | None = None,
                      reference_camera: str | None = None,
                      floor_view: int | str | None = None,
                      world_camera: str | None = None,
                      intrinsics_options: IntrinsicsOptions | None = None,
                      ba_options: BundleAdjustmentOptions | None = None,
                      detection_settings: DetectionSettings | None = None,
                      frame_step: int = 1) -> CalibrationResult:
    """Calibrate cameras from pictures or videos of a board (and optionally a wand).

    Parameters
    ----------
    inputs : mapping camera name -> folder, video, list of image paths or list of images
        Views are synchronised by index across cameras.
    board : BoardSpec
    wand : WandSpec, optional
    wand_observations : WandObservations or (C, F, 3, 2) array, optional
        Labelled wand marker pixels per camera (in ``inputs`` order) and frame.
    out : path, optional
        Output stem: writes ``.toml``, ``.yml`` and ``.report.json``.
    known_intrinsics, reference_camera, floor_view, world_camera, intrinsics_options, ba_options
        See :func:`calibrate_from_observations`.
    detection_settings : DetectionSettings, optional
    frame_step : int
        For videos: use every ``frame_step``-th frame.
    """
    obs, dets = detect_board_views(inputs, board, detection_settings, frame_step)
    if wand_observations is not None and not isinstance(wand_observations, WandObservations):
        wand_observations = WandObservations(list(inputs), np.asarray(wand_observations))
    result = calibrate_from_observations(obs, wand=wand, wand_observations=wand_observations,
                                         known_intrinsics=known_intrinsics, reference_camera=reference_camera,
                                         floor_view=floor_view, world_camera=world_camera,
                                         intrinsics_options=intrinsics_options, ba_options=ba_options, detections=dets)
    if out is not None:
        write_calibration(result, out)
    return result


# ---------------------------------------------------------------------- thin CLI entry
def _parse_size(text: str) -> tuple[int, int]:
    try:
        a, b = text.lower().replace("*", "x").split("x")
        return int(a), int(b)
    except ValueError:
        raise CalibrationError(f"--board-size {text!r} must look like 9x6 (columns x rows)") from None


def run_calibrate_cli(cameras: Sequence[str], out: str, *, board: str = "checkerboard", board_size: str = "9x6",
                      square_mm: float = 25.0, marker_mm: float | None = None, dictionary: str = "DICT_4X4_50",
                      legacy_charuco: bool = False,
                      wand_file: str | None = None, wand_distances_mm: str | None = None,
                      intrinsics: str | None = None, reference: str | None = None, floor_view: str | None = None,
                      world_camera: str | None = None,
                      fix_aspect_ratio: bool = False, fix_principal_point: bool = False, zero_tangent: bool = False,
                      k3: str = "auto", min_views: int = 5, refine_intrinsics: bool = True,
                      loss: str = "soft_l1", ba_max_evaluations: int = 300, frame_step: int = 1,
                      blur_threshold: float = 20.0) -> CalibrationResult:
    """``mocap calibrate`` with plain arguments (the typer command just forwards them).

    Parameters
    ----------
    cameras : list of "name=path"
        ``path`` is a folder of images, a video, or a single image; views are matched by
        index across cameras.
    out : str
        Output stem (``.toml``, ``.yml`` and ``.report.json`` are written).
    wand_file : str, optional
        ``.npz`` with ``markers_px`` ``(C, F, 3, 2)`` labelled wand markers (or
        ``blobs_px``, the same unlabelled, for a collinear wand) in pixels, cameras in the
        order given or named by an optional ``camera_names`` array.
    wand_distances_mm : str, optional
        ``"d01,d12,d02"`` or ``"d01,d12"`` for a collinear wand.
    intrinsics : str, optional
        A calibration file (.toml/.yml) whose cameras' intrinsics are used as known.
    floor_view : str, optional
        Index or file name of the view with the board on the floor (world frame).
    """
    check_calibration_outputs(out)
    inputs: dict[str, str] = {}
    for item in cameras:
        if "=" not in item:
            raise CalibrationError(f"camera {item!r} must be given as name=folder_or_video, e.g. cam0=calib/cam0/")
        name, path = item.split("=", 1)
        inputs[name.strip()] = path.strip()
    cols, rows = _parse_size(board_size)
    spec = BoardSpec(kind=board, size=(cols, rows), square_length_m=square_mm / 1000.0,
                     marker_length_m=None if marker_mm is None else marker_mm / 1000.0,
                     dictionary=dictionary, legacy_pattern=legacy_charuco)
    wand = None
    wand_obs = None
    if (wand_file is None) != (wand_distances_mm is None):
        raise CalibrationError("--wand-file and --wand-distances-mm go together")
    if wand_file is not None:
        d = [float(x) / 1000.0 for x in wand_distances_mm.split(",")]
        wand = WandSpec.collinear(*d) if len(d) == 2 else WandSpec(tuple(d))
        try:
            with np.load(wand_file, allow_pickle=False) as z:
                if "markers_px" in z:
                    px = z["markers_px"]
                else:  # three unlabelled blobs per camera and frame
                    px = label_collinear_wand(z["blobs_px"], wand)
                wnames = [str(n) for n in z["camera_names"]] if "camera_names" in z else list(inputs)
        except (OSError, KeyError, ValueError) as exc:
            raise InputFileError(Path(wand_file), f"not a usable wand file ({exc})",
                                 "save one with numpy.savez(path, markers_px=(C, F, 3, 2) labelled pixels "
                                 "[or blobs_px=(C, F, 3, 2) unlabelled, collinear wand], camera_names=[...])") from exc
        wand_obs = WandObservations(wnames, px)
    known = Calibration.load(intrinsics) if intrinsics is not None else None
    fv: int | str | None = None
    if floor_view is not None:
        fv = int(floor_view) if floor_view.strip().isdigit() else floor_view
    iopt = IntrinsicsOptions(fix_aspect_ratio=fix_aspect_ratio, fix_principal_point=fix_principal_point,
                             zero_tangent=zero_tangent, k3=k3, min_views=min_views)
    bopt = BundleAdjustmentOptions(refine_intrinsics=refine_intrinsics, fix_aspect_ratio=fix_aspect_ratio,
                                   fix_principal_point=fix_principal_point, zero_tangent=zero_tangent, loss=loss,
                                   max_evaluations=ba_max_evaluations)
    return calibrate_cameras(inputs, spec, wand, wand_observations=wand_obs, out=out, known_intrinsics=known,
                             reference_camera=reference, floor_view=fv, world_camera=world_camera,
                             intrinsics_options=iopt, ba_options=bopt,
                             detection_settings=DetectionSettings(blur_threshold=blur_threshold), frame_step=frame_step)
