"""Virtual webcams: pinhole + OpenCV distortion, placed by position and look-at.

Distortion is applied exactly as OpenCV models it: the scene is rasterised through
an ideal pinhole onto a *canvas* large enough to hold every ray the distorted
camera sees, and each output pixel ``(u, v)`` samples the canvas where its
undistorted ray lands (``cv2.undistortPoints`` inverts OpenCV's forward model
iteratively to 1e-12). So ``cv2.projectPoints`` with the camera's K and dist lands
on the rendered image of a point.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from mocap.calibration import Camera
from mocap.calibration_formats import load_calibration
from simbench.scenario import CameraConfig, RigConfig


def look_at_rotation(position: np.ndarray, target: np.ndarray, up: np.ndarray = np.array([0.0, 0.0, 1.0])) -> np.ndarray:
    """World-to-camera rotation (rows: camera x right, y down, z forward)."""
    z = np.asarray(target, float) - np.asarray(position, float)
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    if np.linalg.norm(x) < 1e-9:  # looking straight along `up`
        x = np.cross(z, np.array([1.0, 0.0, 0.0]))
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return np.vstack([x, y, z])


def intrinsics_from_fov(width: int, height: int, hfov_deg: float) -> np.ndarray:
    f = 0.5 * width / np.tan(np.deg2rad(hfov_deg) / 2)
    return np.array([[f, 0, (width - 1) / 2], [0, f, (height - 1) / 2], [0, 0, 1.0]])


@dataclass
class Canvas:
    """Where the pinhole render lives for one camera at one supersampling factor.

    width, height : supersampled canvas size in pixels
    K : (3, 3) intrinsics of the supersampled canvas
    map_xy : (H, W, 2) float32 or None — for each output pixel, its position on the
        1x canvas (None when the camera has no distortion and the canvas is the image)
    ss : supersampling factor per axis
    """

    width: int
    height: int
    K: np.ndarray
    map_xy: np.ndarray | None
    ss: int


@dataclass
class VirtualCamera:
    """A webcam of the virtual rig (exact ground truth of its own calibration)."""

    name: str
    width: int
    height: int
    K: np.ndarray
    dist: np.ndarray
    R: np.ndarray
    t: np.ndarray
    _canvas: dict = field(default_factory=dict, repr=False)

    @classmethod
    def from_config(cls, cfg: CameraConfig) -> "VirtualCamera":
        K = np.asarray(cfg.K, float) if cfg.K is not None else intrinsics_from_fov(cfg.width, cfg.height, cfg.hfov_deg)
        R = look_at_rotation(np.asarray(cfg.position), np.asarray(cfg.look_at), np.asarray(cfg.up))
        t = -R @ np.asarray(cfg.position, float)
        return cls(cfg.name, cfg.width, cfg.height, K, np.asarray(cfg.distortion, float), R, t)

    @classmethod
    def rig(cls, cfg: RigConfig) -> list["VirtualCamera"]:
        """``count`` cameras evenly spread over ``span_deg`` of azimuth around ``look_at`` (:meth:`RigConfig.camera_configs`)."""
        return [cls.from_config(c) for c in cfg.camera_configs()]

    # ------------------------------------------------------------------ geometry
    @property
    def center(self) -> np.ndarray:
        return -self.R.T @ self.t

    def calibration_camera(self) -> Camera:
        """The exact calibration as the pipeline's :class:`mocap.calibration.Camera`."""
        return Camera(self.name, (self.width, self.height), self.K, self.dist, self.R, self.t)

    def project(self, p3ds: np.ndarray) -> np.ndarray:
        """World points ``(N, 3)`` -> distorted pixels ``(N, 2)`` (cv2.projectPoints)."""
        return self.calibration_camera().project(p3ds)

    def depth(self, p3ds: np.ndarray) -> np.ndarray:
        """Camera-frame z ``(N,)`` in metres."""
        return (np.asarray(p3ds) @ self.R.T + self.t)[:, 2]

    def canvas(self, ss: int) -> Canvas:
        """Pinhole canvas covering the distorted field of view, supersampled ``ss`` x ``ss``."""
        if ss in self._canvas:
            return self._canvas[ss]
        W, H = self.width, self.height
        if not np.any(self.dist):
            K1 = self.K.copy()
            W1, H1 = W, H
            map_xy = None
        else:
            u, v = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
            pts = np.stack([u.ravel(), v.ravel()], axis=1).reshape(-1, 1, 2)
            und = cv2.undistortPoints(pts, self.K, self.dist, None, None, self.K,
                                      (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 60, 1e-12)).reshape(H, W, 2)
            margin = 3
            x0 = int(np.floor(und[..., 0].min())) - margin
            y0 = int(np.floor(und[..., 1].min())) - margin
            x1 = int(np.ceil(und[..., 0].max())) + margin
            y1 = int(np.ceil(und[..., 1].max())) + margin
            # Guard against extreme distortion blowing the canvas up.
            x0, y0 = max(x0, -W), max(y0, -H)
            x1, y1 = min(x1, 2 * W), min(y1, 2 * H)
            K1 = self.K.copy()
            K1[0, 2] -= x0
            K1[1, 2] -= y0
            W1, H1 = x1 - x0 + 1, y1 - y0 + 1
            map_xy = (und - np.array([x0, y0])).astype(np.float32)
        Ks = K1.copy()
        Ks[0, 0] *= ss
        Ks[1, 1] *= ss
        Ks[0, 1] *= ss
        Ks[0, 2] = (K1[0, 2] + 0.5) * ss - 0.5
        Ks[1, 2] = (K1[1, 2] + 0.5) * ss - 0.5
        c = Canvas(W1 * ss, H1 * ss, Ks, map_xy, ss)
        self._canvas[ss] = c
        return c

    def finish_radiance(self, canvas_radiance: np.ndarray, ss: int) -> np.ndarray:
        """Supersampled pinhole radiance -> radiance in the distorted image ``(H, W, 3)``."""
        c = self.canvas(ss)
        img = canvas_radiance
        if ss > 1:  # INTER_AREA at an integer factor is the exact box filter over ss x ss samples
            img = cv2.resize(img, (img.shape[1] // ss, img.shape[0] // ss), interpolation=cv2.INTER_AREA)
            if img.ndim == 2:
                img = img[..., None]
        if c.map_xy is not None:
            img = cv2.remap(img, c.map_xy[..., 0], c.map_xy[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
        return img

    def finish_nearest(self, canvas_img: np.ndarray, ss: int) -> np.ndarray:
        """Supersampled id or depth canvas -> the distorted image, nearest sample."""
        c = self.canvas(ss)
        if c.map_xy is None:
            off = ss // 2
            return canvas_img[off::ss, off::ss]
        mx = c.map_xy[..., 0] * ss + (ss - 1) / 2
        my = c.map_xy[..., 1] * ss + (ss - 1) / 2
        ix = np.clip(np.rint(mx).astype(np.int32), 0, canvas_img.shape[1] - 1)
        iy = np.clip(np.rint(my).astype(np.int32), 0, canvas_img.shape[0] - 1)
        out = canvas_img[iy, ix]
        outside = (mx < -0.5) | (my < -0.5) | (mx > canvas_img.shape[1] - 0.5) | (my > canvas_img.shape[0] - 0.5)
        out[outside] = 0
        return out


def cameras_from_scenario(scenario) -> list[VirtualCamera]:
    cams = [VirtualCamera.from_config(c) for c in scenario.cameras]
    if scenario.rig is not None and not cams:
        if scenario.rig.from_calibration is not None:  # a lab's own rig: exactly the file's cameras
            calibration = load_calibration(scenario.resolve_path(scenario.rig.from_calibration))
            return [VirtualCamera(c.name, c.size[0], c.size[1], c.K.copy(), c.dist.copy(), c.R.copy(), c.t.copy())
                    for c in calibration]
        cams = VirtualCamera.rig(scenario.rig)
    return cams
