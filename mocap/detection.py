"""Marker blob detection in camera frames.

One frame in, :class:`mocap.types.Detections` out:

1. **Signal image**: the frame minus its local background, so that markers are bright on
   zero. In ``"ir"`` mode (dark scene, bright retro-reflective spheres) the background is
   the frame's median grey level; in ``"visible"`` mode (white markers on a lit person)
   it is a morphological opening (``cv2.MORPH_TOPHAT``): a marker only needs to be
   brighter than its immediate surroundings. A static background image, if given, is
   subtracted first.
2. **Threshold adapted to the image**: ``k_sigma`` times the noise std (robust estimate
   from horizontal pixel differences), never below ``min_contrast`` grey levels; or Otsu
   on the bright tail of the signal histogram; or a fixed level.
3. **Connected components** (``cv2.connectedComponentsWithStats``), filtered on area,
   on *fill ratio* (blob area over the area of its moment-equivalent ellipse: ~1 for
   discs and for motion-blur streaks, low for rings, crosses, merged clutter) and on
   elongation (generous by default so that streaks pass).
4. **Sub-pixel centroid**: intensity-weighted mean of the signal over each blob grown
   by ``dilate_px`` pixels (so that the dim skirt cut by the threshold still counts),
   computed for all blobs at once with ``np.bincount`` over the label image. A streak's
   centroid is its intensity centroid.

Coordinates follow OpenCV: x right, y down, pixel centres at integers.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Iterator, Literal

import cv2
import numpy as np

from mocap.errors import InputFileError
from mocap.types import Detections

__all__ = ["DetectionParams", "detect_markers", "detect_frames", "detect_video", "iter_video_frames"]


@dataclass(frozen=True)
class DetectionParams:
    """Settings of :func:`detect_markers`.

    Attributes
    ----------
    mode : {"ir", "visible"}
        ``"ir"``: bright markers on a dark scene, global background level.
        ``"visible"``: bright markers on a lit subject, local (top-hat) background.
    threshold : {"sigma", "otsu", "fixed"}
        How the signal threshold is chosen (see module doc).
    k_sigma : float
        ``"sigma"`` threshold in noise standard deviations.
    min_contrast : float
        Lowest threshold above the local background, grey levels.
    fixed_threshold : float
        Threshold above the background for ``threshold="fixed"``, grey levels.
    tophat_radius_px : int
        ``"visible"`` mode: radius of the structuring element; blobs up to about
        ``2 * tophat_radius_px`` pixels across are kept whole.
    min_area_px, max_area_px : int
        Accepted blob area (thresholded pixels).
    min_fill_ratio : float
        Minimum blob area / area of the ellipse with the blob's second moments.
    max_elongation : float
        Maximum ratio of the ellipse's axes (streaks from motion blur are elongated).
    dilate_px : int
        Width of the ring of dim pixels around each blob included in the centroid.
    background_threshold : float
        With a static background image: pixels within this many grey levels of the
        background are ignored.
    mog2_history : int
        History (frames) of the MOG2 background model used by :func:`detect_frames`
        with ``background="mog2"``.
    mog2_var_threshold : float
        MOG2 variance threshold.
    """

    mode: Literal["ir", "visible"] = "ir"
    threshold: Literal["sigma", "otsu", "fixed"] = "sigma"
    k_sigma: float = 6.0
    min_contrast: float = 20.0
    fixed_threshold: float = 100.0
    tophat_radius_px: int = 8
    min_area_px: int = 3
    max_area_px: int = 2000
    min_fill_ratio: float = 0.6
    max_elongation: float = 30.0
    dilate_px: int = 1
    background_threshold: float = 15.0
    mog2_history: int = 200
    mog2_var_threshold: float = 16.0

    def __post_init__(self) -> None:
        def need(cond: bool, field: str, fix: str) -> None:
            if not cond:
                raise ValueError(f"DetectionParams.{field}={getattr(self, field)!r}: {fix}")

        need(self.mode in ("ir", "visible"), "mode", "use 'ir' or 'visible'")
        need(self.threshold in ("sigma", "otsu", "fixed"), "threshold", "use 'sigma', 'otsu' or 'fixed'")
        need(self.k_sigma > 0, "k_sigma", "must be > 0")
        need(self.min_contrast >= 0, "min_contrast", "must be >= 0 grey levels")
        need(0 < self.fixed_threshold < 255, "fixed_threshold", "must be in (0, 255)")
        need(self.tophat_radius_px >= 1, "tophat_radius_px", "must be >= 1 pixel")
        need(1 <= self.min_area_px <= self.max_area_px, "min_area_px", f"need 1 <= min_area_px <= max_area_px ({self.max_area_px})")
        need(0 <= self.min_fill_ratio <= 1, "min_fill_ratio", "must be in [0, 1]")
        need(self.max_elongation >= 1, "max_elongation", "must be >= 1")
        need(self.dilate_px >= 0, "dilate_px", "must be >= 0")
        need(self.background_threshold >= 0, "background_threshold", "must be >= 0")
        need(self.mog2_history >= 1, "mog2_history", "must be >= 1")


def _to_gray(image: np.ndarray, what: str = "image") -> np.ndarray:
    img = np.asarray(image)
    if img.dtype != np.uint8:
        raise ValueError(f"{what} must be uint8 (0-255), got dtype {img.dtype}; convert with np.clip(x, 0, 255).astype(np.uint8)")
    if img.ndim == 2:
        return img
    if img.ndim == 3 and img.shape[2] == 3:
        return cv2.cvtColor(img, cv2.COLOR_RGB2GRAY)
    if img.ndim == 3 and img.shape[2] == 1:
        return img[:, :, 0]
    raise ValueError(f"{what} must be (H, W) grey or (H, W, 3) RGB, got shape {img.shape}")


def _median_u8(values: np.ndarray) -> float:
    """Median of non-negative integers < 256 by histogram (O(n), faster than a partition)."""
    hist = np.bincount(values.ravel(), minlength=256)
    return float(np.searchsorted(np.cumsum(hist), 0.5 * values.size))


def _noise_std(gray: np.ndarray) -> float:
    """Robust noise std (grey levels) from horizontal differences of every 8th row.

    Differences cancel smooth shading; the median absolute value ignores the sparse
    edges and markers. ``1.4826 * MAD / sqrt(2)`` is the std for Gaussian noise.
    """
    rows = gray[::8]
    d = cv2.absdiff(rows[:, 1:], rows[:, :-1])
    return 1.4826 * _median_u8(d) / np.sqrt(2.0)


def _signal_image(gray: np.ndarray, params: DetectionParams, background: np.ndarray | None) -> np.ndarray:
    """Frame minus its local background, uint8 (markers bright, background 0).

    Negative differences saturate at 0, which is what the centroid weights want anyway.
    """
    if params.mode == "visible":
        r = params.tophat_radius_px
        # A square element: OpenCV decomposes it into 1D passes (several times faster
        # than a disc) and it removes the same thing: anything the square cannot fit in.
        kernel = cv2.getStructuringElement(cv2.MORPH_RECT, (2 * r + 1, 2 * r + 1))
        signal = cv2.morphologyEx(gray, cv2.MORPH_TOPHAT, kernel)
    elif background is None:
        signal = cv2.subtract(gray, int(_median_u8(gray[::4, ::4])))
    else:
        signal = cv2.subtract(gray, background)
    if background is not None:
        # Only what is brighter than the static background can be a marker.
        moved = cv2.subtract(gray, background) > params.background_threshold
        signal = np.where(moved, signal, 0).astype(np.uint8)
    return signal


def _threshold(signal: np.ndarray, gray: np.ndarray, params: DetectionParams) -> float:
    if params.threshold == "fixed":
        return float(params.fixed_threshold)
    floor = float(params.min_contrast)
    noise = _noise_std(gray)
    if params.threshold == "sigma":
        return max(params.k_sigma * noise, floor)
    # Otsu on the bright tail: only pixels clearly above the noise take part, so the
    # split is between dim halo/clutter and the markers' cores.
    tail = signal[signal > max(3.0 * noise, 0.5 * floor)]
    if tail.size < 2 * params.min_area_px:
        return max(params.k_sigma * noise, floor)
    t_otsu, _ = cv2.threshold(tail.reshape(1, -1), 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
    return max(float(t_otsu), floor)


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
    gray = _to_gray(image)
    bg = None
    if background is not None:
        bg = _to_gray(background, "background")
        if bg.shape != gray.shape:
            raise ValueError(f"background is {bg.shape} but the image is {gray.shape}; use a background frame of the same camera")
    signal = _signal_image(gray, params, bg)
    thr = _threshold(signal, gray, params)
    _, mask = cv2.threshold(signal, thr, 1, cv2.THRESH_BINARY)
    if foreground_mask is not None:
        fg = np.asarray(foreground_mask)
        if fg.shape != gray.shape:
            raise ValueError(f"foreground_mask is {fg.shape} but the image is {gray.shape}")
        mask &= (fg > 0).astype(np.uint8)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8, ltype=cv2.CV_32S)
    if n <= 1:
        return Detections.empty()
    area = stats[:, cv2.CC_STAT_AREA].astype(np.float64)

    # Pixels of the blobs grown by dilate_px (their labels by max-dilation of the label
    # image; inside a blob this is the blob's own label). Working on this sparse pixel
    # list instead of whole-image arrays keeps the cost proportional to the blobs.
    k = 2 * params.dilate_px + 1
    kernel = np.ones((k, k), np.uint8)
    # cv2.dilate has no int32 support; uint16 is exact below 65536 blobs, float32 beyond.
    lab_img = labels.astype(np.uint16 if n < 65536 else np.float32)
    if params.dilate_px > 0:
        lab_img = cv2.dilate(lab_img, kernel)
        grown = cv2.dilate(mask, kernel)
    else:
        grown = mask
    pts = cv2.findNonZero(grown).reshape(-1, 2)
    px, py = pts[:, 0], pts[:, 1]
    lab = lab_img[py, px].astype(np.intp)
    core = mask[py, px].astype(bool)

    # Geometry of the thresholded blobs: unweighted second moments (all blobs at once).
    lc = lab[core]
    xc = px[core].astype(np.float64)
    yc = py[core].astype(np.float64)
    cnt = np.maximum(area, 1.0)
    mx = np.bincount(lc, xc, n) / cnt
    my = np.bincount(lc, yc, n) / cnt
    # Each pixel is a unit square: add its own variance 1/12 on the diagonal.
    sxx = np.bincount(lc, (xc - mx[lc]) ** 2, n) / cnt + 1.0 / 12.0
    syy = np.bincount(lc, (yc - my[lc]) ** 2, n) / cnt + 1.0 / 12.0
    sxy = np.bincount(lc, (xc - mx[lc]) * (yc - my[lc]), n) / cnt
    det = np.maximum(sxx * syy - sxy**2, 1e-12)
    fill = area / (4.0 * np.pi * np.sqrt(det))
    half_tr = 0.5 * (sxx + syy)
    disc = np.sqrt(np.maximum(half_tr**2 - det, 0.0))
    elong = np.sqrt((half_tr + disc) / np.maximum(half_tr - disc, 1e-12))
    keep = (
        (area >= params.min_area_px) & (area <= params.max_area_px)
        & (fill >= params.min_fill_ratio) & (elong <= params.max_elongation)
    )
    keep[0] = False
    if not keep.any():
        return Detections.empty()

    # Intensity-weighted centroid (weights: signal above the local background).
    wts = signal[py, px].astype(np.float64)
    sw = np.bincount(lab, wts, n)
    cx = np.bincount(lab, wts * px, n)
    cy = np.bincount(lab, wts * py, n)
    ok = keep & (sw > 0)
    xy = np.column_stack([cx[ok] / sw[ok], cy[ok] / sw[ok]])
    mean_grey = np.bincount(lc, gray[py[core], px[core]].astype(np.float64), n)[ok] / cnt[ok]
    return Detections(xy, area[ok], mean_grey)


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
            gray = _to_gray(frame, "frame")
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
