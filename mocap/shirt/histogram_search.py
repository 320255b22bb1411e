"""Locating the shirt by the uniformity of local chromaticity histograms (section 4 of seed 001).

The chromaticity of a pixel is ``(r, g, b) / (r + g + b)``; its histogram over an
``s x s`` window has 100 bins (a 10 x 10 grid over ``(r, g)``; only the bins with
``r + g <= 1`` can be reached, and only those are stored).  A window of the
multi-coloured shirt has a *uniform* histogram, other regions a peaky one; uniformity
is ``u(h) = sum_i min(h_i, tau)`` with ``tau = 0.1``.  The shirt's position and scale
are the average of the window centres and sizes weighted by
``w = exp(-(u - u_max)^2 / u_sigma^2)``, ``u_sigma = u_max / 10``.

Histograms are sampled every 6 pixels at six scales from an *integral histogram*
(Porikli 2005): the image is reduced to half size (``cv2.resize``, area averaging),
cut into 3 x 3-pixel cells (6 x 6 original pixels), the cells' bin counts are
summed cumulatively over rows and columns, and every window's histogram is four
look-ups.  Dark pixels (``r + g + b`` below ``min_brightness``) have no reliable
chromaticity and count in no bin (windows are normalised by their area, so dark
regions are not uniform).  An optional foreground mask (background subtraction)
restricts both the counted pixels and the window centres; then only the block of cells
holding foreground is binned.  The cell counts and the windows' uniformities are
compiled loops (numba).

:func:`naive_search` computes the same windows without the integral histogram (one
``numpy.bincount`` per window) and is the reference of ``simbench bench shirt``.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import cv2
import numba
import numpy as np

from mocap.errors import MocapInputError, require

__all__ = ["HistogramSearchParams", "ShirtLocation", "scales_px", "chromaticity_bins", "search_shirt", "naive_search"]

_REDUCE = 2  # the image is halved before binning


@dataclass(frozen=True)
class HistogramSearchParams:
    """Settings of the histogram search (defaults: the paper's).

    Attributes
    ----------
    bins_per_axis : int
        The chromaticity grid is ``bins_per_axis**2`` bins over ``(r, g)`` (100).
    tau : float
        Cap of each bin in the uniformity ``u(h) = sum_i min(h_i, tau)``.
    stride_px : int
        Spacing of the sampled window centres, original pixels (a multiple of 2).
    scales : tuple[float, ...]
        Window sides as fractions of the image height (rounded to multiples of
        ``stride_px``; 48 to 240 pixels in a 640 x 480 frame).
    u_sigma_fraction : float
        ``u_sigma = u_sigma_fraction * u_max``.
    min_brightness : int
        Pixels with ``r + g + b`` (8-bit codes) below this count in no bin.
    """

    bins_per_axis: int = 10
    tau: float = 0.1
    stride_px: int = 6
    scales: tuple[float, ...] = (0.1, 0.15, 0.2, 0.275, 0.375, 0.5)
    u_sigma_fraction: float = 0.1
    min_brightness: int = 40

    def __post_init__(self) -> None:
        require(self.stride_px % _REDUCE == 0 and self.stride_px > 0, self, "stride_px", f"use a positive multiple of {_REDUCE}",
                error=MocapInputError)
        require(bool(self.scales) and all(0.0 < s <= 1.0 for s in self.scales), self, "scales",
                "give fractions of the image height in (0, 1]", error=MocapInputError)
        require(0.0 < self.tau <= 1.0, self, "tau", "use a value in (0, 1]", error=MocapInputError)


def scales_px(params: HistogramSearchParams, height: int) -> list[int]:
    """Window sides in pixels for an image ``height`` pixels high (multiples of the stride, at least two strides)."""
    st = params.stride_px
    return sorted({max(2 * st, int(round(f * height / st)) * st) for f in params.scales})


@dataclass(frozen=True)
class ShirtLocation:
    """Where the shirt is: window centre ``(x, y)`` and side ``s`` in pixels, and the best uniformity."""

    x: float
    y: float
    s: float
    u_max: float


def _bin_table(n: int) -> tuple[np.ndarray, int]:
    """Map of the ``n x n`` grid bin ``rb * n + gb`` to a compact index of the reachable bins (-1 if unreachable)."""
    rb, gb = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    reachable = (rb + gb) <= n
    table = np.full(n * n, -1, np.int64)
    table[reachable.ravel()] = np.arange(int(reachable.sum()))
    return table, int(reachable.sum())


@lru_cache(maxsize=8)
def _bin_lut(n: int, min_brightness: int) -> tuple[np.ndarray, int]:
    """Compact chromaticity bin of every 6-bit-per-channel colour ``(64**3,)`` int16 (-1: dark), and the bin count.

    A lookup table keyed by the top six bits of each channel replaces a dozen integer
    operations per pixel; the bin of a colour is that of the centre of its 4x4x4 cell.
    """
    table, nb = _bin_table(n)
    c = (np.arange(64) * 4 + 2).astype(np.int64)
    R, G, B = np.meshgrid(c, c, c, indexing="ij")
    s = R + G + B
    rb = np.minimum(R * n // s, n - 1)
    gb = np.minimum(G * n // s, n - 1)
    lut = np.where(s - 6 >= min_brightness, table[rb * n + gb], -1).astype(np.int16)
    return lut.ravel(), nb


def chromaticity_bins(image: np.ndarray, params: HistogramSearchParams, mask: np.ndarray | None = None) -> tuple[np.ndarray, int]:
    """Compact chromaticity bin ``(H, W)`` int64 of every pixel, -1 for dark or masked-out ones; and the bin count."""
    img = np.asarray(image)
    lut, nb = _bin_lut(params.bins_per_axis, params.min_brightness)
    q = (img >> 2).astype(np.int32)
    b = lut[(q[..., 0] << 12) | (q[..., 1] << 6) | q[..., 2]].astype(np.int64)
    if mask is not None:
        b[~mask] = -1
    return b, nb


def _cells(image: np.ndarray, params: HistogramSearchParams, foreground: np.ndarray | None):
    """Cell histogram counts over the cells holding foreground, and the foreground cells.

    Returns
    -------
    counts : (by, bx, nb) float32
        Bin counts of the cells ``r0..r0+by-1`` x ``c0..c0+bx-1`` (all cells without a
        foreground mask; otherwise the bounding box of the cells holding foreground
        pixels, since no other pixel is counted: only that part of the frame is binned).
    fg_cells : (ny, nx) bool or None
        Cells at least half foreground (window centres).
    c : int
        Cell side in half-size pixels.
    origin : (int, int)
        ``(r0, c0)``.
    grid : (int, int)
        ``(ny, nx)``, the whole frame's cells.
    """
    img = np.asarray(image)
    if img.ndim != 3 or img.shape[2] != 3 or img.dtype != np.uint8:
        raise MocapInputError(f"histogram search: expected an (H, W, 3) uint8 RGB image, got {img.shape} {img.dtype}")
    H, W = img.shape[:2]
    c = params.stride_px // _REDUCE
    h, w = H // _REDUCE, W // _REDUCE
    ny, nx = h // c, w // c
    r0, c0, r1, c1 = 0, 0, ny, nx
    fg_small = fg_cells = None
    if foreground is not None:
        fg_small = cv2.resize(np.asarray(foreground, np.uint8), (w, h), interpolation=cv2.INTER_AREA)[: ny * c, : nx * c] > 0
        fg_cells = _half_covered(np.ascontiguousarray(fg_small), c, ny, nx)
        rows = np.flatnonzero(fg_small.any(axis=1))
        cols = np.flatnonzero(fg_small.any(axis=0))
        if rows.size == 0:
            return np.zeros((0, 0, _bin_table(params.bins_per_axis)[1]), np.float32), fg_cells, c, (0, 0), (ny, nx)
        r0, r1 = rows[0] // c, rows[-1] // c + 1
        c0, c1 = cols[0] // c, cols[-1] // c + 1
    # halving a block aligned on even pixels gives the same pixels as halving the frame
    f = c * _REDUCE
    small = cv2.resize(img[r0 * f: r1 * f, c0 * f: c1 * f], ((c1 - c0) * c, (r1 - r0) * c), interpolation=cv2.INTER_AREA)
    by, bx = r1 - r0, c1 - c0
    lut, nb = _bin_lut(params.bins_per_axis, params.min_brightness)
    mask = np.ones(small.shape[:2], bool) if fg_small is None else np.ascontiguousarray(fg_small[r0 * c: r1 * c, c0 * c: c1 * c])
    counts = _cell_counts(np.ascontiguousarray(small), mask, lut, c, by, bx, nb)
    return counts, fg_cells, c, (int(r0), int(c0)), (ny, nx)


@numba.njit(cache=True, nogil=True)
def _half_covered(fg, c, ny, nx):  # pragma: no cover
    """``(ny, nx)`` bool: the ``c x c`` cells of ``fg (ny c, nx c)`` bool at least half foreground.  numpy's
    ``fg.reshape(ny, c, nx, c).mean(axis=(1, 3)) >= 0.5`` (0.7 ms a camera, a frame), counted: ``k / c^2``
    correctly rounded is at least 0.5 exactly when ``2 k >= c^2`` (0.5 is a float and rounding is monotonic)."""
    out = np.empty((ny, nx), np.bool_)
    for cy in range(ny):
        for cx in range(nx):
            k = 0
            for y in range(cy * c, cy * c + c):
                for x in range(cx * c, cx * c + c):
                    if fg[y, x]:
                        k += 1
            out[cy, cx] = 2 * k >= c * c
    return out


@numba.njit(cache=True, nogil=True)
def _cell_counts(small, mask, lut, c, by, bx, nb):  # pragma: no cover
    """Bin counts ``(by, bx, nb)`` float32 of the ``c x c``-pixel cells (:func:`chromaticity_bins` per pixel), compiled."""
    counts = np.zeros((by, bx, nb), np.float32)
    # cell by cell (a division per pixel cost more than the rest; whole counts, so any order sums the same)
    for cy in range(by):
        for cx in range(bx):
            for y in range(cy * c, cy * c + c):
                for x in range(cx * c, cx * c + c):
                    if not mask[y, x]:
                        continue
                    b = lut[((small[y, x, 0] >> 2) << 12) | ((small[y, x, 1] >> 2) << 6) | (small[y, x, 2] >> 2)]
                    if b >= 0:
                        counts[cy, cx, b] += 1
    return counts


def _weighted_location(centres: list[np.ndarray], sizes: list[np.ndarray], us: list[np.ndarray],
                       params: HistogramSearchParams) -> ShirtLocation | None:
    if not us or sum(u.size for u in us) == 0:
        return None
    u = np.concatenate(us)
    xy = np.concatenate(centres)
    s = np.concatenate(sizes)
    u_max = float(u.max())
    if u_max <= 0:
        return None
    sigma = params.u_sigma_fraction * u_max
    w = np.exp(-((u - u_max) ** 2) / sigma**2)
    w /= w.sum()
    return ShirtLocation(float(w @ xy[:, 0]), float(w @ xy[:, 1]), float(w @ s), u_max)


def search_shirt(image: np.ndarray, params: HistogramSearchParams = HistogramSearchParams(),
                 foreground: np.ndarray | None = None) -> ShirtLocation | None:
    """Find the shirt in one RGB frame (integral histogram).

    Parameters
    ----------
    image : (H, W, 3) uint8 RGB
    params : HistogramSearchParams
    foreground : (H, W) bool, optional
        Background-subtraction mask: only foreground pixels are counted, and only
        windows centred on foreground cells are scored.

    Returns
    -------
    ShirtLocation or None
        None when no window has any colour (e.g. an empty or black frame).
    """
    counts, fg_cells, c, (r0, c0), (ny, nx) = _cells(image, params, foreground)
    by, bx, nb = counts.shape
    if by == 0:
        return None
    # cv2.integral sums all bins at once, several times faster than two numpy cumsums over
    # non-contiguous axes; counts stay below 2**24, exact in float32
    integral = cv2.integral(counts, sdepth=cv2.CV_32F)
    cell_px = c * _REDUCE
    centres, sizes, us = [], [], []
    for s_px in scales_px(params, np.asarray(image).shape[0]):
        m = s_px // cell_px
        if m > ny or m > nx:
            continue
        area = float((m * c) ** 2)
        if fg_cells is None:  # the counts cover the whole frame
            S = integral[m:, m:] - integral[:-m, m:] - integral[m:, :-m] + integral[:-m, :-m]
            np.minimum(S, params.tau * area, out=S)
            u = S.sum(axis=2).ravel() / area
            iy, ix = np.divmod(np.arange(u.size), nx - m + 1)
        else:
            half = m // 2
            sel = fg_cells[half: half + ny - m + 1, half: half + nx - m + 1]
            iy, ix = np.nonzero(sel)
            if iy.size == 0:
                continue
            u = _uniformity(integral, iy.astype(np.int64), ix.astype(np.int64), r0, c0, m, np.float32(params.tau * area),
                            np.float32(area))
        # window (iy, ix) covers cells iy..iy+m-1: centre in original pixels
        centres.append(np.stack([(ix + m / 2.0) * cell_px - 0.5, (iy + m / 2.0) * cell_px - 0.5], axis=1))
        sizes.append(np.full(u.size, float(m * cell_px)))
        us.append(u)
    return _weighted_location(centres, sizes, us, params)


@numba.njit(cache=True, nogil=True)
def _uniformity(integral, iy, ix, r0, c0, m, cap, area):  # pragma: no cover
    """``u`` of the windows of ``m x m`` cells at ``(iy, ix)`` (float32, as numpy computed it before).

    Each window's histogram is its part inside the counted block (nothing is counted
    outside it), four look-ups; bins are capped and summed in numpy's pairwise order
    (eight running sums), so the values are bit for bit those of the vectorised form.
    Compiled because the vectorised form gathered ``(windows, bins)`` arrays per scale.
    """
    by, bx, nb = integral.shape[0] - 1, integral.shape[1] - 1, integral.shape[2]
    u = np.empty(len(iy), np.float32)
    S = np.empty(nb, np.float32)
    r = np.empty(8, np.float32)
    for w in range(len(iy)):
        ya, yb = min(max(iy[w] - r0, 0), by), min(max(iy[w] + m - r0, 0), by)
        xa, xb = min(max(ix[w] - c0, 0), bx), min(max(ix[w] + m - c0, 0), bx)
        for b in range(nb):
            v = integral[yb, xb, b] - integral[ya, xb, b] - integral[yb, xa, b] + integral[ya, xa, b]
            S[b] = v if v < cap else cap
        if nb < 8:
            tot = np.float32(0.0)
            for b in range(nb):
                tot += S[b]
        else:
            for j in range(8):
                r[j] = S[j]
            i = 8
            while i < nb - (nb % 8):
                for j in range(8):
                    r[j] += S[i + j]
                i += 8
            tot = ((r[0] + r[1]) + (r[2] + r[3])) + ((r[4] + r[5]) + (r[6] + r[7]))
            while i < nb:
                tot += S[i]
                i += 1
        u[w] = tot / area
    return u


def naive_search(image: np.ndarray, params: HistogramSearchParams = HistogramSearchParams(),
                 foreground: np.ndarray | None = None) -> ShirtLocation | None:
    """The same search with one histogram per window counted directly (no integral histogram).

    Gives the result of :func:`search_shirt` (up to float rounding); it exists as the
    speed reference of ``simbench bench shirt``.
    """
    img = np.asarray(image)
    H, W = img.shape[:2]
    small = cv2.resize(img, (W // _REDUCE, H // _REDUCE), interpolation=cv2.INTER_AREA)
    fg_small = None
    if foreground is not None:
        fg_small = cv2.resize(np.asarray(foreground, np.uint8), (W // _REDUCE, H // _REDUCE), interpolation=cv2.INTER_AREA) > 0
    c = params.stride_px // _REDUCE
    ny, nx = small.shape[0] // c, small.shape[1] // c
    small = small[: ny * c, : nx * c]
    bins, nb = chromaticity_bins(small, params, None if fg_small is None else fg_small[: ny * c, : nx * c])
    fg_cells = None
    if fg_small is not None:
        fg_cells = fg_small[: ny * c, : nx * c].reshape(ny, c, nx, c).mean(axis=(1, 3)) >= 0.5
    cell_px = c * _REDUCE
    centres, sizes, us = [], [], []
    for s_px in scales_px(params, H):
        m = s_px // cell_px
        if m > ny or m > nx:
            continue
        area = float((m * c) ** 2)
        half = m // 2
        for iy in range(ny - m + 1):
            for ix in range(nx - m + 1):
                if fg_cells is not None and not fg_cells[iy + half, ix + half]:
                    continue
                win = bins[iy * c: (iy + m) * c, ix * c: (ix + m) * c]
                h = np.bincount(win[win >= 0], minlength=nb).astype(np.float32)
                us.append(np.array([np.minimum(h, params.tau * area).sum() / area]))
                centres.append(np.array([[(ix + m / 2.0) * cell_px - 0.5, (iy + m / 2.0) * cell_px - 0.5]]))
                sizes.append(np.array([float(m * cell_px)]))
    return _weighted_location(centres, sizes, us, params)
