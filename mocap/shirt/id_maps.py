"""Small operations on the crops' id maps that the shirt tracker's steps share (:mod:`mocap.shirt.pipeline`).

A crop's square at another resolution (:func:`reduced_view`), the classified map without
its thin structures (:func:`without_thin_bits`, :func:`without_stray_thin_bits`), the
border test that grows a crop (:func:`border_band`, :func:`touches_border`), an id map
padded with its edge (:func:`edge_padded`) and the distance to the classified shirt
(:func:`silhouette`) for the IK's absence constraints.
"""

from __future__ import annotations

import cv2
import numba
import numpy as np

from mocap.shirt.edt import exact_distances
from mocap.shirt.ik import Silhouette
from mocap.shirt.shirt_model import CropView

__all__ = ["reduced_view", "without_thin_bits", "without_stray_thin_bits", "edge_padded", "border_band", "touches_border", "silhouette"]


def reduced_view(view: CropView, size: int) -> CropView:
    """The same square as ``view`` sampled with ``size`` pixels per side."""
    r = view.size / size
    return CropView(view.x0 + 0.5 * view.scale * (r - 1.0), view.y0 + 0.5 * view.scale * (r - 1.0), view.scale * r, size)


def without_thin_bits(colour: np.ndarray) -> np.ndarray:
    """Classified map with structures thinner than 3 pixels removed (morphological opening of the classified mask).

    The query of the pose database frames the shirt by its classified pixels; a rim of
    mixed colours along the subject's outline or a few stray pixels on the trousers would
    stretch that frame.  Forearms are several working pixels wide and survive.
    """
    mask = (colour >= 0).astype(np.uint8)
    kept = cv2.morphologyEx(mask, cv2.MORPH_OPEN, np.ones((3, 3), np.uint8)) > 0
    return np.where(kept, colour, -1).astype(colour.dtype)


def without_stray_thin_bits(colour: np.ndarray) -> np.ndarray:
    """Classified map without the pixels of each colour that lie in its connected components (8-connected)
    thinner than 3 pixels everywhere: those with no pixel that the opening of :func:`without_thin_bits`
    (the classified mask, all colours together) keeps.

    A rim of mixed pixels along an outline goes; a limb seen 1-2 pixels wide at its end stays
    with the thicker part of its colour it joins.
    """
    colour = np.asarray(colour)
    # (one compiled flood fill over all colours: per colour, bounding box and connectedComponents
    # cost 0.1 ms a colour, up to ten a map, twice a frame; a component is a set of pixels, so the
    # same pixels go)
    return _stray_thin_bits_out(np.ascontiguousarray(colour), np.ascontiguousarray(without_thin_bits(colour)))


@numba.njit(cache=True, nogil=True)
def _stray_thin_bits_out(colour, opened):  # pragma: no cover
    """:func:`without_stray_thin_bits`: a copy of ``colour`` with -1 on each 8-connected component of one colour
    ``k >= 0`` where ``opened`` is nowhere ``k``."""
    h, w = colour.shape
    out = colour.copy()
    seen = np.zeros((h, w), np.bool_)
    stack = np.empty(h * w, np.int64)
    members = np.empty(h * w, np.int64)
    for y0 in range(h):
        for x0 in range(w):
            k = colour[y0, x0]
            if k < 0 or seen[y0, x0]:
                continue
            seen[y0, x0] = True
            stack[0] = y0 * w + x0
            top, n, thick = 1, 0, False
            while top > 0:
                top -= 1
                p = stack[top]
                members[n] = p
                n += 1
                y, x = p // w, p % w
                if opened[y, x] == k:
                    thick = True
                for yy in range(max(y - 1, 0), min(y + 2, h)):
                    for xx in range(max(x - 1, 0), min(x + 2, w)):
                        if not seen[yy, xx] and colour[yy, xx] == k:
                            seen[yy, xx] = True
                            stack[top] = yy * w + xx
                            top += 1
            if not thick:
                for i in range(n):
                    out[members[i] // w, members[i] % w] = -1
    return out


def edge_padded(a: np.ndarray) -> np.ndarray:
    """``np.pad(a, 1, mode="edge")`` of a 2-D array (its copies written out: np.pad's overhead is most of its cost here)."""
    h, w = a.shape
    out = np.empty((h + 2, w + 2), a.dtype)
    out[1:-1, 1:-1] = a
    out[0, 1:-1] = a[0]
    out[-1, 1:-1] = a[-1]
    out[:, 0] = out[:, 1]
    out[:, -1] = out[:, -2]
    return out


def border_band(size: int, band: int = 2) -> np.ndarray:
    """``(size, size)`` bool: the pixels within ``band`` pixels of the crop's edge (those :func:`touches_border` counts)."""
    m = np.ones((size, size), bool)
    m[band:-band, band:-band] = False
    return m


def touches_border(colour: np.ndarray, band: int = 2, min_pixels: int = 4) -> bool:
    """Whether at least ``min_pixels`` classified pixels lie within ``band`` pixels of the crop's edge."""
    c = colour >= 0
    edge = c[:band].sum() + c[-band:].sum() + c[band:-band, :band].sum() + c[band:-band, -band:].sum()
    return bool(edge >= min_pixels)


def silhouette(colour: np.ndarray, view: CropView) -> Silhouette:
    """Distance (image pixels) from every working pixel of a crop to the nearest classified shirt pixel."""
    # (the compiled transform: the same bits as exact_distance_transform, twice as fast at the crop's size)
    dt = exact_distances((colour < 0).view(np.uint8))
    return Silhouette(dt * np.float32(view.scale), view.x0, view.y0, view.scale)
