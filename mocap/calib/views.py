"""Reading a camera's calibration views (a folder of images, a video, a list of images) and finding the board in each.

The first step of :func:`mocap.calibrate.calibrate_cameras`: :func:`detect_board_views`
gives the :class:`~mocap.calib.observations.BoardObservations` the calibration starts from.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Iterator, Mapping, Sequence, Union

import cv2
import numpy as np

from mocap.calib.board_detection import BoardDetection, DetectionSettings, detect_board
from mocap.calib.boards import BoardSpec
from mocap.calib.observations import BoardObservations
from mocap.errors import InputFileError

__all__ = ["ViewSource", "IMAGE_SUFFIXES", "VIDEO_SUFFIXES", "iter_views", "detect_board_views"]

ViewSource = Union[str, os.PathLike, Sequence[Union[str, os.PathLike, np.ndarray]]]

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp", ".pgm", ".ppm")
VIDEO_SUFFIXES = (".mp4", ".avi", ".mov", ".mkv", ".webm", ".m4v", ".mpg", ".mpeg")


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
