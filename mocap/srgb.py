"""The sRGB transfer function (IEC 61966-2-1) as a lookup table: what webcams encode their
grey levels with, undone before light is added up (centroids, colour statistics)."""

from __future__ import annotations

import numpy as np

__all__ = ["SRGB_TO_LINEAR"]


def _srgb_to_linear_table() -> np.ndarray:
    x = np.arange(256, dtype=np.float64) / 255.0
    return np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)


SRGB_TO_LINEAR = _srgb_to_linear_table()
"""(256,) float64: 8-bit sRGB code -> linear value in 0..1."""
SRGB_TO_LINEAR.setflags(write=False)
