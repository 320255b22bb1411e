"""Exact synthetic pictures of a calibration board, without a 3D renderer.

A board texture (:func:`mocap.calib.boards.render_board_texture`) is mapped through a
:class:`mocap.calibration.Camera` (pinhole + OpenCV distortion) at a known board pose,
supersampled and box-filtered like a sensor, then optionally blurred and noised. The
exact corner positions come from ``Camera.project`` of the board's object points, so
detectors and the whole calibration can be checked against ground truth in
milliseconds.
"""

from __future__ import annotations

import cv2
import numpy as np

from mocap.calib.boards import BoardSpec, board_object_points, board_texture_layout, render_board_texture
from mocap.calibration import Camera


def board_corners_in_image(camera: Camera, R_wb: np.ndarray, t_wb: np.ndarray, spec: BoardSpec) -> np.ndarray:
    """Exact distorted pixels ``(N, 2)`` of the board corners at world-from-board pose ``(R_wb, t_wb)``."""
    obj = board_object_points(spec)
    return camera.project(obj @ np.asarray(R_wb).T + np.asarray(t_wb))


def render_board_view(camera: Camera, R_wb: np.ndarray, t_wb: np.ndarray, spec: BoardSpec, *,
                      px_per_m: float = 4000.0, supersample: int = 3, background: int = 110,
                      blur_sigma_px: float = 0.0, noise_sigma: float = 0.0,
                      rng: np.random.Generator | None = None) -> np.ndarray:
    """Grey image ``(H, W)`` uint8 of the board seen by ``camera``.

    Parameters
    ----------
    camera : Camera
        Intrinsics, distortion and world-to-camera pose.
    R_wb, t_wb : (3, 3), (3,) float
        World-from-board pose (board frame as in :mod:`mocap.calib.boards`), metres.
    px_per_m : float
        Texture resolution; keep it above the image's own (pixels per metre on the board).
    supersample : int
        Sub-samples per pixel side (anti-aliasing by box filter).
    background : int
        Grey level outside the board texture.
    blur_sigma_px, noise_sigma : float
        Gaussian optical blur (pixels) and additive Gaussian noise (grey levels).
    rng : numpy.random.Generator
        Needed when ``noise_sigma > 0``.
    """
    tex = render_board_texture(spec, px_per_m)
    lay = board_texture_layout(spec, px_per_m)
    w, h = camera.size
    s = int(supersample)
    # Texture coordinates are computed exactly at pixel centres (plus a one-pixel
    # border) and bilinearly upsampled to the sub-samples: the map is smooth, so this
    # costs << 0.01 px while undistorting s*s times fewer points.
    gx, gy = np.meshgrid(np.arange(-1, w + 1, dtype=np.float64), np.arange(-1, h + 1, dtype=np.float64))
    rays = camera.normalized_rays(np.column_stack([gx.ravel(), gy.ravel()]))  # world directions
    # Intersect the rays from the camera centre with the board plane z_b = 0.
    R_wb = np.asarray(R_wb, dtype=np.float64)
    t_wb = np.asarray(t_wb, dtype=np.float64)
    c_b = R_wb.T @ (camera.center - t_wb)
    d_b = rays @ R_wb  # R_wb.T @ ray, row-wise
    with np.errstate(divide="ignore", invalid="ignore"):
        lam = -c_b[2] / d_b[:, 2]
    p_b = c_b[None, :] + lam[:, None] * d_b
    u = p_b[:, 0] * lay.px_per_m + lay.origin_px[0]
    v = p_b[:, 1] * lay.px_per_m + lay.origin_px[1]
    bad = ~np.isfinite(lam) | (lam <= 0)
    u[bad] = -1e6
    v[bad] = -1e6
    size_big = ((w + 2) * s, (h + 2) * s)
    mapx = cv2.resize(u.reshape(h + 2, w + 2), size_big, interpolation=cv2.INTER_LINEAR)[s:-s, s:-s].astype(np.float32)
    mapy = cv2.resize(v.reshape(h + 2, w + 2), size_big, interpolation=cv2.INTER_LINEAR)[s:-s, s:-s].astype(np.float32)
    big = cv2.remap(tex.astype(np.float32), mapx, mapy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                    borderValue=float(background))
    img = big.reshape(h, s, w, s).mean(axis=(1, 3))
    if blur_sigma_px > 0:
        img = cv2.GaussianBlur(img, (0, 0), blur_sigma_px)
    if noise_sigma > 0:
        if rng is None:
            raise ValueError("render_board_view: pass rng (numpy.random.Generator) when noise_sigma > 0")
        img = img + rng.normal(0.0, noise_sigma, img.shape)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)
