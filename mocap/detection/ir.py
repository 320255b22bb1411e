"""The IR detector: retro-reflective spheres lit by the camera's ring light, dark scene.

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
4. **Sub-pixel centroid**: mean of the pixels of each blob grown by ``dilate_px`` pixels
   (so that the dim skirt cut by the threshold still counts), weighted by their *light* above
   the local background: grey levels decoded through the camera's transfer function
   (``response``, sRGB for webcams) first, since the encoded levels flatten a small blob's
   profile and pull its centroid towards the pixel centres.
"""

from __future__ import annotations

import cv2
import numpy as np

from mocap.detection.blobs import Blobs, blobs_with_small, gate, median_u8, noise_std, threshold_level
from mocap.detection.params import DetectionParams
from mocap.srgb import SRGB_TO_LINEAR
from mocap.types import Detections


def local_background(gray: np.ndarray, cell: int, cells: int) -> np.ndarray:
    """Median background level around each pixel, uint8 ``(H, W)``.

    The median of ``cells x cells`` cell means (area-downsampled image, median filter,
    bilinear upsampling): blobs covering less than about half of that span are not part
    of it. Cheaper than a full-resolution median filter of the same span by ~cell^2.
    """
    h, w = gray.shape
    sh, sw = max(h // cell, 1), max(w // cell, 1)
    if min(sh, sw) < cells:
        return np.full_like(gray, int(median_u8(gray)))
    small = cv2.resize(gray, (sw, sh), interpolation=cv2.INTER_AREA)
    if cells > 1:
        small = cv2.medianBlur(small, cells)
    return cv2.resize(small, (w, h), interpolation=cv2.INTER_LINEAR)


def grown_pixels(b: Blobs, mask: np.ndarray, d: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The pixels within ``d`` (chessboard distance) of the blobs' pixels in raster order, and
    for each the largest blob label within ``d``: ``cv2.findNonZero(cv2.dilate(mask, k))`` and
    ``cv2.dilate(labels, k)`` at those pixels, ``k`` a ``(2d+1)``-square kernel.

    On a marker frame the blobs cover a few hundred pixels, so these are found from the blob
    pixels themselves (each pixel's neighbours, sorted to raster order, the largest label of
    each kept), not by two full-image dilations and a full-image scan: the same pixels, in the
    same order (the centroid sums add in the same order, to the same bits) and with the same
    labels. Where the blobs cover much of the image, the dilations are cheaper."""
    h, w = mask.shape
    k = 2 * d + 1
    if len(b.px) * k * k > h * w // 16:
        # cv2.dilate has no int32 support; uint16 is exact below 65536 blobs, float32 beyond.
        lab_img = cv2.dilate(b.label_image().astype(np.uint16 if b.n < 65536 else np.float32), np.ones((k, k), np.uint8))
        pts = cv2.findNonZero(cv2.dilate(mask, np.ones((k, k), np.uint8))).reshape(-1, 2)
        return pts[:, 0], pts[:, 1], lab_img[pts[:, 1], pts[:, 0]].astype(np.intp)
    off = np.arange(-d, d + 1)
    x = (b.px.astype(np.intp)[None, :] + np.tile(off, k)[:, None]).ravel()
    y = (b.py.astype(np.intp)[None, :] + np.repeat(off, k)[:, None]).ravel()
    inside = (x >= 0) & (x < w) & (y >= 0) & (y < h)
    # One sort key: raster index, then label (so a pixel's largest label comes last).
    v = np.sort((y[inside] * w + x[inside]) * b.n + np.broadcast_to(b.lab, (k * k, len(b.lab))).ravel()[inside])
    v = v[np.append(v[1:] // b.n != v[:-1] // b.n, True)]
    key = v // b.n
    return key % w, key // w, v % b.n


def detect_ir(gray: np.ndarray, params: DetectionParams, bg: np.ndarray | None,
               foreground_mask: np.ndarray | None) -> Detections:
    if bg is None:
        bg_level = local_background(gray, params.background_cell_px, params.background_cells)
    else:
        bg_level = bg
    signal = cv2.subtract(gray, bg_level)
    thr = threshold_level(signal, noise_std(gray), params)
    _, mask = cv2.threshold(signal, thr, 1, cv2.THRESH_BINARY)
    mask = gate(mask, gray, bg, foreground_mask, params)
    b = blobs_with_small(mask, signal, thr, params)
    if b is None:
        return Detections.empty()
    n = b.n
    # Pixels of the blobs grown by dilate_px, each with its blob's label (the largest label
    # within reach, as a max-dilation of the label image gives).
    px, py, lab = grown_pixels(b, mask, params.dilate_px)
    # Light-weighted centroid (weights: light above the local background).
    if params.response == "srgb":
        wts = np.maximum(SRGB_TO_LINEAR[gray[py, px]] - SRGB_TO_LINEAR[bg_level[py, px]], 0.0)
    else:
        wts = signal[py, px].astype(np.float64)
    sw = np.bincount(lab, wts, n)
    cx = np.bincount(lab, wts * px, n)
    cy = np.bincount(lab, wts * py, n)
    ok = b.keep & (sw > 0)
    xy = np.column_stack([cx[ok] / sw[ok], cy[ok] / sw[ok]])
    cnt = np.maximum(b.area, 1.0)
    mean_grey = np.bincount(b.lab, gray[b.py, b.px].astype(np.float64), n)[ok] / cnt[ok]
    return Detections(xy, b.area[ok], mean_grey)
