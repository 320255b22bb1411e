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


def look_at(center: np.ndarray, target: np.ndarray, up: np.ndarray = (0.0, 0.0, 1.0)) -> tuple[np.ndarray, np.ndarray]:
    """World-to-camera ``(R (3, 3), t (3,))`` of a camera at ``center`` looking at ``target``.

    Camera axes follow OpenCV: ``z`` forward, ``x`` right, ``y`` down (``up`` is world up).
    """
    c = np.asarray(center, dtype=np.float64)
    z = np.asarray(target, dtype=np.float64) - c
    z /= np.linalg.norm(z)
    x = np.cross(z, np.asarray(up, dtype=np.float64))
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])
    return R, -R @ c


def observe_board(calibration, R_wb: np.ndarray, t_wb: np.ndarray, spec: BoardSpec, *,
                  rng: np.random.Generator, noise_px: float = 0.0, partial: bool | None = None,
                  max_view_angle_deg: float = 75.0, margin_px: float = 5.0) -> np.ndarray:
    """Exact board-corner observations of a rig, as a detector would report them.

    Parameters
    ----------
    calibration : mocap.calibration.Calibration
        The true rig.
    R_wb, t_wb : (V, 3, 3), (V, 3) float
        World-from-board pose of each view, metres.
    spec : BoardSpec
    rng : numpy.random.Generator
        For the pixel noise.
    noise_px : float
        Gaussian noise per coordinate, pixels.
    partial : bool, optional
        Keep views where only part of the board is in the image (default: ChArUco yes,
        checkerboard no, as the detectors behave).
    max_view_angle_deg : float
        The printed face is seen only when the angle between the board normal and the
        line of sight is below this.
    margin_px : float
        Corners closer than this to the image edge are not detected.

    Returns
    -------
    (C, V, N, 2) float
        Pixels, NaN where not seen.
    """
    obj = board_object_points(spec)
    partial = spec.kind == "charuco" if partial is None else partial
    R_wb = np.asarray(R_wb, dtype=np.float64)
    t_wb = np.asarray(t_wb, dtype=np.float64)
    V = len(R_wb)
    pw = np.einsum("vij,nj->vni", R_wb, obj) + t_wb[:, None, :]  # (V, N, 3)
    into_board = R_wb[:, :, 2]  # board +z in world, (V, 3)
    out = np.full((len(calibration), V, len(obj), 2), np.nan)
    cos_max = np.cos(np.radians(max_view_angle_deg))
    for c, cam in enumerate(calibration):
        sight = pw.mean(axis=1) - cam.center
        sight /= np.linalg.norm(sight, axis=1, keepdims=True)
        facing = np.einsum("vi,vi->v", sight, into_board) > cos_max
        uv = cam.project(pw.reshape(-1, 3)).reshape(V, len(obj), 2)
        ok = cam.in_image(uv.reshape(-1, 2), margin_px=margin_px).reshape(V, len(obj)) & facing[:, None]
        keep = ok.sum(axis=1) >= 6 if partial else ok.all(axis=1)
        ok &= keep[:, None]
        noisy = uv + rng.normal(0.0, noise_px, uv.shape) if noise_px > 0 else uv
        out[c] = np.where(ok[..., None], noisy, np.nan)
    return out
