"""What the IR and visible detectors share: image checks, the noise estimate, the
threshold, connected components with their shape tests, and the background gate.

Coordinates follow OpenCV: x right, y down, pixel centres at integers.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from mocap.detection.params import DetectionParams


def to_gray(image: np.ndarray, what: str = "image") -> np.ndarray:
    img = check_image(image, what)
    if img.ndim == 2:
        return img
    return cv2.cvtColor(img, cv2.COLOR_RGB2GRAY)


def check_image(image: np.ndarray, what: str = "image") -> np.ndarray:
    """``(H, W)`` grey or ``(H, W, 3)`` RGB uint8 (a single-channel 3D array is squeezed)."""
    img = np.asarray(image)
    if img.dtype != np.uint8:
        raise ValueError(f"{what} must be uint8 (0-255), got dtype {img.dtype}; convert with np.clip(x, 0, 255).astype(np.uint8)")
    if img.ndim == 3 and img.shape[2] == 1:
        return img[:, :, 0]
    if img.ndim == 2 or (img.ndim == 3 and img.shape[2] == 3):
        return img
    raise ValueError(f"{what} must be (H, W) grey or (H, W, 3) RGB, got shape {img.shape}")


def median_u8(values: np.ndarray) -> float:
    """Median of non-negative integers < 256 by histogram (O(n), faster than a partition)."""
    hist = np.bincount(values.ravel(), minlength=256)
    return float(np.searchsorted(np.cumsum(hist), 0.5 * values.size))


# Noise from differences trimmed at their 90th percentile: E[d^2 | |d| <= q90] of a
# Gaussian difference is (1 - 2 * 1.645 * phi(1.645) / 0.9) = 0.623 of its variance.
_TRIM_CORRECTION = 1.0 / np.sqrt(0.623)


def noise_std(gray: np.ndarray) -> float:
    """Robust noise std (grey levels) from horizontal differences of every 4th row.

    Differences cancel smooth shading; trimming the largest 10 % ignores edges and
    markers. The RMS of the rest (not a median absolute deviation, which is 0 or 1 on
    8-bit frames whose noise is below a grey level, e.g. after JPEG) is scaled to the
    std of Gaussian noise (within ~10 % of it on integer-rounded noise of std >= 0.5).
    """
    rows = gray[::4]
    d = cv2.absdiff(rows[:, 1:], rows[:, :-1])
    # OpenCV's histogram: the same counts as np.bincount (exact in its float32 below 2^24
    # pixels), without bincount's copy of the image to intp (half of this function's time).
    hist = (cv2.calcHist([d], [0], None, [256], [0, 256]).ravel() if 0 < d.size < 2**24
            else np.bincount(d.ravel(), minlength=256)).astype(np.float64)
    q = int(np.searchsorted(np.cumsum(hist), 0.9 * d.size))
    h = hist[: q + 1]
    levels = np.arange(q + 1, dtype=np.float64)
    ms = float((h * levels**2).sum() / max(h.sum(), 1.0))
    return _TRIM_CORRECTION * np.sqrt(ms) / np.sqrt(2.0)


def threshold_level(signal: np.ndarray, noise: float, params: DetectionParams) -> float:
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
class Blobs:
    """Connected components of a mask and their geometry (index 0 is the background).

    ``px, py`` (P,) pixels of the blobs (``lab`` their labels), ``area`` (n,),
    ``mx, my`` (n,) unweighted centroids, ``keep`` (n,) bool: passed the shape tests.
    ``window`` is the label image of the part of the mask at ``origin`` ``(x0, y0)`` that holds
    every blob; :meth:`label_image` the whole mask's.
    """

    n: int
    window: np.ndarray
    origin: tuple[int, int]
    shape: tuple[int, int]
    px: np.ndarray
    py: np.ndarray
    lab: np.ndarray
    area: np.ndarray
    mx: np.ndarray
    my: np.ndarray
    keep: np.ndarray

    def label_image(self) -> np.ndarray:
        """``(H, W)`` int32 labels of the whole mask (0: background)."""
        out = np.zeros(self.shape, np.int32)
        x0, y0 = self.origin
        out[y0:y0 + self.window.shape[0], x0:x0 + self.window.shape[1]] = self.window
        return out


def find_blobs(mask: np.ndarray, params: DetectionParams, min_area_px: int | None = None) -> Blobs | None:
    """Components of a uint8 mask (non-zero: foreground) with area, fill-ratio and elongation tests (all blobs at
    once with ``np.bincount`` over the pixel list: cost proportional to the blobs)."""
    # Labelled in the bounding box of the mask's pixels only (a quarter of a 640x480 marker
    # frame or less), its corner rounded down to even coordinates: Grana's block-based
    # algorithm (BBDT) numbers the components in the raster order of the first 2x2 block
    # of each, so on the same block grid they get the labels they get in the whole mask.
    # No stats from OpenCV: on one core its stats pass cost 5x the labelling itself on
    # sparse masks (0.75 against 0.13 ms an image on the quickstart's frames); the areas
    # are counts of the pixels already listed, the background's the rest of the image.
    x, y, w, h = cv2.boundingRect(mask)
    if w == 0:
        return None
    x0, y0 = x - x % 2, y - y % 2
    window = mask[y0:y + h, x0:x + w]
    n, labels = cv2.connectedComponentsWithAlgorithm(window, 8, cv2.CV_32S, cv2.CCL_GRANA)
    if n <= 1:
        return None
    pts = cv2.findNonZero(window).reshape(-1, 2)
    lab = labels[pts[:, 1], pts[:, 0]].astype(np.intp)
    px, py = pts[:, 0] + np.int32(x0), pts[:, 1] + np.int32(y0)
    area = np.bincount(lab, minlength=n).astype(np.float64)
    area[0] = mask.size - len(pts)
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
    return Blobs(n, labels, (x0, y0), mask.shape, px, py, lab, area, mx, my, keep)


def blobs_with_small(mask: np.ndarray, signal: np.ndarray, thr: float, params: DetectionParams) -> Blobs | None:
    """:func:`find_blobs` of the mask, with blobs under ``min_area_px`` kept only when their peak
    ``signal`` is at least ``small_peak_factor * thr`` and their area at least
    ``small_area_fraction`` of the median of the larger blobs; None when no blob is kept."""
    min_area = params.resolved("min_area_px")
    b = find_blobs(mask, params, min_area_px=1 if params.small_peak_factor > 0 else None)
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


def gate(mask: np.ndarray, gray: np.ndarray, bg: np.ndarray | None, foreground_mask: np.ndarray | None,
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
