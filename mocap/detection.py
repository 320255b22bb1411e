"""Marker blob detection in camera frames.

One frame in, :class:`mocap.types.Detections` out. Two detectors share the
connected-component machinery and differ in what "brighter than its surroundings" means.

``"ir"`` (retro-reflective spheres lit by the camera's ring light, dark scene):

1. **Signal image**: the frame minus a *local* background level: the median of
   ``background_cells x background_cells`` cells of ``background_cell_px`` pixels around
   each pixel (an area-downsampled image, median-filtered, upsampled). A wall or floor
   lit brighter than the rest of the frame is background, not a carpet of noise peaks
   over a global level (the quickstart had ~26 such false blobs per image with the
   frame's median as background; none with the local one). A static background image,
   if given, is subtracted instead.
2. **Threshold**: ``k_sigma`` times the noise std (robust estimate from horizontal pixel
   differences), never below ``min_contrast`` grey levels; or Otsu on the bright tail of
   the signal histogram; or a fixed level.
3. **Connected components**, filtered on area, on *fill ratio* (blob area over the area
   of its moment-equivalent ellipse: ~1 for discs and for motion-blur streaks, low for
   rings, crosses, merged clutter) and on elongation (generous, so that streaks pass).
4. **Sub-pixel centroid**: intensity-weighted mean of the signal over each blob grown by
   ``dilate_px`` pixels (so that the dim skirt cut by the threshold still counts).

``"visible"`` (white/grey spheres of a few pixels on a lit, textured, coloured scene):

1. **Achromatic brightness**: ``min(R, G, B)`` of a colour frame. A white or grey marker
   keeps its brightness; skin, clothes and objects with colour lose theirs, so a grey
   marker on skin under a tungsten lamp still stands out. Grey frames are used as is.
2. **Local contrast at the marker's scale**: a white top-hat (frame minus its opening by
   a ``2 * tophat_radius_px + 1`` square) of the lightly smoothed image: what is left is
   any bright structure narrower than the square (markers, but also thin strips of
   background between limbs and corners of the background).
3. **Half-maximum blobs**: a pixel belongs to a blob when its top-hat value is above the
   threshold (as in IR) *and* above ``peak_fraction`` of the largest value within 2
   pixels. A marker touching a brighter strip or another bright structure is then cut
   off from it at the valley between the two instead of merging into one blob whose
   centroid is neither.
4. **Shape**: area, fill ratio and a *strict* elongation limit (a sphere's image is
   round; strips of background between limbs are long).
5. **Ring test**: the blob's peak must exceed the upper quartile (4th brightest of 16)
   of the smoothed image on a ring just outside it by ``ring_contrast`` grey levels. A
   piece of background framed by dark limbs is no brighter than the background it
   belongs to; a marker is brighter than most of what surrounds it even where it
   touches something bright on one side.
6. **Centroid**: a marker lit from above is a bright cap over a dim lower half, so its
   intensity centroid is pulled towards the light (0.3-0.5 px on 3-pixel markers in the
   office and dim presets). The centroid uses weights that saturate at
   ``shading_weight`` of the blob's peak over the local background (the opening), in a
   disc of the blob's radius + 1.5 px, re-centred twice. 0.7: on visible_office over seeds
   0-4, RMSE 2.11 mm (95 % CI 2.10-2.12) and no swap, against 2.55 (2.33-3.20) and 0.4
   swaps at 0.3 (why the flatter weights lose is not established; the shading pull is still
   there: the points sit 1.2 mm high on average); 1.0 gives 2.10 on seed 0.

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

# Defaults that differ between the two modes (a field left at None takes these).
_MODE_DEFAULTS: dict[str, dict[str, float]] = {
    "ir": {"k_sigma": 6.0, "min_contrast": 20.0, "min_area_px": 3, "min_fill_ratio": 0.6, "max_elongation": 30.0},
    # Visible: measured on visible_office (office, tungsten, dim presets, JPEG 75/90) and
    # dim_gym_noisy with scripts/detection_eval.py; markers there are 2-4 px across and
    # 10-60 grey levels above their surroundings.
    "visible": {"k_sigma": 4.0, "min_contrast": 10.0, "min_area_px": 2, "min_fill_ratio": 0.5, "max_elongation": 3.0},
}


@dataclass(frozen=True)
class DetectionParams:
    """Settings of :func:`detect_markers`.

    Fields left at ``None`` take the mode's default (``_MODE_DEFAULTS``: IR, visible).

    Attributes
    ----------
    mode : {"ir", "visible"}
        ``"ir"``: bright markers on a dark scene, local median background.
        ``"visible"``: white/grey markers on a lit subject, local top-hat contrast.
    threshold : {"sigma", "otsu", "fixed"}
        How the signal threshold is chosen (see module doc).
    k_sigma : float or None
        ``"sigma"`` threshold in noise standard deviations (IR 6, visible 4).
    min_contrast : float or None
        Lowest threshold above the local background, grey levels (IR 20, visible 10).
    fixed_threshold : float
        Threshold above the background for ``threshold="fixed"``, grey levels.
    tophat_radius_px : int
        ``"visible"``: radius of the top-hat square; markers up to about
        ``2 * tophat_radius_px`` pixels across are kept whole, wider bright regions are
        background.
    background_cell_px, background_cells : int
        ``"ir"``: the local background is the median of ``background_cells`` x
        ``background_cells`` cells of ``background_cell_px`` pixels (blobs up to about
        half that span across are not part of it).
    min_area_px : int or None
        Smallest accepted blob (thresholded pixels; IR 3, visible 2).
    small_peak_factor : float
        A blob smaller than ``min_area_px`` (down to one pixel) is still accepted
        when its peak is at least this many times the threshold above the background. A
        14 mm marker 4-5 m from a 640x480 camera is 1-2 pixels across; noise that crosses
        the threshold barely does (on bvh_walk with 4 cameras the true 1-2 pixel blobs peak
        at 2.4x the threshold or more in 95 % of cases, median 4.2x). 0 disables.
    small_area_fraction : float
        Such a blob must also be at least this fraction of the median area of the
        image's blobs of ``min_area_px`` or more (where markers are 15-20 px, a 1-2 px blob is
        the sliver of a marker hidden behind the body, not a distant marker).
    max_area_px : int
        Largest accepted blob (thresholded pixels).
    min_fill_ratio : float or None
        Minimum blob area / area of the ellipse with the blob's second moments
        (IR 0.6, visible 0.5).
    max_elongation : float or None
        Maximum ratio of the ellipse's axes (IR 30: motion-blur streaks pass; visible 3:
        strips of background between limbs do not).
    dilate_px : int
        ``"ir"``: width of the ring of dim pixels around each blob included in the centroid.
    achromatic : bool
        ``"visible"``: detect on ``min(R, G, B)`` of colour frames (white/grey markers).
    peak_fraction : float
        ``"visible"``: a blob is the pixels above this fraction of the local maximum of
        the top-hat (half maximum by default).
    ring_contrast : float
        ``"visible"``: grey levels the blob's peak must exceed the upper quartile of a
        ring just outside it by.
    shading_weight : float
        ``"visible"``: centroid weights saturate at this fraction of the blob's peak
        (1 = plain intensity weights).
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
    k_sigma: float | None = None
    min_contrast: float | None = None
    fixed_threshold: float = 100.0
    tophat_radius_px: int = 3
    background_cell_px: int = 8
    background_cells: int = 5
    min_area_px: int | None = None
    small_peak_factor: float = 2.0
    small_area_fraction: float = 0.2
    max_area_px: int = 2000
    min_fill_ratio: float | None = None
    max_elongation: float | None = None
    dilate_px: int = 1
    achromatic: bool = True
    peak_fraction: float = 0.5
    ring_contrast: float = 8.0
    shading_weight: float = 0.7
    background_threshold: float = 15.0
    mog2_history: int = 200
    mog2_var_threshold: float = 16.0

    def __post_init__(self) -> None:
        def need(cond: bool, field: str, fix: str) -> None:
            if not cond:
                raise ValueError(f"DetectionParams.{field}={getattr(self, field)!r}: {fix}")

        def opt(field: str) -> float:
            v = getattr(self, field)
            return 1.0 if v is None else v  # None is valid (the mode's default)

        need(self.mode in ("ir", "visible"), "mode", "use 'ir' or 'visible'")
        need(self.threshold in ("sigma", "otsu", "fixed"), "threshold", "use 'sigma', 'otsu' or 'fixed'")
        need(opt("k_sigma") > 0, "k_sigma", "must be > 0 (or None: the mode's default)")
        need(opt("min_contrast") >= 0, "min_contrast", "must be >= 0 grey levels (or None)")
        need(0 < self.fixed_threshold < 255, "fixed_threshold", "must be in (0, 255)")
        need(self.tophat_radius_px >= 1, "tophat_radius_px", "must be >= 1 pixel")
        need(self.background_cell_px >= 1, "background_cell_px", "must be >= 1 pixel")
        need(self.background_cells >= 1 and self.background_cells % 2 == 1, "background_cells", "must be an odd number >= 1")
        need(1 <= opt("min_area_px") <= self.max_area_px, "min_area_px", f"need 1 <= min_area_px <= max_area_px ({self.max_area_px})")
        need(0 <= opt("min_fill_ratio") <= 1, "min_fill_ratio", "must be in [0, 1]")
        need(opt("max_elongation") >= 1, "max_elongation", "must be >= 1")
        need(self.dilate_px >= 0, "dilate_px", "must be >= 0")
        need(0 <= self.peak_fraction < 1, "peak_fraction", "must be in [0, 1)")
        need(self.small_peak_factor >= 0, "small_peak_factor", "must be >= 0 (0: no blob under min_area_px)")
        need(0 <= self.small_area_fraction <= 1, "small_area_fraction", "must be in [0, 1]")
        need(self.ring_contrast >= 0, "ring_contrast", "must be >= 0 grey levels")
        need(0 < self.shading_weight <= 1, "shading_weight", "must be in (0, 1]")
        need(self.background_threshold >= 0, "background_threshold", "must be >= 0")
        need(self.mog2_history >= 1, "mog2_history", "must be >= 1")

    def resolved(self, field: str) -> float:
        """The value of a mode-dependent field (its mode default when left at None)."""
        v = getattr(self, field)
        return _MODE_DEFAULTS[self.mode][field] if v is None else v


def _to_gray(image: np.ndarray, what: str = "image") -> np.ndarray:
    img = _check_image(image, what)
    if img.ndim == 2:
        return img
    return cv2.cvtColor(img, cv2.COLOR_RGB2GRAY)


def _check_image(image: np.ndarray, what: str = "image") -> np.ndarray:
    """``(H, W)`` grey or ``(H, W, 3)`` RGB uint8 (a single-channel 3D array is squeezed)."""
    img = np.asarray(image)
    if img.dtype != np.uint8:
        raise ValueError(f"{what} must be uint8 (0-255), got dtype {img.dtype}; convert with np.clip(x, 0, 255).astype(np.uint8)")
    if img.ndim == 3 and img.shape[2] == 1:
        return img[:, :, 0]
    if img.ndim == 2 or (img.ndim == 3 and img.shape[2] == 3):
        return img
    raise ValueError(f"{what} must be (H, W) grey or (H, W, 3) RGB, got shape {img.shape}")


def _median_u8(values: np.ndarray) -> float:
    """Median of non-negative integers < 256 by histogram (O(n), faster than a partition)."""
    hist = np.bincount(values.ravel(), minlength=256)
    return float(np.searchsorted(np.cumsum(hist), 0.5 * values.size))


# Noise from differences trimmed at their 90th percentile: E[d^2 | |d| <= q90] of a
# Gaussian difference is (1 - 2 * 1.645 * phi(1.645) / 0.9) = 0.623 of its variance.
_TRIM_CORRECTION = 1.0 / np.sqrt(0.623)


def _noise_std(gray: np.ndarray) -> float:
    """Robust noise std (grey levels) from horizontal differences of every 4th row.

    Differences cancel smooth shading; trimming the largest 10 % ignores edges and
    markers. The RMS of the rest (not a median absolute deviation, which is 0 or 1 on
    8-bit frames whose noise is below a grey level, e.g. after JPEG) is scaled to the
    std of Gaussian noise (within ~10 % of it on integer-rounded noise of std >= 0.5).
    """
    rows = gray[::4]
    d = cv2.absdiff(rows[:, 1:], rows[:, :-1])
    hist = np.bincount(d.ravel(), minlength=256).astype(np.float64)
    q = int(np.searchsorted(np.cumsum(hist), 0.9 * d.size))
    h = hist[: q + 1]
    levels = np.arange(q + 1, dtype=np.float64)
    ms = float((h * levels**2).sum() / max(h.sum(), 1.0))
    return _TRIM_CORRECTION * np.sqrt(ms) / np.sqrt(2.0)


def _local_background(gray: np.ndarray, cell: int, cells: int) -> np.ndarray:
    """Median background level around each pixel, uint8 ``(H, W)``.

    The median of ``cells x cells`` cell means (area-downsampled image, median filter,
    bilinear upsampling): blobs covering less than about half of that span are not part
    of it. Cheaper than a full-resolution median filter of the same span by ~cell^2.
    """
    h, w = gray.shape
    sh, sw = max(h // cell, 1), max(w // cell, 1)
    if min(sh, sw) < cells:
        return np.full_like(gray, int(_median_u8(gray)))
    small = cv2.resize(gray, (sw, sh), interpolation=cv2.INTER_AREA)
    if cells > 1:
        small = cv2.medianBlur(small, cells)
    return cv2.resize(small, (w, h), interpolation=cv2.INTER_LINEAR)


def _threshold(signal: np.ndarray, noise: float, params: DetectionParams) -> float:
    if params.threshold == "fixed":
        return float(params.fixed_threshold)
    floor = float(params.resolved("min_contrast"))
    k_sigma = params.resolved("k_sigma")
    if params.threshold == "sigma":
        return max(k_sigma * noise, floor)
    # Otsu on the bright tail: only pixels clearly above the noise take part, so the
    # split is between dim halo/clutter and the markers' cores.
    tail = signal[signal > max(3.0 * noise, 0.5 * floor)]
    if tail.size < 2 * params.resolved("min_area_px"):
        return max(k_sigma * noise, floor)
    t_otsu, _ = cv2.threshold(tail.reshape(1, -1), 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
    return max(float(t_otsu), floor)


@dataclass
class _Blobs:
    """Connected components of a mask and their geometry (index 0 is the background).

    ``px, py`` (P,) pixels of the blobs (``lab`` their labels), ``area`` (n,),
    ``mx, my`` (n,) unweighted centroids, ``keep`` (n,) bool: passed the shape tests.
    """

    n: int
    labels: np.ndarray
    px: np.ndarray
    py: np.ndarray
    lab: np.ndarray
    area: np.ndarray
    mx: np.ndarray
    my: np.ndarray
    keep: np.ndarray


def _blobs(mask: np.ndarray, params: DetectionParams, min_area_px: int | None = None) -> _Blobs | None:
    """Components of a uint8 mask (non-zero: foreground) with area, fill-ratio and elongation tests (all blobs at
    once with ``np.bincount`` over the pixel list: cost proportional to the blobs)."""
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8, ltype=cv2.CV_32S)
    if n <= 1:
        return None
    area = stats[:, cv2.CC_STAT_AREA].astype(np.float64)
    pts = cv2.findNonZero(mask).reshape(-1, 2)
    px, py = pts[:, 0], pts[:, 1]
    lab = labels[py, px].astype(np.intp)
    x = px.astype(np.float64)
    y = py.astype(np.float64)
    cnt = np.maximum(area, 1.0)
    mx = np.bincount(lab, x, n) / cnt
    my = np.bincount(lab, y, n) / cnt
    # Each pixel is a unit square: add its own variance 1/12 on the diagonal.
    sxx = np.bincount(lab, (x - mx[lab]) ** 2, n) / cnt + 1.0 / 12.0
    syy = np.bincount(lab, (y - my[lab]) ** 2, n) / cnt + 1.0 / 12.0
    sxy = np.bincount(lab, (x - mx[lab]) * (y - my[lab]), n) / cnt
    det = np.maximum(sxx * syy - sxy**2, 1e-12)
    fill = area / (4.0 * np.pi * np.sqrt(det))
    half_tr = 0.5 * (sxx + syy)
    disc = np.sqrt(np.maximum(half_tr**2 - det, 0.0))
    elong = np.sqrt((half_tr + disc) / np.maximum(half_tr - disc, 1e-12))
    keep = (
        (area >= (params.resolved("min_area_px") if min_area_px is None else min_area_px)) & (area <= params.max_area_px)
        & (fill >= params.resolved("min_fill_ratio")) & (elong <= params.resolved("max_elongation"))
    )
    keep[0] = False
    return _Blobs(n, labels, px, py, lab, area, mx, my, keep)


def _blobs_with_small(mask: np.ndarray, signal: np.ndarray, thr: float, params: DetectionParams) -> _Blobs | None:
    """:func:`_blobs` of the mask, with blobs under ``min_area_px`` kept only when their peak
    ``signal`` is at least ``small_peak_factor * thr`` and their area at least
    ``small_area_fraction`` of the median of the larger blobs; None when no blob is kept."""
    min_area = params.resolved("min_area_px")
    b = _blobs(mask, params, min_area_px=1 if params.small_peak_factor > 0 else None)
    if b is None or not b.keep.any():
        return None
    small = b.keep & (b.area < min_area)
    if small.any():
        # Tiny blobs only when clearly brighter than the threshold, and only where the
        # image's markers are small anyway: beside markers of 15-20 px a blob of one or two
        # is a sliver of a hidden marker, its centroid off by a pixel or more.
        peak = np.zeros(b.n)
        np.maximum.at(peak, b.lab, signal[b.py, b.px].astype(np.float64))
        large = b.keep & ~small
        typical = float(np.median(b.area[large])) if large.any() else 0.0
        b.keep &= ~small | ((peak >= params.small_peak_factor * thr) & (b.area >= params.small_area_fraction * typical))
    return b if b.keep.any() else None


def _gate(mask: np.ndarray, gray: np.ndarray, bg: np.ndarray | None, foreground_mask: np.ndarray | None,
          params: DetectionParams) -> np.ndarray:
    """Keep mask pixels (non-zero) brighter than a static background / inside a
    foreground mask; the others are set to 0."""
    if bg is not None:
        moved = cv2.compare(cv2.subtract(gray, bg), params.background_threshold, cv2.CMP_GT)
        mask = np.where(moved > 0, mask, 0).astype(np.uint8)
    if foreground_mask is not None:
        fg = np.asarray(foreground_mask)
        if fg.shape != gray.shape:
            raise ValueError(f"foreground_mask is {fg.shape} but the image is {gray.shape}")
        mask = np.where(fg > 0, mask, 0).astype(np.uint8)
    return mask


def _detect_ir(gray: np.ndarray, params: DetectionParams, bg: np.ndarray | None,
               foreground_mask: np.ndarray | None) -> Detections:
    if bg is None:
        signal = cv2.subtract(gray, _local_background(gray, params.background_cell_px, params.background_cells))
    else:
        signal = cv2.subtract(gray, bg)
    thr = _threshold(signal, _noise_std(gray), params)
    _, mask = cv2.threshold(signal, thr, 1, cv2.THRESH_BINARY)
    mask = _gate(mask, gray, bg, foreground_mask, params)
    b = _blobs_with_small(mask, signal, thr, params)
    if b is None:
        return Detections.empty()
    n = b.n
    # Pixels of the blobs grown by dilate_px (their labels by max-dilation of the label
    # image; inside a blob this is the blob's own label).
    k = 2 * params.dilate_px + 1
    kernel = np.ones((k, k), np.uint8)
    # cv2.dilate has no int32 support; uint16 is exact below 65536 blobs, float32 beyond.
    lab_img = b.labels.astype(np.uint16 if n < 65536 else np.float32)
    if params.dilate_px > 0:
        lab_img = cv2.dilate(lab_img, kernel)
        grown = cv2.dilate(mask, kernel)
    else:
        grown = mask
    pts = cv2.findNonZero(grown).reshape(-1, 2)
    px, py = pts[:, 0], pts[:, 1]
    lab = lab_img[py, px].astype(np.intp)
    # Intensity-weighted centroid (weights: signal above the local background).
    wts = signal[py, px].astype(np.float64)
    sw = np.bincount(lab, wts, n)
    cx = np.bincount(lab, wts * px, n)
    cy = np.bincount(lab, wts * py, n)
    ok = b.keep & (sw > 0)
    xy = np.column_stack([cx[ok] / sw[ok], cy[ok] / sw[ok]])
    cnt = np.maximum(b.area, 1.0)
    mean_grey = np.bincount(b.lab, gray[b.py, b.px].astype(np.float64), n)[ok] / cnt[ok]
    return Detections(xy, b.area[ok], mean_grey)


def _achromatic(img: np.ndarray) -> np.ndarray:
    """``min(R, G, B)`` ``(H, W)`` of an RGB frame (a grey frame is returned as is).

    Computed as a 1x3 erosion of the frame seen as one ``(H, 3W)`` plane, sampled at
    each pixel's middle channel: one SIMD pass, ~10x faster than ``cv2.split`` + two
    ``cv2.min`` (which allocate three planes) or ``img.min(axis=2)``.
    """
    if img.ndim == 2:
        return img
    h, w, _ = img.shape
    plane = np.ascontiguousarray(img).reshape(h, 3 * w)
    eroded = cv2.erode(plane, np.ones((1, 3), np.uint8))
    return np.ascontiguousarray(eroded[:, 1::3])


# 16 ring directions of the visible ring test.
_RING_COS = np.cos(np.arange(16) * np.pi / 8)
_RING_SIN = np.sin(np.arange(16) * np.pi / 8)


def _detect_visible(img: np.ndarray, gray: np.ndarray, params: DetectionParams, bg: np.ndarray | None,
                    foreground_mask: np.ndarray | None) -> Detections:
    base = _achromatic(img) if params.achromatic else gray
    h, w = base.shape
    smooth = cv2.GaussianBlur(base, (3, 3), 0.7)
    r = params.tophat_radius_px
    # A square element: OpenCV decomposes it into 1D passes (several times faster than a
    # disc) and it removes the same thing: anything the square cannot fit in.
    opened = cv2.morphologyEx(smooth, cv2.MORPH_OPEN, cv2.getStructuringElement(cv2.MORPH_RECT, (2 * r + 1, 2 * r + 1)))
    signal = cv2.subtract(smooth, opened)
    thr = _threshold(signal, _noise_std(base), params)
    # Half-maximum blobs: above the threshold and above peak_fraction of the local maximum.
    local_max = cv2.dilate(signal, np.ones((5, 5), np.uint8))
    # level(v) = max(ceil(peak_fraction * v), ceil(thr)) as a lookup table over the 256
    # grey levels (cheaper than float images); mask is 255 where signal >= level.
    lut = np.maximum(np.ceil(params.peak_fraction * np.arange(256)), np.ceil(thr)).clip(0, 256)
    if lut.max() > 255:  # a threshold above 255 grey levels: nothing can pass
        return Detections.empty()
    level = cv2.LUT(local_max, lut.astype(np.uint8))
    mask = cv2.compare(signal, level, cv2.CMP_GE)
    mask = _gate(mask, gray, bg, foreground_mask, params)
    b = _blobs_with_small(mask, signal, thr, params)
    if b is None:
        return Detections.empty()
    n = b.n
    # Ring test: peak of the smoothed image over the upper quartile of 16 samples on a
    # ring 1.5 px outside the blob's equivalent disc.
    peak = np.zeros(n, np.float32)
    np.maximum.at(peak, b.lab, smooth[b.py, b.px].astype(np.float32))
    idx = np.flatnonzero(b.keep)
    rho = np.sqrt(b.area[idx] / np.pi)
    rad = rho + 1.5
    rx = np.clip(np.rint(b.mx[idx, None] + rad[:, None] * _RING_COS), 0, w - 1).astype(np.intp)
    ry = np.clip(np.rint(b.my[idx, None] + rad[:, None] * _RING_SIN), 0, h - 1).astype(np.intp)
    upper_quartile = np.partition(smooth[ry, rx], 12, axis=1)[:, 12].astype(np.float32)
    passed = peak[idx] - upper_quartile >= params.ring_contrast
    idx, rho = idx[passed], rho[passed]
    if len(idx) == 0:
        return Detections.empty()
    cx, cy = _shading_robust_centroids(cv2.subtract(base, opened), b.mx[idx], b.my[idx], rho + 1.5,
                                       params.shading_weight, r + 2)
    cnt = np.maximum(b.area, 1.0)
    mean_grey = (np.bincount(b.lab, gray[b.py, b.px].astype(np.float64), n) / cnt)[idx]
    return Detections(np.column_stack([cx, cy]), b.area[idx], mean_grey)


def _shading_robust_centroids(signal: np.ndarray, x0: np.ndarray, y0: np.ndarray, radius: np.ndarray,
                              saturation: float, half: int, iterations: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """Centroids ``(k,), (k,)`` px of ``signal`` (uint8, above local background) in discs
    of ``radius`` (k,) px around ``x0, y0`` (k,), weights saturating at ``saturation`` of
    each disc's peak, re-centred ``iterations`` times.

    The disc edge is a 1-pixel linear taper in the distance to the current centre, so
    the weights move continuously with it (no locking to pixel centres). Vectorised over
    blobs in ``(2 * half + 1)^2`` windows (hand-written: OpenCV's moments work per blob).
    """
    h, w = signal.shape
    o = np.arange(-half, half + 1)
    ox, oy = (a.ravel() for a in np.meshgrid(o, o))
    cx, cy = x0.astype(np.float64), y0.astype(np.float64)
    for _ in range(iterations):
        xs = np.rint(cx).astype(np.intp)[:, None] + ox
        ys = np.rint(cy).astype(np.intp)[:, None] + oy
        inside = (xs >= 0) & (xs < w) & (ys >= 0) & (ys < h)
        v = signal[np.clip(ys, 0, h - 1), np.clip(xs, 0, w - 1)].astype(np.float64) * inside
        taper = np.clip(radius[:, None] + 0.5 - np.hypot(xs - cx[:, None], ys - cy[:, None]), 0.0, 1.0)
        v *= taper
        top = np.maximum(v.max(axis=1, keepdims=True) * saturation, 1e-9)
        wts = np.minimum(v / top, taper)
        sw = wts.sum(axis=1)
        good = sw > 0
        cx = np.where(good, (wts * xs).sum(axis=1) / np.where(good, sw, 1.0), cx)
        cy = np.where(good, (wts * ys).sum(axis=1) / np.where(good, sw, 1.0), cy)
    return cx, cy


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
    img = _check_image(image)
    gray = _to_gray(img)
    bg = None
    if background is not None:
        bg = _to_gray(background, "background")
        if bg.shape != gray.shape:
            raise ValueError(f"background is {bg.shape} but the image is {gray.shape}; use a background frame of the same camera")
    if params.mode == "visible":
        return _detect_visible(img, gray, params, bg, foreground_mask)
    return _detect_ir(gray, params, bg, foreground_mask)


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
