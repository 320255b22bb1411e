"""The visible detector: white/grey spheres of a few pixels on a lit, textured, coloured scene.

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
7. **Lit limb** (:func:`lit_limbs`): the image's light direction (from the steepness of the
   blobs' edges) and each blob's distance to the half-maximum edge of its lit limb, which
   lies on the silhouette whatever the shading. The detector cannot use it alone: it needs
   the marker's image radius, known once the marker is triangulated
   (:func:`mocap.marker_pipeline.limb_centroids`, ``MarkerPipelineParams.marker_radius_m``).
"""

from __future__ import annotations

import cv2
import numpy as np

from mocap.detection.blobs import blobs_with_small, gate, noise_std, threshold_level
from mocap.detection.params import DetectionParams
from mocap.types import Detections


def achromatic_brightness(img: np.ndarray) -> np.ndarray:
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


def detect_visible(img: np.ndarray, gray: np.ndarray, params: DetectionParams, bg: np.ndarray | None,
                    foreground_mask: np.ndarray | None) -> Detections:
    base = achromatic_brightness(img) if params.achromatic else gray
    h, w = base.shape
    smooth = cv2.GaussianBlur(base, (3, 3), 0.7)
    r = params.tophat_radius_px
    # A square element: OpenCV decomposes it into 1D passes (several times faster than a
    # disc) and it removes the same thing: anything the square cannot fit in.
    opened = cv2.morphologyEx(smooth, cv2.MORPH_OPEN, cv2.getStructuringElement(cv2.MORPH_RECT, (2 * r + 1, 2 * r + 1)))
    signal = cv2.subtract(smooth, opened)
    thr = threshold_level(signal, noise_std(base), params)
    # Half-maximum blobs: above the threshold and above peak_fraction of the local maximum.
    local_max = cv2.dilate(signal, np.ones((5, 5), np.uint8))
    # level(v) = max(ceil(peak_fraction * v), ceil(thr)) as a lookup table over the 256
    # grey levels (cheaper than float images); mask is 255 where signal >= level.
    lut = np.maximum(np.ceil(params.peak_fraction * np.arange(256)), np.ceil(thr)).clip(0, 256)
    if lut.max() > 255:  # a threshold above 255 grey levels: nothing can pass
        return Detections.empty()
    level = cv2.LUT(local_max, lut.astype(np.uint8))
    mask = cv2.compare(signal, level, cv2.CMP_GE)
    mask = gate(mask, gray, bg, foreground_mask, params)
    b = blobs_with_small(mask, signal, thr, params)
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
    above = cv2.subtract(base, opened)
    cx, cy = shading_robust_centroids(above, b.mx[idx], b.my[idx], rho + 1.5, params.shading_weight, r + 2)
    cnt = np.maximum(b.area, 1.0)
    mean_grey = (np.bincount(b.lab, gray[b.py, b.px].astype(np.float64), n) / cnt)[idx]
    limb_dir, limb_dist = lit_limbs(above, cx, cy)
    return Detections(np.column_stack([cx, cy]), b.area[idx], mean_grey, limb_dir, limb_dist)


def shading_robust_centroids(signal: np.ndarray, x0: np.ndarray, y0: np.ndarray, radius: np.ndarray,
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


# Lit limbs: rays from each centroid, samples along them, the shared direction's consistency.
_LIMB_RAYS = 16
_LIMB_COS = np.cos(np.arange(_LIMB_RAYS) * 2 * np.pi / _LIMB_RAYS)
_LIMB_SIN = np.sin(np.arange(_LIMB_RAYS) * 2 * np.pi / _LIMB_RAYS)
_LIMB_STEP = 0.05
_LIMB_T = np.arange(0.0, 4.0 + 1e-9, _LIMB_STEP)
#: The image has a light direction when its blobs' shading directions pass a Rayleigh test
#: against uniform directions at 5 %: ``n * R**2 > 3.0``, ``R`` their mean resultant length.
LIMB_RAYLEIGH_Z = 3.0


def _bilinear(img: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    h, w = img.shape
    x = np.clip(x, 0.0, w - 1.001)
    y = np.clip(y, 0.0, h - 1.001)
    x0 = x.astype(np.intp)
    y0 = y.astype(np.intp)
    fx, fy = x - x0, y - y0
    return (img[y0, x0] * (1 - fx) * (1 - fy) + img[y0, x0 + 1] * fx * (1 - fy)
            + img[y0 + 1, x0] * (1 - fx) * fy + img[y0 + 1, x0 + 1] * fx * fy)


def _half_max_edges(profile: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distance along ``_LIMB_T`` where each profile ``(..., T)`` first falls below half its
    maximum within 2 px (after that maximum), linearly interpolated, NaN if it never does;
    and the profile's slope there (grey levels / px, positive when falling)."""
    nt = len(_LIMB_T)
    am = np.argmax(np.where(_LIMB_T <= 2.0, profile, -np.inf), axis=-1)
    pk = np.take_along_axis(profile, am[..., None], -1)[..., 0]
    below = (profile < 0.5 * pk[..., None]) & (np.arange(nt) > am[..., None])
    j = np.maximum(np.argmax(below, axis=-1), 1)
    p1 = np.take_along_axis(profile, j[..., None] - 1, -1)[..., 0]
    p2 = np.take_along_axis(profile, j[..., None], -1)[..., 0]
    t = _LIMB_T[j - 1] + _LIMB_STEP * np.clip((p1 - 0.5 * pk) / np.maximum(p1 - p2, 1e-9), 0.0, 1.0)
    lo, hi = np.clip(j - 10, 0, nt - 1), np.clip(j + 10, 0, nt - 1)
    slope = (np.take_along_axis(profile, lo[..., None], -1)[..., 0]
             - np.take_along_axis(profile, hi[..., None], -1)[..., 0]) / (_LIMB_T[hi] - _LIMB_T[lo])
    ok = below.any(axis=-1) & (pk > 0)
    return np.where(ok, t, np.nan), np.where(ok, slope, 0.0)


def lit_limbs(signal: np.ndarray, cx: np.ndarray, cy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The image's light direction and each blob's lit limb: ``(k, 2)`` unit directions and
    ``(k,)`` distances (px) from ``(cx, cy)`` along them to the half-maximum edge of
    ``signal`` (light above the local background); NaN distances where not measured.

    A sphere lit from one side has a sharp, bright limb on that side and a soft terminator
    on the other: its image is brightest towards the light and fades out before its
    silhouette on the far side, so any centroid of its light (or of a mask of it) lies
    towards the light (on visible_office 0.3 px up, 0.3-0.85 px for markers near the
    ceiling lights or the floor). The lit limb's half-maximum edge, by contrast, sits on the
    silhouette whatever the shading. Given the marker's image radius ``rho`` (its physical
    radius and its distance, known once it is triangulated), ``xy + (dist - rho) * dir``
    is its centre along the light, and the centroid is unbiased across the light
    (the shading is symmetric about the light's direction). See
    :func:`mocap.marker_pipeline.limb_centroids`.

    The direction is one for the image, from the blobs' unit shading directions, each
    the sum of 16 ray directions weighted by the steepness of the blob's edge along the ray
    (the lit limb is steep, the terminator soft). Lights overhead light every marker of a
    webcam's image from about the same side; a single blob's direction is too noisy on 3-pixel
    markers (on visible_office per-blob directions leave 0.22 px of the 0.3 px offset,
    the image's direction 0.08 px). The direction is the median of the
    blobs' unit directions (a cluttered or crowded blob does not turn it). Where the blobs do
    not agree (a Rayleigh test, :data:`LIMB_RAYLEIGH_Z`; e.g. a ring light on the camera,
    where there is no shading to remove) no limb is measured.
    """
    k = len(cx)
    dirs = np.zeros((k, 2))
    dist = np.full(k, np.nan)
    if k == 0:
        return dirs, dist
    sig = signal.astype(np.float32)
    px = cx[:, None, None] + _LIMB_T * _LIMB_COS[None, :, None]
    py = cy[:, None, None] + _LIMB_T * _LIMB_SIN[None, :, None]
    _, slope = _half_max_edges(_bilinear(sig, px, py))
    sx, sy = (np.maximum(slope, 0.0) * _LIMB_COS).sum(axis=1), (np.maximum(slope, 0.0) * _LIMB_SIN).sum(axis=1)
    norm = np.hypot(sx, sy)
    good = norm > 0
    if not good.any():
        return dirs, dist
    ux, uy = sx[good] / norm[good], sy[good] / norm[good]
    # Rayleigh test of the blobs' directions against uniform ones: n * R^2 (R the mean
    # resultant length) exceeds 3.0 with probability about exp(-3.0) = 0.05 when they are.
    if good.sum() * (ux.mean() ** 2 + uy.mean() ** 2) < LIMB_RAYLEIGH_Z:
        return dirs, dist
    d = np.array([np.median(ux), np.median(uy)])  # robust to the odd blob (clutter, a crowded pair)
    dn = np.hypot(*d)
    if dn == 0:
        return dirs, dist
    dirs[:] = d / dn
    t, _ = _half_max_edges(_bilinear(sig, cx[:, None] + _LIMB_T * dirs[:, :1], cy[:, None] + _LIMB_T * dirs[:, 1:]))
    return dirs, t
