"""Integer ids written by the renderer into every pixel of the id map.

``0`` background (nothing drawn), then one range per kind of object so that one
``int32`` image says, for each pixel, which marker, shirt patch or prop it shows.
"""

from __future__ import annotations

import numpy as np

BACKGROUND = 0
BODY = 1            # skin, clothes (everything of the humanoid that is not a shirt patch)
SET = 2             # floor and walls
CLUTTER = 3         # coloured objects of the set
PROP_BASE = 10      # + prop index (ball, barrier, moving object, ...)
BOARD = 50          # calibration board
SHIRT_PATCH_BASE = 100   # + shirt patch 0..19
MARKER_BASE = 1000       # + marker index 0..M-1


def marker_index(ids: np.ndarray) -> np.ndarray:
    """Marker index per pixel, -1 where the pixel is not a marker."""
    return np.where(ids >= MARKER_BASE, ids - MARKER_BASE, -1)


def shirt_patch(ids: np.ndarray) -> np.ndarray:
    """Shirt patch 0..19 per pixel, -1 elsewhere."""
    m = (ids >= SHIRT_PATCH_BASE) & (ids < SHIRT_PATCH_BASE + 100)
    return np.where(m, ids - SHIRT_PATCH_BASE, -1)
