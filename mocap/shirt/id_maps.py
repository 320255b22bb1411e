"""Small operations on the crops' id maps that the shirt tracker's steps share (:mod:`mocap.shirt.pipeline`).

A crop's square at another resolution (:func:`reduced_view`), the classified map without
its thin structures (:func:`without_thin_bits`, :func:`without_stray_thin_bits`), the
border test that grows a crop (:func:`border_band`, :func:`touches_border`), an id map
padded with its edge (:func:`edge_padded`) and the distance to the classified shirt
(:func:`silhouette`) for the IK's absence constraints.
"""

from __future__ import annotations

import cv2
import numpy as np

from mocap.distance_transform import exact_distance_transform
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
    opened = without_thin_bits(colour)
    out = colour.copy()
    for k in np.unique(colour[(colour >= 0) & (opened < 0)]):
        # within the colour's bounding box (its components lie inside it)
        x, y, w, h = cv2.boundingRect((colour == k).astype(np.uint8))
        box = (slice(y, y + h), slice(x, x + w))
        mask = colour[box] == k
        n, lab = cv2.connectedComponents(mask.astype(np.uint8), connectivity=8)
        thick = np.zeros(n, bool)
        thick[lab[opened[box] == k]] = True
        out[box][mask & ~thick[lab]] = -1
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
    dt = exact_distance_transform((colour < 0).astype(np.uint8))
    return Silhouette(dt * np.float32(view.scale), view.x0, view.y0, view.scale)
