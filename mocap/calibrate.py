"""``mocap calibrate``: images or videos of a board (and optionally a wand) in, calibration out.

Pipeline (each step in :mod:`mocap.calib`):

1. find the board in every image / video frame of every camera
   (:func:`mocap.calib.board_detection.detect_board`), keeping why each failed;
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
from typing import Iterator, Mapping, Sequence, Union

import cv2
import numpy as np

from mocap.calib.board_detection import BoardDetection, DetectionSettings, detect_board
from mocap.calib.boards import BoardSpec
from mocap.calib.bundle_adjustment import BundleAdjustmentOptions, bundle_adjust
from mocap.calib.errors import BoardNotFoundError, CalibrationError, DisconnectedCamerasError, ViewFailure
from mocap.calib.extrinsics import board_poses_pnp, initial_rig
from mocap.calib.geometry import intrinsics_from_vector, intrinsics_vector
from mocap.calib.intrinsics import IntrinsicsOptions, calibrate_intrinsics
from mocap.calib.observations import BoardObservations, WandObservations
from mocap.calib.wand import WandSpec, label_collinear_wand, triangulate_wand, wand_initial_rig
from mocap.calib.world_frame import camera_transform, floor_transform, transform_cameras, transform_points, transform_poses
from mocap.calibration import Calibration, Camera
from mocap.errors import InputFileError

ViewSource = Union[str, os.PathLike, Sequence[Union[str, os.PathLike, np.ndarray]]]

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp", ".pgm", ".ppm")
VIDEO_SUFFIXES = (".mp4", ".avi", ".mov", ".mkv", ".webm", ".m4v", ".mpg", ".mpeg")


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


# ---------------------------------------------------------------------- reading views
def _list_images(directory: Path) -> list[Path]:
    files = sorted(p for p in directory.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
    if not files:
        raise InputFileError(directory, "no images found in this folder",
                             f"put the calibration pictures ({', '.join(IMAGE_SUFFIXES)}) there or pass a video file")
    return files


def iter_views(source: ViewSource, frame_step: int = 1) -> Iterator[tuple[str, np.ndarray]]:
    """Yield ``(label, image)`` for a folder, a video, a list of files or in-memory images.

    Parameters
    ----------
    source
        A folder of images (sorted by name), a video file (every ``frame_step``-th
        frame), or a sequence of image paths / ``(H, W[, 3])`` arrays.
    frame_step : int
        For videos: use one frame in ``frame_step``.
    """
    if isinstance(source, (str, os.PathLike)):
        path = Path(source)
        if path.is_dir():
            yield from iter_views(_list_images(path))
            return
        if not path.exists():
            raise InputFileError(path, "file or folder not found", "pass a folder of images, a video file, or a list of images")
        if path.suffix.lower() in IMAGE_SUFFIXES:
            yield from iter_views([path])
            return
        cap = cv2.VideoCapture(str(path))
        if not cap.isOpened():
            raise InputFileError(path, "cannot be opened as a video",
                                 f"use a video OpenCV can read ({', '.join(VIDEO_SUFFIXES)}) or a folder of images")
        try:
            i = 0
            while True:
                ok, frame = cap.read()
                if not ok:
                    break
                if i % max(1, int(frame_step)) == 0:
                    yield f"{path.name}#frame {i}", frame
                i += 1
        finally:
            cap.release()
        return
    for k, item in enumerate(source):
        if isinstance(item, np.ndarray):
            yield f"image {k}", item
            continue
        p = Path(item)
        img = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
        if img is None:
            raise InputFileError(p, "not a readable image" if p.exists() else "file not found",
                                 "check the path and that the file is a PNG/JPEG image")
        yield p.name, img


def detect_board_views(inputs: Mapping[str, ViewSource], board: BoardSpec, settings: DetectionSettings | None = None,
                       frame_step: int = 1) -> tuple[BoardObservations, dict[str, list[BoardDetection]]]:
    """Find the board in every view of every camera.

    Returns
    -------
    observations : BoardObservations
        ``corners_px (C, V, N, 2)``, NaN where a view had no usable board.
    detections : dict[str, list[BoardDetection]]
        Per camera, the detection (or failure and its cause) of every view.
    """
    if not inputs:
        raise InputFileError(Path("."), "no cameras given", "pass at least one camera as name=folder_or_video")
    names = list(inputs)
    dets: dict[str, list[BoardDetection]] = {}
    labels: dict[str, list[str]] = {}
    for name in names:
        dets[name], labels[name] = [], []
        for label, image in iter_views(inputs[name], frame_step):
            dets[name].append(detect_board(image, board, settings))
            labels[name].append(label)
        if not dets[name]:
            raise InputFileError(Path(str(inputs[name])) if isinstance(inputs[name], (str, os.PathLike)) else Path(name),
                                 f"camera {name!r} has no images or frames", "check the folder or video")
    counts = {n: len(d) for n, d in dets.items()}
    if len(set(counts.values())) > 1:
        src = inputs[names[0]]
        raise InputFileError(Path(str(src)) if isinstance(src, (str, os.PathLike)) else Path(names[0]),
                             "cameras have different numbers of views: " + ", ".join(f"{n} {k}" for n, k in counts.items()),
                             "give every camera the same number of synchronised images or frames "
                             "(view i of each camera must be the same moment)")
    V = counts[names[0]]
    corners = np.full((len(names), V, board.n_corners, 2), np.nan)
    sizes = []
    for c, name in enumerate(names):
        sizes.append(dets[name][0].image_size)
        for v, d in enumerate(dets[name]):
            if d.image_size != sizes[-1]:
                raise InputFileError(Path(labels[name][v]), f"image size {d.image_size} differs from the camera's first "
                                     f"view {sizes[-1]}", f"use one resolution per camera ({name!r})")
            if d.found:
                corners[c, v, d.corner_ids] = d.corners_px
    obs = BoardObservations(board, names, sizes, corners, [labels[n] for n in names])
    return obs, dets


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
    detections : mapping, optional
        Per camera, the :class:`BoardDetection` of each view, to explain failures.
    """
    obs = observations
    iopt = intrinsics_options if intrinsics_options is not None else IntrinsicsOptions()
    bopt = ba_options if ba_options is not None else BundleAdjustmentOptions(
        fix_aspect_ratio=iopt.fix_aspect_ratio, fix_principal_point=iopt.fix_principal_point, zero_tangent=iopt.zero_tangent)
    names = obs.camera_names
    C, V = obs.n_cameras, obs.n_views
    if C > 1 and not obs.board.orientation_unique:
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
        wand_px = wand_observations.reordered(names).markers_px
    elif (wand is None) != (wand_observations is None):
        raise CalibrationError("wand refinement needs both the wand's distances (WandSpec / --wand-distances-mm) and its "
                               "2D marker observations (--wand-file)")
    obj = obs.object_points
    usable = obs.usable(iopt.min_corners)
    rejected = _detection_rejections(obs, usable, detections)

    # 1. intrinsics -------------------------------------------------------------
    intr, k3_free, zhang_rms, use = _intrinsics_per_camera(obs, usable, iopt, known_intrinsics, detections, rejected)
    Ks = np.stack([intrinsics_from_vector(p)[0] for p in intr])
    dists = np.stack([intrinsics_from_vector(p)[1] for p in intr])
    poses = board_poses_pnp(obs.corners_px, obj, Ks, dists, use)
    use &= poses.valid

    # 2. extrinsics ----------------------------------------------------------------
    R_cw, t_cw, R_wb, t_wb = _initial_extrinsics(poses, names, ref, intr, wand, wand_px)

    # 3. bundle adjustment -----------------------------------------------------------
    wand_pts = None
    ba_info: dict = {}
    final_rms = dict(zhang_rms)
    view_rms = {n: np.full(V, np.nan) for n in names}
    wand_rms_mm = None
    if C > 1 or wand_px is not None:
        if wand_px is not None:
            wand_pts = triangulate_wand(intr, R_cw, t_cw, wand_px)
        ba = bundle_adjust(intr, R_cw, t_cw, camera_names=names, reference=ref, k3_free=k3_free,
                           board_corners_px=obs.corners_px, object_points=obj, board_use=use, R_wb=R_wb, t_wb=t_wb,
                           wand_px=wand_px, wand_points=wand_pts,
                           wand_distances_m=None if wand is None else wand.distances, options=bopt)
        intr, R_cw, t_cw, R_wb, t_wb = ba.intrinsics, ba.R_cw, ba.t_cw, ba.R_wb, ba.t_wb
        if wand_px is not None:
            wand_pts = ba.wand_points
            err = ba.wand_distance_error_m[np.isfinite(ba.wand_distance_error_m)]
            wand_rms_mm = float(np.sqrt(np.mean(err ** 2)) * 1000) if err.size else None
        final_rms = {n: float(ba.rms_px[c]) for c, n in enumerate(names)}
        view_rms = {n: ba.view_rms_px[c] for c, n in enumerate(names)}
        ba_info = dict(cost=ba.cost, initial_cost=ba.initial_cost, evaluations=ba.evaluations, status=ba.status,
                       message=ba.message, n_parameters=ba.n_parameters, n_residuals=ba.n_residuals)
    else:
        view_rms = {names[0]: _single_camera_view_rms(obs, poses, intr[0], use[0])}

    # 4. world frame ---------------------------------------------------------------
    if floor_index is not None:
        v = floor_index
        if not np.isfinite(t_wb[v]).all():
            raise CalibrationError(f"floor view {obs.view_labels[0][v]!r} (index {v}): no camera saw enough of the board in "
                                   f"it; take a picture of the board lying on the floor that at least one camera sees "
                                   f"entirely")
        R_a, t_a = floor_transform(R_wb[v], t_wb[v])
        world = f"floor board in view {v} ({obs.view_labels[0][v]}): origin at the board origin, x along its rows, z up"
    else:
        wc = obs.camera_index(world_camera) if world_camera is not None else ref
        R_a, t_a = camera_transform(R_cw[wc], t_cw[wc])
        world = f"camera {names[wc]!r} frame (x right, y down, z forward)"
    R_cw, t_cw = transform_cameras(R_cw, t_cw, R_a, t_a)
    R_wb, t_wb = transform_poses(R_wb, t_wb, R_a, t_a)
    if wand_pts is not None:
        wand_pts = transform_points(wand_pts, R_a, t_a)

    cams = []
    for c, n in enumerate(names):
        K, d = intrinsics_from_vector(intr[c])
        cams.append(Camera(n, obs.image_sizes[c], K, d, R_cw[c], t_cw[c]))
    poses_h = np.full((V, 4, 4), np.nan)
    poses_h[:, :3, :3] = R_wb
    poses_h[:, :3, 3] = t_wb
    poses_h[:, 3] = [0, 0, 0, 1]
    return CalibrationResult(
        calibration=Calibration(tuple(cams)),
        reprojection_rms_px=final_rms,
        intrinsics_rms_px=zhang_rms,
        view_rms_px=view_rms,
        views_used={n: [obs.view_labels[c][v] for v in np.flatnonzero(use[c])] for c, n in enumerate(names)},
        views_rejected=rejected,
        board_poses_world=poses_h,
        wand_points_world=wand_pts,
        wand_distance_rms_mm=wand_rms_mm,
        world_frame=world,
        bundle_adjustment=ba_info,
    )


def write_calibration(result: CalibrationResult, out: str | os.PathLike) -> list[Path]:
    """Write ``<out>.toml`` (anipose), ``<out>.yml`` (OpenCV) and ``<out>.report.json``."""
    out = Path(out)
    stem = out.with_suffix("") if out.suffix.lower() in (".toml", ".yml", ".yaml", ".json") else out
    stem.parent.mkdir(parents=True, exist_ok=True)
    toml_path, yml_path = stem.with_suffix(".toml"), stem.with_suffix(".yml")
    report_path = stem.with_name(stem.name + ".report.json")
    result.calibration.save_toml(toml_path)
    result.calibration.save_opencv_yaml(yml_path)
    result.written = [toml_path, yml_path, report_path]
    report_path.write_text(json.dumps(result.to_dict(), indent=2, default=float))
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
