"""Colour classification of the shirt region (steps 1 and 3 of seed 001, section 5.2).

Step 1 (:func:`classify_gaussian`): white-balance the cropped pixels with ``W`` and give
each the colour whose Gaussian is nearest in Mahalanobis distance, if nearer than
``T = 3``; pixels outside the background-subtraction mask stay unclassified.  When
fewer than 40 % of the foreground pixels get a colour the light has probably changed,
and :func:`best_reference` re-classifies with every stored reference illumination and
keeps the one that classifies most.

Step 3 (:func:`classify_pose_assisted`): the rasterised blended pose is a prior; with
``d(r, k)`` the distance (image pixels) from a pixel to the nearest pixel of colour
``k`` in that id map (a distance transform per colour, ``cv2.distanceTransform``), a
pixel takes ``argmin_k |W I - mu_k|_Sigma_k + C d(r, k)`` if below ``T = 5``, with
``C = 6 / s`` and ``s`` the side of the shirt region.

Both work on a *crop*: the square around the shirt found by the histogram search,
area-resampled to a working resolution (:func:`crop_image`).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numba
import numpy as np

from mocap.shirt.colour_model import SRGB_TO_LINEAR, ColourModel
from mocap.shirt.edt import exact_distances, not_patch_cells
from mocap.shirt.shirt_model import CropView

__all__ = [
    "Classification",
    "crop_view",
    "crop_image",
    "crop_reduced_mask",
    "foreground_pixels",
    "other_distance",
    "row_min",
    "nearest_colour",
    "classify_gaussian",
    "best_reference",
    "PatchDistances",
    "patch_distances",
    "distance_to_patches",
    "classify_pose_assisted",
    "assign_patches",
    "patch_centroids",
]


@dataclass
class Classification:
    """A classified crop.

    Attributes
    ----------
    colour : (h, w) int16
        Colour id per working pixel, -1 for unclassified.
    score : (h, w) float32
        The winning colour's score (Mahalanobis distance, plus the pose prior in step 3).
    best : (h, w) int16
        The winning colour before thresholding (for ROC curves).
    classified_fraction : float
        Classified pixels over foreground pixels of the crop.
    """

    colour: np.ndarray
    score: np.ndarray
    best: np.ndarray
    classified_fraction: float


def crop_view(x: float, y: float, side: float, max_size: int) -> CropView:
    """Square crop of ``side`` image pixels centred at ``(x, y)``, at most ``max_size`` working pixels."""
    side_i = max(int(round(side)), 8)
    size = min(side_i, int(max_size))
    x0 = int(round(x - side_i / 2.0))
    y0 = int(round(y - side_i / 2.0))
    scale = side_i / size
    return CropView(x0 + 0.5 * scale - 0.5, y0 + 0.5 * scale - 0.5, scale, size)


def _crop_origin(view: CropView) -> tuple[int, int, int]:
    side = int(round(view.scale * view.size))
    x0 = int(round(view.x0 - 0.5 * view.scale + 0.5))
    y0 = int(round(view.y0 - 0.5 * view.scale + 0.5))
    return x0, y0, side


def crop_image(image: np.ndarray, view: CropView, interpolation: int = cv2.INTER_AREA) -> np.ndarray:
    """The crop of an image ``(H, W, ...)`` at working resolution ``(size, size, ...)``, zero outside the image."""
    img = np.asarray(image)
    x0, y0, side = _crop_origin(view)
    H, W = img.shape[:2]
    xa, ya, xb, yb = max(x0, 0), max(y0, 0), min(x0 + side, W), min(y0 + side, H)
    if side != view.size and (xa, ya, xb, yb) == (x0, y0, x0 + side, y0 + side):
        # inside the image: resampled from the image itself (the same pixels as from a copy)
        return cv2.resize(img[y0:y0 + side, x0:x0 + side], (view.size, view.size), interpolation=interpolation)
    sub = np.zeros((side, side) + img.shape[2:], img.dtype)
    if xb > xa and yb > ya:
        sub[ya - y0: yb - y0, xa - x0: xb - x0] = img[ya:yb, xa:xb]
    if side == view.size:
        return sub
    out = cv2.resize(sub, (view.size, view.size), interpolation=interpolation)
    return out


def crop_reduced_mask(mask_small: np.ndarray, width: int, height: int, view: CropView) -> np.ndarray:
    """``(size, size)`` bool: ``crop_image(full, view, cv2.INTER_NEAREST) > 0`` of the reduced mask ``mask_small (h, w)``
    bool resized to ``full = (height, width)`` by nearest neighbour, without making ``full``.

    Both resamplings are OpenCV's nearest neighbour, a map of indices: destination index ``i`` takes source index
    ``min(floor(i * (1 / (n_dst / n_src))), n_src - 1)`` (the same doubles as OpenCV's); here the two maps are
    composed and the mask read once (the full-size mask and its crop cost 0.14 ms a camera, this 0.04).
    """
    h, w = mask_small.shape
    x0, y0, side = _crop_origin(view)
    inner = _nearest_index(view.size, side) if side != view.size else np.arange(side)
    return _gather_mask(np.ascontiguousarray(mask_small, np.bool_), _nearest_index(height, h), _nearest_index(width, w),
                        y0 + inner, x0 + inner)


def _nearest_index(n_dst: int, n_src: int) -> np.ndarray:
    """OpenCV's ``INTER_NEAREST`` source index ``(n_dst,)`` of every destination index."""
    return np.minimum(np.floor(np.arange(n_dst) * (1.0 / (n_dst / n_src))).astype(np.int64), n_src - 1)


@numba.njit(cache=True, nogil=True)
def _gather_mask(small, row_of, col_of, ys, xs):  # pragma: no cover
    """``out[j, i] = small[row_of[ys[j]], col_of[xs[i]]]``, False where ``ys[j]`` or ``xs[i]`` is outside
    ``row_of`` / ``col_of`` (outside the full-size image)."""
    out = np.zeros((ys.shape[0], xs.shape[0]), np.bool_)
    H, W = row_of.shape[0], col_of.shape[0]
    for j in range(ys.shape[0]):
        y = ys[j]
        if y < 0 or y >= H:
            continue
        row = small[row_of[y]]
        for i in range(xs.shape[0]):
            x = xs[i]
            if x >= 0 and x < W:
                out[j, i] = row[col_of[x]]
    return out


def _linear(work_rgb: np.ndarray) -> np.ndarray:
    return SRGB_TO_LINEAR[work_rgb]


def other_distance(x: np.ndarray, other: ColourModel | None, W: np.ndarray) -> np.ndarray | None:
    """Distance ``(n,)`` of pixels ``(n, 3)`` to the nearest not-shirt colour (None without those colours)."""
    if other is None or len(x) == 0:
        return None
    return row_min(other.distances(x, W))


def row_min(d: np.ndarray) -> np.ndarray:
    """``d.min(axis=1)`` of ``d (n, k)``, ``k >= 1``, as a chain of np.minimum over the columns (the same values;
    numpy's reduction along a short last axis is ten times slower)."""
    out = d[:, 0].copy()
    for k in range(1, d.shape[1]):
        np.minimum(out, d[:, k], out=out)
    return out


def nearest_colour(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``d.argmin(axis=1)`` as int16 and :func:`row_min` of ``d (n, k)``, ``k >= 1``, in one compiled pass (the same
    values, NaN included: numpy's argmin along a short last axis cost three times row_min, on every classification)."""
    d = np.ascontiguousarray(d)
    return _argmin_and_min(d) if d.dtype in (np.float32, np.float64) else (d.argmin(axis=1).astype(np.int16), row_min(d))


@numba.njit(cache=True, nogil=True)
def _argmin_and_min(d):  # pragma: no cover
    """:func:`nearest_colour`: per row numpy's argmin (the first NaN, else the first least value) and the chain
    ``np.minimum(out, d[:, k])`` (``out`` kept where it is less or NaN, else the column's value)."""
    n, K = d.shape
    best = np.empty(n, np.int16)
    score = np.empty(n, d.dtype)
    for i in range(n):
        s = d[i, 0]
        m = d[i, 0]
        b = 0
        for k in range(1, K):
            v = d[i, k]
            if not (s < v or s != s):
                s = v
            if not (m != m) and not (v >= m):
                m = v
                b = k
        best[i] = b
        score[i] = s
    return best, score


def _other_wins(x: np.ndarray, other: ColourModel | None, W: np.ndarray, score: np.ndarray,
                other_min: np.ndarray | None = None) -> np.ndarray:
    """Pixels ``(n, 3)`` where a not-shirt Gaussian is nearer than the best shirt colour's ``score``
    (``other_min``: :func:`other_distance` of the pixels, when at hand)."""
    if other is None or len(x) == 0:
        return np.zeros(score.shape, bool)
    return (other_distance(x, other, W) if other_min is None else other_min) < score


def foreground_pixels(linear_rgb: np.ndarray, foreground: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """Flat indices of the crop's foreground pixels ``(n,)`` and their linear colours ``(n, 3)``."""
    flat = np.asarray(linear_rgb, np.float32).reshape(-1, 3)
    if foreground is None:
        return np.arange(len(flat)), flat
    idx = np.flatnonzero(np.asarray(foreground).ravel())
    return idx, flat[idx]


def _result(shape: tuple[int, int], idx: np.ndarray, best: np.ndarray, score: np.ndarray, threshold: float) -> Classification:
    h, w = shape
    ok = score < threshold
    colour = np.full(h * w, -1, np.int16)
    colour[idx[ok]] = best[ok]
    full_score = np.full(h * w, np.inf, np.float32)
    full_score[idx] = score
    full_best = np.full(h * w, -1, np.int16)
    full_best[idx] = best
    return Classification(colour.reshape(h, w), full_score.reshape(h, w), full_best.reshape(h, w),
                          float(ok.sum()) / max(len(idx), 1))


def _classify_by_cost(shape: tuple[int, int], idx: np.ndarray, x: np.ndarray, cost: np.ndarray, threshold: float,
                      other: ColourModel | None, W: np.ndarray, other_min: np.ndarray | None) -> Classification:
    """Each foreground pixel's cheapest colour in ``cost`` ``(n, K)``; unclassified where a
    not-shirt colour is nearer, or beyond ``threshold`` (steps 1 and 3 share this)."""
    best, score = nearest_colour(cost)
    score = np.where(_other_wins(x, other, W, score, other_min), np.inf, score)
    return _result(shape, idx, best, score, threshold)


def _pixels_and_distances(linear_rgb: np.ndarray, model: ColourModel, W: np.ndarray, foreground: np.ndarray | None,
                          pixels: tuple[np.ndarray, np.ndarray] | None,
                          distances: np.ndarray | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The foreground pixels ``(idx, x)`` and their ``model.distances`` with ``W``, unless the caller has them."""
    idx, x = foreground_pixels(linear_rgb, foreground) if pixels is None else pixels
    return idx, x, (model.distances(x, W) if distances is None else distances)


def classify_gaussian(linear_rgb: np.ndarray, model: ColourModel, W: np.ndarray, foreground: np.ndarray | None,
                      threshold: float = 3.0, distances: np.ndarray | None = None,
                      other: ColourModel | None = None, pixels: tuple[np.ndarray, np.ndarray] | None = None,
                      other_min: np.ndarray | None = None) -> Classification:
    """Step 1: nearest Gaussian after white balance, thresholded (``T``), foreground only.

    Parameters
    ----------
    linear_rgb : (h, w, 3) float32
        Linear RGB of the crop.
    W : (3, 3) float
    foreground : (h, w) bool or None
        Only these pixels are classified (all if None).
    distances : (n, K) float, optional
        Precomputed ``model.distances`` of the foreground pixels (:func:`foreground_pixels`) with ``W``.
    other : ColourModel, optional
        Not-shirt colours of the session (:func:`mocap.shirt.colour_model.train_other_colours`):
        a pixel nearer to one of them than to every shirt colour stays unclassified.
    pixels : ((n,) int, (n, 3) float32), optional
        ``foreground_pixels(linear_rgb, foreground)`` when the caller has it.
    other_min : (n,) float, optional
        :func:`other_distance` of those pixels with ``W``, when the caller has it.
    """
    idx, x, D = _pixels_and_distances(linear_rgb, model, W, foreground, pixels, distances)
    return _classify_by_cost(linear_rgb.shape[:2], idx, x, D, threshold, other, W, other_min)


def best_reference(linear_rgb: np.ndarray, model: ColourModel, references: list[np.ndarray], foreground: np.ndarray | None,
                   threshold: float = 3.0, other: ColourModel | None = None) -> tuple[int, Classification]:
    """Re-classify with every reference white balance; the index and result of the one classifying most."""
    best_i, best_c = -1, None
    for i, Wr in enumerate(references):
        c = classify_gaussian(linear_rgb, model, Wr, foreground, threshold, other=other)
        if best_c is None or c.classified_fraction > best_c.classified_fraction:
            best_i, best_c = i, c
    return best_i, best_c


@dataclass(frozen=True)
class PatchDistances:
    """Distances from query pixels to the patches of a rendered map, kept per map cell (:func:`patch_distances`).

    Attributes
    ----------
    cells : (P, c) float32
        Distance (working pixels of the full crop) from every cell of the reduced map to
        the nearest cell of each patch; ``inf`` for patches absent from the map.
    cell : (n,) int
        The cell of each query pixel.
    """

    cells: np.ndarray
    cell: np.ndarray

    def pixels(self) -> np.ndarray:
        """``(P, n)`` float32: the distances of the query pixels (:func:`distance_to_patches`)."""
        return self.cells[:, self.cell]


def patch_distances(patch_map: np.ndarray, n_patches: int, idx: np.ndarray, full_size: int, reduce: int = 1,
                    cell: np.ndarray | None = None) -> PatchDistances:
    """:func:`distance_to_patches` per map cell, with the cell of every query pixel (no ``(P, n)`` array).

    ``cell``: the query pixels' cells as a previous result for the same pixels and sizes has them
    (:attr:`PatchDistances.cell`), when at hand.
    """
    pm = np.asarray(patch_map)
    r0 = pm.shape[0]
    if reduce > 1:
        r = r0 // reduce
        pm = pm[: r * reduce, : r * reduce]
    else:
        r = r0
    f = full_size / r
    if cell is None:
        ys, xs = np.divmod(np.asarray(idx), full_size)
        cell = (np.minimum((ys / f).astype(np.int64), r - 1) * r + np.minimum((xs / f).astype(np.int64), r - 1))
    present = np.unique(pm[pm >= 0])
    D = np.full((n_patches, r * r), np.inf, np.float32)
    if present.size == 0:
        return PatchDistances(D, cell)
    # not-this-patch masks of all present patches, (m, r, r) uint8: a cell is not the patch if none of its
    # reduce x reduce pixels is; then distances per map cell (both compiled, all patches in one call)
    other = not_patch_cells(pm, np.ascontiguousarray(present, np.int64), reduce)
    D[present] = exact_distances(other).reshape(len(present), r * r)
    D[present] *= np.float32(f)
    return PatchDistances(D, cell)


def distance_to_patches(patch_map: np.ndarray, n_patches: int, idx: np.ndarray, full_size: int, reduce: int = 1) -> np.ndarray:
    """Distance ``(P, n)`` float32 (working pixels of the full crop) from pixels to the nearest pixel of each patch.

    Parameters
    ----------
    patch_map : (r, r) int
        Rendered patch ids of the crop at a reduced resolution ``r`` (the transforms
        run there: the prior needs distances to a few pixels, not to a tenth of one).
    idx : (n,) int
        Flat indices of the query pixels in the ``full_size x full_size`` crop.
    reduce : int
        The transforms run on cells of ``reduce x reduce`` map pixels (a cell holds a
        patch if any of its pixels does; distances between cell centres): a transform
        costs about the square of its side, and the prior and the patch split need
        distances to a few cells, not to one pixel of the map.

    Returns
    -------
    (P, n) float32
        ``inf`` for patches absent from the map.
    """
    return patch_distances(patch_map, n_patches, idx, full_size, reduce).pixels()


def classify_pose_assisted(linear_rgb: np.ndarray, model: ColourModel, W: np.ndarray, colour_distance_px: np.ndarray,
                           prior_weight: float, foreground: np.ndarray | None, threshold: float = 5.0,
                           distances: np.ndarray | None = None, other: ColourModel | None = None,
                           pixels: tuple[np.ndarray, np.ndarray] | None = None,
                           other_min: np.ndarray | None = None) -> Classification:
    """Step 3: Mahalanobis distance plus ``prior_weight * d(r_b, k)``, thresholded at ``T``.

    Parameters
    ----------
    colour_distance_px : (K, n) float
        Distance in *image* pixels from each foreground pixel (:func:`foreground_pixels`
        order) to the nearest pixel of each colour in the rendered blended pose
        (``inf`` where a colour is not rendered).
    prior_weight : float
        ``C = 6 / s``.
    other : ColourModel, optional
        Not-shirt colours (see :func:`classify_gaussian`); they carry no pose prior.
    linear_rgb, W, foreground, distances, pixels, other_min
        As :func:`classify_gaussian`.
    """
    idx, x, D = _pixels_and_distances(linear_rgb, model, W, foreground, pixels, distances)
    total = D + np.minimum(np.asarray(colour_distance_px, np.float32).T, 1e6) * np.float32(prior_weight)
    return _classify_by_cost(linear_rgb.shape[:2], idx, x, total, threshold, other, W, other_min)


def assign_patches(colour: np.ndarray, idx: np.ndarray, patch_distance: np.ndarray, patch_colour: np.ndarray,
                   gate: float = np.inf) -> np.ndarray:
    """Split each colour's pixels between its patches: the patch nearest in the rendered pose.

    Parameters
    ----------
    colour : (h, w) int
        Classified colour ids, -1 for none.
    idx : (n,) int
        Flat indices of the pixels ``patch_distance`` describes (the foreground).
    patch_distance : (P, n) float or PatchDistances
        Distance from those pixels to each rendered patch (``inf`` if not rendered).
    patch_colour : (P,) int
    gate : float
        Pixels farther than this (units of ``patch_distance``) from the nearest patch of
        their colour are left out: a stray pixel of the colour elsewhere (an object of the
        set, a misclassified edge) would drag a centroid.

    Returns
    -------
    (h, w) int16
        Patch id per pixel, -1 where unclassified, where no patch of the colour is
        rendered, or beyond the gate.
    """
    K = int(np.max(patch_colour)) + 1
    members = [np.flatnonzero(np.asarray(patch_colour) == k) for k in range(K)]
    m = max(len(x) for x in members)
    table = np.full((K, m), -1, np.int64)
    for k, x in enumerate(members):
        table[k, : len(x)] = x
    out = np.full(colour.size, -1, np.int16)
    c = colour.ravel()[idx]
    if isinstance(patch_distance, PatchDistances):
        if c.size and int(c.max()) >= K:
            raise IndexError(f"assign_patches: colour {int(c.max())} in the map, the patches have {K} colours")
        # compiled: the numpy form's ten passes over the pixels were most of its cost (the same choices:
        # the first nearest candidate, the gate compared in float32 as numpy compares it with the distances)
        _assign_nearest(np.ascontiguousarray(c, np.int64), np.asarray(idx, np.int64), patch_distance.cells,
                        np.asarray(patch_distance.cell, np.int64), table, np.float32(gate), out)
        return out.reshape(colour.shape)
    ok = c >= 0
    if not ok.any():
        return out.reshape(colour.shape)
    sel = np.flatnonzero(ok)
    cand = table[c[ok]]  # (n, m)
    d = np.where(cand >= 0, patch_distance[np.maximum(cand, 0), sel[:, None]], np.inf)
    j = d.argmin(axis=1)
    r = np.arange(len(sel))
    good = d[r, j] <= gate
    out[idx[sel[good]]] = cand[r, j][good]
    return out.reshape(colour.shape)


@numba.njit(cache=True, nogil=True)
def _assign_nearest(c, idx, cells, cell, table, gate, out):  # pragma: no cover
    """:func:`assign_patches` with :class:`PatchDistances`: each classified pixel ``t`` (colour ``c[t]``, flat index
    ``idx[t]``, map cell ``cell[t]``) gets the first of its colour's patches ``table[c[t]]`` nearest in ``cells``
    (``argmin``'s choice; ``inf`` for none) if that distance is within ``gate`` (float32, as the distances)."""
    m = table.shape[1]
    for t in range(c.shape[0]):
        k = c[t]
        if k < 0:
            continue
        best = np.float32(np.inf)
        bj = 0
        for j in range(m):
            p = table[k, j]
            d = cells[p, cell[t]] if p >= 0 else np.float32(np.inf)
            if d < best:
                best = d
                bj = j
        if best <= gate:
            out[idx[t]] = table[k, bj]


def patch_centroids(patch_map: np.ndarray, n_patches: int) -> tuple[np.ndarray, np.ndarray]:
    """Centroid ``(P, 2)`` (x, y working pixels; NaN if empty) and pixel count ``(P,)`` of every patch."""
    h, w = patch_map.shape
    n, sx, sy = _patch_sums(patch_map.ravel(), w, n_patches)
    with np.errstate(invalid="ignore", divide="ignore"):
        c = np.stack([sx / n, sy / n], axis=1)
    c[n == 0] = np.nan
    return c, n.astype(int)



@numba.njit(cache=True, nogil=True)
def _patch_sums(p, w, n_patches):  # pragma: no cover
    """:func:`patch_centroids`' pixel counts and sums of x and y per patch over a flat map ``p`` of width ``w``,
    in pixel order (``np.bincount``'s sums, with its length: at least ``n_patches``), compiled."""
    size = n_patches
    for i in range(p.shape[0]):
        if p[i] + 1 > size:
            size = p[i] + 1
    n = np.zeros(size)
    sx = np.zeros(size)
    sy = np.zeros(size)
    for i in range(p.shape[0]):
        v = p[i]
        if v < 0:
            continue
        n[v] += 1.0
        sx[v] += i % w
        sy[v] += i // w
    return n, sx, sy
