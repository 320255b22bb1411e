"""The webcam's sensor and image pipeline: light in, 8-bit frame out.

Order of operations (per pixel, per channel), as in a real camera:
mean radiance over the shutter -> electrons (sensitivity x exposure time) ->
photon shot noise (Poisson, Gaussian approximation with variance = electrons) and
read noise (Gaussian, e-) -> clip at full well -> gain -> white balance (per-channel
gains; fixed for an illuminant, or auto grey-world with a time constant) ->
gamma (sRGB OETF) -> 8-bit quantisation -> optional JPEG.
In ``ir`` mode the sensor is monochrome (the three channels are equal).
"""

from __future__ import annotations

import cv2
import numpy as np
from scipy.special import ndtri

from simbench.render.color import cct_to_rgb
from simbench.scenario import SensorConfig

_LUT_BITS = 14

# Standard normal deviates by inverse-transform sampling from a table of the 65536
# quantiles (k + 0.5) / 65536: two cheap passes (uint16 draws, a gather) instead of
# numpy's Gaussian sampler, ~3x faster per pixel here; exact to 16-bit resolution
# (variance 1.0001, kurtosis 3.002, tails cut at 4.3 sigma: immaterial for sensor noise).
_NORMAL_TABLE = ndtri((np.arange(65536) + 0.5) / 65536).astype(np.float32)


def standard_normal_f32(rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
    """Standard normal float32 samples of ``shape`` from ``rng`` (see ``_NORMAL_TABLE``)."""
    return np.take(_NORMAL_TABLE, rng.integers(0, 65536, size=shape, dtype=np.uint16))


def _gamma_lut(kind: str) -> np.ndarray:
    x = np.arange(2**_LUT_BITS, dtype=np.float64) / (2**_LUT_BITS - 1)
    if kind == "srgb":
        y = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    else:
        y = x
    return np.round(y * 255.0).astype(np.uint8)


class WhiteBalance:
    """Camera white-balance gains ``(3,)`` (green = 1), fixed or auto (grey world)."""

    def __init__(self, cfg: SensorConfig, fps: float) -> None:
        self.mode = cfg.white_balance
        white = cct_to_rgb(cfg.wb_cct_k)
        self.fixed_gains = (white[1] / white).astype(np.float32)
        self.alpha = float(1.0 - np.exp(-1.0 / (fps * cfg.wb_adapt_s)))
        self.gains = self.fixed_gains.copy()
        self._started = False

    def update(self, linear_rgb: np.ndarray) -> np.ndarray:
        """Feed a linear frame (before gains); returns the gains to apply to it."""
        if self.mode == "fixed":
            return self.gains
        means = linear_rgb.reshape(-1, 3)[::7].mean(axis=0) + 1e-6
        target = (means[1] / means).astype(np.float32)
        if not self._started:
            self.gains = target
            self._started = True
        else:
            self.gains = (1 - self.alpha) * self.gains + self.alpha * target
        return self.gains


class Sensor:
    """Turns time-averaged radiance into the camera's 8-bit frame."""

    def __init__(self, cfg: SensorConfig, fps: float) -> None:
        self.cfg = cfg
        self.scale = np.float32(cfg.electrons_per_unit * cfg.exposure_ms * 1e-3)
        self.lut = _gamma_lut(cfg.gamma)
        self.fps = fps

    def electrons(self, radiance: np.ndarray, rng: np.random.Generator | None) -> np.ndarray:
        """Mean radiance ``(H, W, 3)`` -> noisy electron counts ``(H, W, C)`` float32.

        Shot noise uses the Gaussian approximation of the Poisson law (variance = mean),
        exact to well under a grey level above ~20 e-; written in place because this
        runs on every pixel of every frame.
        """
        cfg = self.cfg
        if cfg.mode == "ir" and radiance.shape[2] != 1:
            radiance = radiance[..., :1]  # the IR sensor: one channel (the renderer's red ~ near infrared)
        e = np.multiply(radiance, self.scale, dtype=np.float32)
        if rng is not None and (cfg.shot_noise or cfg.read_noise_e > 0):
            std = (e + np.float32(cfg.read_noise_e**2)) if cfg.shot_noise else np.full_like(e, cfg.read_noise_e**2)
            np.maximum(std, 0, out=std)
            np.sqrt(std, out=std)
            noise = standard_normal_f32(rng, e.shape)
            noise *= std
            e += noise
        np.clip(e, 0, cfg.full_well_e, out=e)
        return e

    def to_frame(self, electrons: np.ndarray, wb: WhiteBalance | None) -> np.ndarray:
        """Electrons ``(H, W, C)`` -> uint8 ``(H, W, 3)`` (RGB order)."""
        cfg = self.cfg
        top = 2**_LUT_BITS - 1
        k = np.float32(cfg.gain / cfg.full_well_e * top)
        if electrons.shape[2] == 3 and wb is not None:
            # Auto white balance looks at the linear image before its gains.
            k = (wb.update(electrons) * k).astype(np.float32)
        x = electrons * k
        x += np.float32(0.5)
        np.clip(x, 0, top, out=x)
        frame = np.take(self.lut, x.astype(np.uint16))
        if frame.shape[2] == 1:
            frame = np.repeat(frame, 3, axis=2)
        if cfg.jpeg_quality > 0:
            ok, enc = cv2.imencode(".jpg", frame[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, cfg.jpeg_quality])
            frame = cv2.imdecode(enc, cv2.IMREAD_COLOR)[..., ::-1]
        return np.ascontiguousarray(frame)
