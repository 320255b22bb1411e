"""The marker capture pipeline end to end: frames -> labelled 3D trajectories -> skeleton.

detection (per camera, per frame) -> label initialisation on the first frame (T-pose
template, no ground truth) -> 2D tracking that keeps labels (any registered tracker)
-> multi-camera reconstruction -> optional skeleton solving. The same function runs on
real webcam video (``mocap markers``) and on the bench's rendered frames
(``simbench run``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable, Sequence

import numpy as np

from mocap.calibration import Calibration
from mocap.detection import DetectionParams, detect_markers
from mocap.errors import MocapInputError
from mocap.labelling import LabelInit, LabelInitParams, LabelTemplate, initial_labels
from mocap.reconstruction import ReconstructionParams, reconstruct
from mocap.tracking import track_cameras
from mocap.types import Detections, Tracks2D, Trajectories


@dataclass
class MarkerPipelineParams:
    detection: DetectionParams = field(default_factory=DetectionParams)
    tracker: str = "kalman"
    tracker_params: dict = field(default_factory=dict)
    label_init: LabelInitParams = field(default_factory=LabelInitParams)
    reconstruction: ReconstructionParams = field(default_factory=ReconstructionParams)
    solve_skeleton: bool = True


@dataclass
class MarkerCapture:
    """Everything the pipeline produced.

    detections : C lists of F :class:`Detections`
    label_init : first-frame labelling
    tracks : labelled 2D tracks ``(F, C, M, 2)``
    trajectories : labelled 3D trajectories ``(F, M, 3)`` metres
    skeleton : solved skeleton (``mocap.skeleton.SkeletonFit``) or None
    timings_ms : stage name -> total milliseconds
    """

    detections: list[list[Detections]]
    label_init: LabelInit
    tracks: Tracks2D
    trajectories: Trajectories
    skeleton: object | None
    timings_ms: dict[str, float]


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
) -> MarkerCapture:
    """Label, track, reconstruct and (optionally) solve the skeleton.

    Parameters
    ----------
    detections : C lists of F Detections, in calibration order
    calibration : Calibration
    template : LabelTemplate (T-pose marker positions, subject-local frame)
    times : (F,) seconds
    subject : mocap.subject.SubjectModel, needed when ``params.solve_skeleton``
    """
    params = params or MarkerPipelineParams()
    if rng is None:
        raise ValueError("capture_from_detections needs rng=np.random.default_rng(seed)")
    C = len(calibration)
    if len(detections) != C:
        raise MocapInputError(f"got detections of {len(detections)} cameras for a calibration of {C} ({calibration.names})")
    F = len(times)
    timings = {"detection": detection_ms}
    t0 = time.perf_counter()
    init = initial_labels([d[0] for d in detections], calibration, template, params.label_init)
    timings["label_init"] = (time.perf_counter() - t0) * 1e3
    t0 = time.perf_counter()
    dt = float(np.median(np.diff(times))) if F > 1 else 1 / 30
    tracks = track_cameras(detections, init.xy, list(template.names), calibration.names, tracker=params.tracker,
                           dt=dt, rng=rng, **params.tracker_params)
    timings["tracking"] = (time.perf_counter() - t0) * 1e3
    t0 = time.perf_counter()
    traj = reconstruct(tracks, calibration, params.reconstruction, times=np.asarray(times, float))
    timings["reconstruction"] = (time.perf_counter() - t0) * 1e3
    fit = None
    if params.solve_skeleton and subject is not None:
        from mocap.skeleton import solve_skeleton

        t0 = time.perf_counter()
        fit = solve_skeleton(traj, subject)
        timings["skeleton"] = (time.perf_counter() - t0) * 1e3
    return MarkerCapture(detections, init, tracks, traj, fit, timings)


def capture_markers(
    frames_per_camera: Sequence[Iterable[np.ndarray]],
    calibration: Calibration,
    template: LabelTemplate,
    times: np.ndarray,
    params: MarkerPipelineParams | None = None,
    rng: np.random.Generator | None = None,
    subject=None,
) -> MarkerCapture:
    """Run the whole pipeline on frames (``C`` iterables of images, synchronised)."""
    params = params or MarkerPipelineParams()
    stream = DetectionStream(len(calibration), params.detection)
    for images in zip(*frames_per_camera):
        stream.add(images)
    n = len(stream.detections[0])
    return capture_from_detections(stream.detections, calibration, template, np.asarray(times, float)[:n], params,
                                   rng, subject, stream.ms)


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
