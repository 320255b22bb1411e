"""What another capture system needs from a scenario, in files (``simbench export-inputs``).

Layout of an inputs folder (every format; only the calibration file differs)::

    inputs.json                      manifest: scenario, seed, hash, format, cameras, markers,
                                     frame times, conventions, file list
    calibration/<file>               the rig in the system's own format and convention
                                     (mocap.calibration_formats: calibration.yml, calibration.toml,
                                     Calib.toml, intri.yml + extri.yml)
    videos/<camera>.mp4              the take
    pose/<camera>_json/<camera>_<frame:06d>_keypoints.json
                                     2D detections, OpenPose style: one person whose
                                     pose_keypoints_2d are x, y, confidence per marker in
                                     the manifest's marker order (0, 0, 0 when not detected)
    detections_2d.csv                the same as a table: frame, camera, marker, x_px, y_px, confidence
    label_template.csv               the subject's markers in its T-pose (name, x, y, z metres)
    calibration_board/               (scenarios with a [calibration_scene]) board.json, the board
                                     pictures <camera>/view_NNN.png and one <camera>.mp4 per camera

Conventions (also in the manifest): world Z up, metres; pixels with pixel centres at
integers (OpenCV), distorted (as the cameras see them); ``x_cam = R @ x_world + t``.

2D detections are the bench's own blob detector on the rendered frames, each blob labelled
with the marker whose exact projection it lies on (one-to-one, within ``LABEL_GATE_PX``):
the role a 2D keypoint detector plays in a markerless system. So every system on the
scoreboard triangulates the same measured 2D points, with their real centroid errors,
merges and occlusions; what it does not get is a wrong label. Confidence is 1 for a
labelled blob.
"""

from __future__ import annotations

import csv
import json
import os
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from scipy.optimize import linear_sum_assignment

from mocap.calibration import Calibration
from mocap.calibration_formats import CALIBRATION_FILE_NAMES, CALIBRATION_FORMATS, save_calibration
from mocap.detection import DetectionParams
from mocap.labelling import save_template
from mocap.marker_pipeline import DetectionStream
from mocap.types import Detections
from simbench import interrupts
from simbench.output_dir import AtomicOutputDir
from simbench.pipelines.markers import label_template
from simbench.render.video import Mp4Writer
from simbench.scenario import Scenario
from simbench.stage.build import build_stage
from simbench.stage.ground_truth import GroundTruth
from simbench.stage.rendering import render_frames, render_writer
from simbench.stage.stage import Stage

__all__ = ["LABEL_GATE_PX", "ExportedInputs", "export_inputs", "write_inputs", "labelled_detections", "read_detections_csv"]

LABEL_GATE_PX = 3.0  # a blob farther than this from every visible marker's projection stays unlabelled
MANIFEST = "inputs.json"


@dataclass(frozen=True)
class ExportedInputs:
    """An inputs folder and what it holds (the arrays stay in memory for the caller's scoring)."""

    folder: Path
    fmt: str
    calibration: Calibration
    points_px: np.ndarray  # (F, C, M, 2) labelled detections, NaN where none
    confidence: np.ndarray  # (F, C, M) in [0, 1], 0 where none
    marker_names: list[str]
    times: np.ndarray  # (F,) s


def labelled_detections(detections: list[list[Detections]], gt: GroundTruth,
                        gate_px: float = LABEL_GATE_PX) -> tuple[np.ndarray, np.ndarray]:
    """Blobs labelled by the exact projections: ``points (F, C, M, 2)`` px (NaN: none) and
    ``confidence (F, C, M)``. One blob per marker and marker per blob (Hungarian assignment
    on pixel distance); a visible marker with no blob within ``gate_px`` has none."""
    F, C, M = gt.markers_2d.shape[:3]
    pts = np.full((F, C, M, 2), np.nan)
    conf = np.zeros((F, C, M))
    for c in range(C):
        for f in range(F):
            blobs = detections[c][f].xy
            vis = np.flatnonzero(gt.marker_visible[f, c])
            if len(blobs) == 0 or len(vis) == 0:
                continue
            d = np.linalg.norm(gt.markers_2d[f, c, vis][:, None, :] - blobs[None, :, :], axis=2)
            rows, cols = linear_sum_assignment(np.where(d < gate_px, d, 1e6))
            ok = d[rows, cols] < gate_px
            pts[f, c, vis[rows[ok]]] = blobs[cols[ok]]
            conf[f, c, vis[rows[ok]]] = 1.0
    return pts, conf


def _write_openpose(folder: Path, cameras: list[str], points: np.ndarray, confidence: np.ndarray) -> None:
    F = points.shape[0]
    for c, cam in enumerate(cameras):
        d = folder / "pose" / f"{cam}_json"
        d.mkdir(parents=True, exist_ok=True)
        for f in range(F):
            kp = np.column_stack([np.nan_to_num(points[f, c], nan=0.0), confidence[f, c]]).ravel()
            doc = {"version": 1.3, "people": [{"person_id": [-1], "pose_keypoints_2d": [round(float(v), 6) for v in kp],
                                               "face_keypoints_2d": [], "hand_left_keypoints_2d": [],
                                               "hand_right_keypoints_2d": []}]}
            (d / f"{cam}_{f:06d}_keypoints.json").write_text(json.dumps(doc))


def _write_detections_csv(path: Path, cameras: list[str], markers: list[str], points: np.ndarray,
                          confidence: np.ndarray) -> None:
    with path.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["frame", "camera", "marker", "x_px", "y_px", "confidence"])
        F, C, M = confidence.shape
        for f in range(F):
            for c in range(C):
                for m in np.flatnonzero(confidence[f, c] > 0):
                    w.writerow([f, cameras[c], markers[m], f"{points[f, c, m, 0]:.6f}", f"{points[f, c, m, 1]:.6f}",
                                f"{confidence[f, c, m]:.3f}"])


def read_detections_csv(path: str | os.PathLike, cameras: list[str], markers: list[str], n_frames: int) -> tuple[np.ndarray, np.ndarray]:
    """``detections_2d.csv`` back to ``points (F, C, M, 2)`` (NaN where none) and ``confidence (F, C, M)``."""
    pts = np.full((n_frames, len(cameras), len(markers), 2), np.nan)
    conf = np.zeros((n_frames, len(cameras), len(markers)))
    ci = {n: i for i, n in enumerate(cameras)}
    mi = {n: i for i, n in enumerate(markers)}
    with Path(path).open(newline="") as fh:
        for row in csv.DictReader(fh):
            f, c, m = int(row["frame"]), ci[row["camera"]], mi[row["marker"]]
            pts[f, c, m] = float(row["x_px"]), float(row["y_px"])
            conf[f, c, m] = float(row["confidence"])
    return pts, conf


def _write_calibration_board(folder: Path, scenario: Scenario, stage: Stage) -> dict:
    """The calibration session's board pictures (PNG and one MP4 per camera) and the board's description."""
    from simbench.stage.calibration_scene import render_calibration_scene  # only for scenarios with a calibration scene

    cfg = scenario.calibration_scene
    rng = np.random.default_rng(np.random.SeedSequence([scenario.seed, 0xCA11B]))  # the run's calibration session
    scene = render_calibration_scene(scenario, rng, stage.cameras, stage.lighting)
    out = folder / "calibration_board"
    scene.write_images(out)
    V, C, H, W = scene.board_images.shape
    for c, name in enumerate(scene.camera_names):
        with Mp4Writer(out / f"{name}.mp4", W, H, 1.0) as writer:
            for v in range(V):
                writer.write(cv2.cvtColor(scene.board_images[v, c], cv2.COLOR_GRAY2RGB))
    board = {"kind": cfg.board, "inner_corners": [cfg.board_cols, cfg.board_rows] if cfg.board == "checkerboard" else None,
             "squares": [cfg.board_cols + 1, cfg.board_rows + 1] if cfg.board == "checkerboard" else [cfg.board_cols, cfg.board_rows],
             "square_m": cfg.square_m, "marker_m": cfg.marker_m if cfg.marker_m is not None else (0.75 * cfg.square_m if cfg.board == "charuco" else None),
             "dictionary": cfg.dictionary if cfg.board == "charuco" else None, "views": V,
             "floor_view": cfg.floor_view, "board_thickness_m": cfg.board_thickness_m,
             "note": "checkerboard sizes: inner corners (what OpenCV's findChessboardCorners and aniposelib's Checkerboard take) and squares"}
    (out / "board.json").write_text(json.dumps(board, indent=2) + "\n")
    return board


def write_inputs(folder: Path, fmt: str, scenario: Scenario, stage: Stage, gt: GroundTruth, calibration: Calibration,
                 detections: list[list[Detections]] | None, board: bool = True) -> ExportedInputs:
    """Write everything but the videos (the caller rendered them into ``folder/videos``) into ``folder``."""
    if fmt not in CALIBRATION_FORMATS:
        raise ValueError(f"format {fmt!r}: use one of {', '.join(CALIBRATION_FORMATS)}")
    folder.mkdir(parents=True, exist_ok=True)
    cal_files = save_calibration(calibration, folder / "calibration", fmt)
    cameras, markers = gt.camera_names, list(stage.marker_names)
    F = gt.n_frames
    if detections is not None and markers:
        pts, conf = labelled_detections(detections, gt)
        _write_openpose(folder, cameras, pts, conf)
        _write_detections_csv(folder / "detections_2d.csv", cameras, markers, pts, conf)
        save_template(label_template(stage), folder / "label_template.csv")
    else:
        pts, conf = np.full((F, len(cameras), 0, 2), np.nan), np.zeros((F, len(cameras), 0))
    board_info = _write_calibration_board(folder, scenario, stage) if (board and scenario.calibration_scene is not None) else None
    manifest = {
        "format": fmt,
        "scenario": scenario.name,
        "scenario_hash": scenario.content_hash(),
        "seed": scenario.seed,
        "fps": scenario.fps,
        "n_frames": F,
        "times_s": [float(t) for t in gt.times],
        "cameras": cameras,
        "image_size": list(gt.image_size),
        "markers": markers,
        "calibration": [str(p.relative_to(folder)) for p in cal_files],
        "videos": [f"videos/{c}.mp4" for c in cameras],
        "detections": {"openpose_json": "pose/<camera>_json/<camera>_<frame:06d>_keypoints.json",
                       "csv": "detections_2d.csv",
                       "how": f"the bench's blob detector on the rendered frames, labelled by the exact projections within {LABEL_GATE_PX} px"}
        if markers else None,
        "label_template": "label_template.csv" if markers else None,
        "calibration_board": board_info,
        "conventions": {"world": "Z up, metres", "pixels": "distorted, pixel centres at integers (OpenCV)",
                        "extrinsics": "x_cam = R @ x_world + t", "calibration_file": CALIBRATION_FILE_NAMES[fmt]},
    }
    (folder / MANIFEST).write_text(json.dumps(manifest, indent=1) + "\n")
    return ExportedInputs(folder, fmt, calibration, pts, conf, markers, gt.times)


def export_inputs(scenario: Scenario, out: str | Path, fmt: str, progress=None) -> ExportedInputs:
    """``simbench export-inputs``: render the take and write an inputs folder at ``out`` (replaced
    only if it is an earlier bench output or empty: :mod:`simbench.output_dir`)."""
    with AtomicOutputDir(out, scenario=scenario.name, kind="render") as tmp:
        stage = build_stage(scenario)
        stream = DetectionStream(len(stage.cameras), DetectionParams(mode=scenario.sensor.mode)) if stage.marker_names else None
        with render_writer(stage, tmp, png=False) as write:
            def on_frame(fo):
                interrupts.raise_if_pending()
                write(fo)
                if stream is not None:
                    stream.add(list(fo.images))

            seq = render_frames(stage, on_frame=on_frame, keep_frames=False, keep_ids=False, progress=progress)
        gt = seq.ground_truth
        exported = write_inputs(tmp, fmt, scenario, stage, gt, gt.calibration(),
                                stream.detections if stream is not None else None)
    return ExportedInputs(Path(out), fmt, exported.calibration, exported.points_px, exported.confidence,
                          exported.marker_names, exported.times)
