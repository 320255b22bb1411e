"""Marker blob detection in camera frames.

One frame in, :class:`mocap.types.Detections` out. Two detectors share the
connected-component machinery and differ in what "brighter than its surroundings" means.

``"ir"`` (:mod:`mocap.detection.ir`): retro-reflective spheres lit by the camera's ring
light on a dark scene; the frame minus a local median background, thresholded.

``"visible"`` (:mod:`mocap.detection.visible`): white/grey spheres of a few pixels on a lit,
textured, coloured scene; the local top-hat of ``min(R, G, B)``, half-maximum blobs, a ring
test and a shading-robust centroid.

What both share (noise, threshold, connected components and their shape tests) is in
:mod:`mocap.detection.blobs`; their settings in :mod:`mocap.detection.params`.

Coordinates follow OpenCV: x right, y down, pixel centres at integers.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Iterable, Iterator, Literal

import cv2
import numpy as np

from mocap.detection.blobs import check_image, to_gray
from mocap.detection.ir import detect_ir
from mocap.detection.params import DetectionParams
from mocap.detection.visible import detect_visible
from mocap.errors import InputFileError
from mocap.types import Detections

__all__ = ["DetectionParams", "detect_markers", "detect_frames", "detect_video", "iter_video_frames"]


def detect_markers(
    image: np.ndarray,
    params: DetectionParams | None = None,
    background: np.ndarray | None = None,
    foreground_mask: np.ndarray | None = None,
) -> Detections:
    """Find marker blobs in one frame.

    Parameters
    ----------
    image : (H, W) or (H, W, 3) uint8
        Grey or RGB frame (for BGR frames from OpenCV, convert first or pass grey).
        ``"visible"`` mode uses the colour of an RGB frame (``achromatic``).
    params : DetectionParams, optional
    background : (H, W) or (H, W, 3) uint8, optional
        Static background (e.g. the empty scene); only what is brighter than it counts.
    foreground_mask : (H, W) uint8 or bool, optional
        Non-zero where a moving-foreground model (e.g. MOG2) says foreground; blobs are
        kept only where it is set.

    Returns
    -------
    Detections
        ``xy`` (n, 2) sub-pixel centroids (pixels), ``area`` (n,) thresholded pixels,
        ``intensity`` (n,) mean grey level of each blob.
    """
    params = DetectionParams() if params is None else params
    img = check_image(image)
    gray = to_gray(img)
    bg = None
    if background is not None:
        bg = to_gray(background, "background")
        if bg.shape != gray.shape:
            raise ValueError(f"background is {bg.shape} but the image is {gray.shape}; use a background frame of the same camera")
    if params.mode == "visible":
        return detect_visible(img, gray, params, bg, foreground_mask)
    return detect_ir(gray, params, bg, foreground_mask)


def detect_frames(
    frames: Iterable[np.ndarray],
    params: DetectionParams | None = None,
    background: np.ndarray | Literal["mog2"] | None = None,
) -> list[Detections]:
    """Run :func:`detect_markers` on a sequence of frames of one camera.

    Parameters
    ----------
    frames : iterable of (H, W) or (H, W, 3) uint8
    params : DetectionParams, optional
    background : (H, W) uint8, ``"mog2"`` or None
        A static background image, or ``"mog2"`` for an adaptive background model
        (``cv2.createBackgroundSubtractorMOG2``, one per call) whose foreground mask
        gates the blobs.

    Returns
    -------
    list of Detections, one per frame.
    """
    params = DetectionParams() if params is None else params
    out: list[Detections] = []
    if isinstance(background, str):
        if background != "mog2":
            raise ValueError(f"background={background!r}: pass an image, 'mog2' or None")
        sub = cv2.createBackgroundSubtractorMOG2(history=params.mog2_history, varThreshold=params.mog2_var_threshold, detectShadows=False)
        grow = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (5, 5))
        for frame in frames:
            gray = to_gray(frame, "frame")
            fg = cv2.dilate(sub.apply(gray), grow)
            out.append(detect_markers(gray, params, foreground_mask=fg))
        return out
    for frame in frames:
        out.append(detect_markers(frame, params, background))
    return out


def iter_video_frames(path: str | os.PathLike, max_frames: int | None = None) -> Iterator[np.ndarray]:
    """Grey ``(H, W)`` uint8 frames of a video file, decoded by OpenCV.

    Raises
    ------
    InputFileError
        If the file is missing or OpenCV cannot decode it.
    """
    path = Path(path)
    if not path.is_file():
        raise InputFileError(path, "file not found", "pass the path of a video file (e.g. an MP4 written by `simbench render`)")
    cap = cv2.VideoCapture(str(path))
    try:
        if not cap.isOpened():
            raise InputFileError(path, "cannot be opened as a video", "check that it is a video OpenCV/FFmpeg can decode (e.g. MP4 H.264)")
        n = 0
        while max_frames is None or n < max_frames:
            ok, frame = cap.read()
            if not ok:
                break
            yield cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY) if frame.ndim == 3 else frame
            n += 1
        if n == 0:
            raise InputFileError(path, "no frame could be decoded", "check the file is not empty or truncated")
    finally:
        cap.release()


def detect_video(
    path: str | os.PathLike,
    params: DetectionParams | None = None,
    background: np.ndarray | Literal["mog2"] | None = None,
    max_frames: int | None = None,
) -> list[Detections]:
    """Detections of every frame of a video file (see :func:`detect_frames`)."""
    return detect_frames(iter_video_frames(path, max_frames), params, background)
