"""The IR detector's sub-pixel centroid against known blob centres.

Small markers (1-2 px) imaged by a webcam: the light of a Gaussian spot integrated over
each pixel, sRGB-encoded to 8 bits. The true centre is known exactly.
"""

import numpy as np
from scipy.special import erf

from mocap.detection import DetectionParams, detect_markers


def _linear_to_srgb(v: np.ndarray) -> np.ndarray:
    return np.where(v <= 0.0031308, 12.92 * v, 1.055 * np.power(v, 1 / 2.4) - 0.055)


def _spot_image(centres: np.ndarray, sigma_px: float, peak: float, background: float,
                size: tuple[int, int] = (120, 160)) -> np.ndarray:
    """Gaussian spots integrated over the pixel areas (linear light), then sRGB to uint8."""
    h, w = size
    edges_x, edges_y = np.arange(w + 1) - 0.5, np.arange(h + 1) - 0.5
    light = np.full((h, w), background)
    s = np.sqrt(2.0) * sigma_px
    for cx, cy in centres:
        ix = np.diff(0.5 * erf((edges_x - cx) / s))
        iy = np.diff(0.5 * erf((edges_y - cy) / s))
        light += peak * 2 * np.pi * sigma_px ** 2 * np.outer(iy, ix)
    return np.round(255.0 * _linear_to_srgb(np.clip(light, 0.0, 1.0))).astype(np.uint8)


_LINEAR = np.where(np.arange(256) <= 10, np.arange(256) / 255.0 / 12.92,
                   ((np.arange(256) / 255.0 + 0.055) / 1.055) ** 2.4)


def _light_centroids(image: np.ndarray, centres: np.ndarray, background_level: int) -> np.ndarray:
    """Centroid of the light above the background in a 7x7 window around each spot,
    from the decoded 8-bit levels: what a light-weighted centroid must return."""
    out = []
    for cx, cy in centres:
        x0, y0 = int(round(cx)) - 3, int(round(cy)) - 3
        win = image[y0:y0 + 7, x0:x0 + 7]
        w = np.maximum(_LINEAR[win] - _LINEAR[background_level], 0.0)
        gy, gx = np.mgrid[y0:y0 + 7, x0:x0 + 7]
        out.append([np.sum(w * gx) / w.sum(), np.sum(w * gy) / w.sum()])
    return np.array(out)


def test_srgb_response_centroid_is_the_centroid_of_light():
    """sRGB-encoded small spots (webcam output): the centroid weighs each pixel by its decoded
    light, so it equals the light's centroid computed from the frame; weights on the encoded
    levels give another point."""
    rng = np.random.default_rng(3)
    gx, gy = np.meshgrid(np.arange(20, 150, 16), np.arange(20, 110, 16))
    centres = np.column_stack([gx.ravel(), gy.ravel()]) + rng.uniform(-0.5, 0.5, (gx.size, 2))
    # Elongated spots (a short streak: two Gaussians 0.8 px apart, unequal) so that the
    # weighting matters; peak below saturation, as the bench's IR markers are.
    image = _spot_image(np.concatenate([centres, centres + [0.8, 0.3]]), sigma_px=0.5, peak=0.25, background=0.01)
    image = np.maximum(image, _spot_image(centres, sigma_px=0.5, peak=0.5, background=0.01))
    background_level = int(np.median(image))
    expected = _light_centroids(image, centres, background_level)
    rgb = np.repeat(image[..., None], 3, axis=2)

    def found(params: DetectionParams) -> np.ndarray:
        det = detect_markers(rgb, params)
        d = np.linalg.norm(det.xy[:, None, :] - expected[None], axis=2)
        if not np.all(d.min(axis=0) < 1.0):
            raise AssertionError("every spot must be detected")
        return det.xy[d.argmin(axis=0)]

    err_srgb = np.linalg.norm(found(DetectionParams(mode="ir")) - expected, axis=1)
    err_encoded = np.linalg.norm(found(DetectionParams(mode="ir", response="linear")) - expected, axis=1)
    assert err_srgb.max() < 0.01
    assert np.median(err_encoded) > 0.02


def test_linear_response_is_exact_on_linear_frames():
    """A camera with a linear output: the plain light-weighted centroid, no decoding."""
    rng = np.random.default_rng(5)
    centres = np.array([[40.3, 30.7], [90.8, 60.2], [120.45, 95.55]])
    h, w = 120, 160
    edges_x, edges_y = np.arange(w + 1) - 0.5, np.arange(h + 1) - 0.5
    light = np.zeros((h, w))
    s = np.sqrt(2.0) * 0.7
    for cx, cy in centres:
        light += np.outer(np.diff(0.5 * erf((edges_y - cy) / s)), np.diff(0.5 * erf((edges_x - cx) / s)))
    image = np.round(np.clip(light / light.max() * 250.0 + rng.normal(0, 0.3, light.shape), 0, 255)).astype(np.uint8)
    det = detect_markers(np.repeat(image[..., None], 3, axis=2), DetectionParams(mode="ir", response="linear"))
    d = np.linalg.norm(det.xy[:, None, :] - centres[None], axis=2)
    assert len(det.xy) == 3
    assert np.all(d.min(axis=0) < 0.03)
