"""Colour of light: correlated colour temperature to linear sRGB, and sRGB encoding."""

from __future__ import annotations

import numpy as np

# XYZ (D65) -> linear sRGB, IEC 61966-2-1.
_XYZ_TO_SRGB = np.array(
    [[3.2404542, -1.5371385, -0.4985314],
     [-0.9692660, 1.8760108, 0.0415560],
     [0.0556434, -0.2040259, 1.0572252]]
)


def cct_to_xy(cct_k: float) -> tuple[float, float]:
    """CIE 1931 xy of a blackbody at ``cct_k`` kelvin (1667-25000 K).

    Kang et al. (2002) cubic approximation of the Planckian locus; hand-written
    because it is eight lines and pulling in a colour-science package for it is not
    worth a dependency.
    """
    T = float(np.clip(cct_k, 1667.0, 25000.0))
    if T <= 4000:
        x = -0.2661239e9 / T**3 - 0.2343589e6 / T**2 + 0.8776956e3 / T + 0.179910
    else:
        x = -3.0258469e9 / T**3 + 2.1070379e6 / T**2 + 0.2226347e3 / T + 0.240390
    if T <= 2222:
        y = -1.1063814 * x**3 - 1.34811020 * x**2 + 2.18555832 * x - 0.20219683
    elif T <= 4000:
        y = -0.9549476 * x**3 - 1.37418593 * x**2 + 2.09137015 * x - 0.16748867
    else:
        y = 3.0817580 * x**3 - 5.87338670 * x**2 + 3.75112997 * x - 0.37001483
    return x, y


def cct_to_rgb(cct_k: float, tint: float = 0.0) -> np.ndarray:
    """Linear sRGB ``(3,)`` of light at ``cct_k``, scaled to luminance Y = 1.

    ``tint`` shifts green/magenta (positive = greener, as fluorescent tubes), in
    units of 0.01 in CIE y.
    """
    x, y = cct_to_xy(cct_k)
    y = y + 0.01 * tint
    XYZ = np.array([x / y, 1.0, (1.0 - x - y) / y])
    rgb = _XYZ_TO_SRGB @ XYZ
    return np.clip(rgb, 0.0, None)


def srgb_encode(linear: np.ndarray) -> np.ndarray:
    """sRGB opto-electronic transfer function on values in 0..1."""
    a = np.clip(linear, 0.0, 1.0)
    return np.where(a <= 0.0031308, 12.92 * a, 1.055 * np.power(a, 1 / 2.4) - 0.055)


def srgb_decode(encoded: np.ndarray) -> np.ndarray:
    """Inverse of :func:`srgb_encode`."""
    a = np.clip(encoded, 0.0, 1.0)
    return np.where(a <= 0.04045, a / 12.92, np.power((a + 0.055) / 1.055, 2.4))
