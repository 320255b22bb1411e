"""The webcam's sensor and image pipeline: light in, 8-bit frame out.

:meth:`Sensor.frame` is the fast path the renderer uses; :meth:`Sensor.electrons` and
:meth:`Sensor.to_frame` are the reference implementation it is tested against.

Order of operations (per pixel, per channel), as in a real camera:
mean radiance over the shutter -> electrons (sensitivity x exposure time) ->
photon shot noise (Poisson, Gaussian approximation with variance = electrons) and
read noise (Gaussian, e-) -> clip at full well -> gain -> white balance (per-channel
gains; fixed for an illuminant, or auto grey-world with a time constant) ->
gamma (sRGB OETF) -> 8-bit quantisation -> optional JPEG.
In ``ir`` mode the sensor is monochrome (the three channels are equal).

Vignetting (``vignetting``) darkens the radiance radially before the electrons
(``1 - v * (r / r_corner)^2``). Auto exposure (``auto_exposure``, :class:`AutoExposure`)
multiplies the gain: each frame is metered (its mean linear level after gain) and the
gain of the next frame moves towards the level ``ae_target`` in the log domain with time
constant ``ae_adapt_s``, so after a step in the light the brightness error decays as
``exp(-t / ae_adapt_s)``, one frame late, as a webcam's does.
"""

from __future__ import annotations

import cv2
import numba
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


# The fast path's noise: a window of a pre-drawn table per frame (see Sensor._noise_window).
_NOISE_TABLE_MIN = 1 << 22  # entries (16 MB float32): four 640x480 RGB frames' worth
_NOISE_TABLE_SEED = 0x5EB5_7AB1E  # the table's generator when the caller gives none

# Values per block of the compiled index pass: a multiple of 3 (the channel pattern of
# the per-value gains repeats in every block) and of the SIMD width, so that the inner
# loop has a fixed trip count and compiles to vector code.
_BLOCK = 48


@numba.njit(cache=True, nogil=True, boundscheck=False, fastmath=True)
def _noisy_value(v, z, shot, read_var, full_well):
    """One value's electrons with noise (``v + z * sqrt(shot * v + read_var)``), clipped
    to ``[0, full_well]``; the variance is clamped at 0 for radiance below zero."""
    v = v + z * np.sqrt(max(shot * v + read_var, np.float32(0.0)))
    return min(max(v, np.float32(0.0)), full_well)


@numba.njit(cache=True, nogil=True, boundscheck=False, fastmath=True)
def _noisy_electrons(e, z, noisy, shot, read_var, full_well):
    """In place: electrons ``e (N,)`` float32 -> with shot + read noise from the standard
    normal deviates ``z (N,)`` (if ``noisy``), clipped to ``[0, full_well]``."""
    zero = np.float32(0.0)
    if noisy:
        for i in range(e.size):
            e[i] = _noisy_value(e[i], z[i], shot, read_var, full_well)
    else:
        for i in range(e.size):
            e[i] = min(max(e[i], zero), full_well)


@numba.njit(cache=True, nogil=True, boundscheck=False, fastmath=True)
def _noisy_index(e, z, noisy, shot, read_var, full_well, kk, top, idx):
    """Electrons ``e (N,)`` float32 -> gamma-table indices ``idx (N,)`` uint16, one pass.

    Noise as :func:`_noisy_electrons` (if ``noisy``; ``z (N,)`` standard normal), clip to
    ``[0, full_well]``, then ``idx = clip(e * k + 0.5, 0, top)`` truncated, as
    :meth:`Sensor.to_frame`; ``kk (_BLOCK,)`` float32 holds each value's ``k`` (gain x
    white balance x table size / full well) for one block, the channel pattern repeated.
    """
    n = e.size
    nb = n // _BLOCK
    half = np.float32(0.5)
    zero = np.float32(0.0)
    # Full blocks, then the tail in a loop of its own: with the tail inside the block loop
    # the vectoriser's run-time overlap check of idx against e and z spans up to a block
    # beyond the arrays' ends, so arrays within ~200 bytes of each other (the work
    # arrays are often allocated back to back) fell back to the scalar loop, 6x slower.
    if noisy:
        for b in range(nb):
            o = b * _BLOCK
            for j in range(_BLOCK):
                v = _noisy_value(e[o + j], z[o + j], shot, read_var, full_well)
                idx[o + j] = np.uint16(min(max(v * kk[j] + half, zero), top))
    else:
        for b in range(nb):
            o = b * _BLOCK
            for j in range(_BLOCK):
                v = min(max(e[o + j], zero), full_well)
                idx[o + j] = np.uint16(min(max(v * kk[j] + half, zero), top))
    for i in range(nb * _BLOCK, n):
        v = e[i]
        v = _noisy_value(v, z[i], shot, read_var, full_well) if noisy else min(max(v, zero), full_well)
        idx[i] = np.uint16(min(max(v * kk[i - nb * _BLOCK] + half, zero), top))


@numba.njit(cache=True, nogil=True, boundscheck=False)
def _gather(idx, table, out):
    """``out[i] = table[idx[i]]`` for ``idx (N,)`` uint16 within the table (about 2.5x
    ``np.take`` here: no bounds checks, vector gathers)."""
    for i in range(idx.size):
        out[i] = table[idx[i]]


def gaussian_half_kernel(sigma_px: float) -> np.ndarray:
    """Centre-first half ``(r + 1,)`` float64 of OpenCV's Gaussian kernel for float images,
    without its negligible outer taps.

    ``cv2.GaussianBlur`` on float32 uses ``round(8 sigma + 1) | 1`` taps. Outer taps
    whose summed weight (both sides) is below 1e-4 are dropped and the rest
    renormalised: no output moves by more than 0.03 grey level, and at the default
    sigma (0.4 px) the 5 x 5 kernel becomes 3 x 3 (its outer taps weigh 4e-6 each).
    """
    ksize = int(np.round(sigma_px * 8 + 1)) | 1
    k = cv2.getGaussianKernel(ksize, sigma_px, cv2.CV_64F).ravel()
    half = k[ksize // 2:].copy()
    while len(half) > 1 and 2 * half[-1] < 1e-4:
        half = half[:-1]
    return half / (half[0] + 2 * half[1:].sum())


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
        return self.update_means(linear_rgb.reshape(-1, 3)[::7].mean(axis=0))

    def update_means(self, means: np.ndarray) -> np.ndarray:
        """Feed the per-channel means ``(3,)`` of a linear frame; returns its gains ``(3,)``."""
        if self.mode == "fixed":
            return self.gains
        means = np.asarray(means) + 1e-6  # dtype kept: float32 from `update`, as before
        target = (means[1] / means).astype(np.float32)
        if not self._started:
            self.gains = target
            self._started = True
        else:
            self.gains = (1 - self.alpha) * self.gains + self.alpha * target
        return self.gains


class AutoExposure:
    """A camera's auto exposure: a gain multiplier ``gain`` (1 .. ``ae_max_gain``, ``1 / ae_max_gain``
    at the least) that follows the metered level towards ``ae_target`` with time constant ``ae_adapt_s``.

    The first frame starts at the gain its own (noise-free) level asks for; after that each
    frame's metered level sets the next frame's gain (:meth:`update`):
    ``log g <- log g + alpha * log(target / level)``, ``alpha = 1 - exp(-1 / (fps * ae_adapt_s))``.
    """

    def __init__(self, cfg: SensorConfig, fps: float) -> None:
        self.target = float(cfg.ae_target)
        self.alpha = float(1.0 - np.exp(-1.0 / (fps * cfg.ae_adapt_s)))
        self.lo, self.hi = 1.0 / float(cfg.ae_max_gain), float(cfg.ae_max_gain)
        self.gain = 1.0
        self.started = False
        self.history: list[tuple[float, float]] = []  # (gain applied, metered level) per frame

    def start(self, level_at_unit_gain: float) -> None:
        """Set the first frame's gain from its level at gain 1."""
        self.gain = float(np.clip(self.target / max(level_at_unit_gain, 1e-6), self.lo, self.hi))
        self.started = True

    def update(self, level: float) -> None:
        """Feed the metered level (0..1, linear, after this frame's gain); sets the next frame's gain."""
        self.history.append((self.gain, float(level)))
        step = self.alpha * np.log(self.target / max(float(level), 1e-6))
        self.gain = float(np.clip(self.gain * np.exp(step), self.lo, self.hi))


def vignetting_map(height: int, width: int, strength: float) -> np.ndarray:
    """Relative illumination ``(H, W)`` float32: ``1 - strength * (r / r_corner)^2`` about the image centre."""
    y, x = np.mgrid[0:height, 0:width].astype(np.float32)
    cy, cx = (height - 1) / 2.0, (width - 1) / 2.0
    r2 = ((x - cx) ** 2 + (y - cy) ** 2) / (cx**2 + cy**2)
    return (1.0 - np.float32(strength) * r2).astype(np.float32)


class Sensor:
    """Turns time-averaged radiance into the camera's 8-bit frame."""

    def __init__(self, cfg: SensorConfig, fps: float, work: dict | None = None,
                 noise_rng: np.random.Generator | None = None) -> None:
        """``work``: scratch arrays of :meth:`frame` and its noise table, shareable by the
        sensors of cameras that are processed one after the other (a new dict if None).
        ``noise_rng``: draws the noise table (see :meth:`_noise_window`) the first time a
        noisy frame needs it; None: a generator of a fixed seed (frames then depend only
        on the generators passed to :meth:`frame`)."""
        self.cfg = cfg
        self.scale = np.float32(cfg.electrons_per_unit * cfg.exposure_ms * 1e-3)
        self.lut = _gamma_lut(cfg.gamma)
        self.fps = fps
        self._buffers: dict[tuple, np.ndarray] = {} if work is None else work
        self.noise_rng = np.random.default_rng(_NOISE_TABLE_SEED) if noise_rng is None else noise_rng

    # ------------------------------------------------------------ fast path
    def _buffer(self, name: str, shape: tuple[int, ...], dtype) -> np.ndarray:
        """A scratch array, reused from frame to frame (fresh multi-MB arrays cost page
        faults on every frame); its content does not outlive a :meth:`frame` call."""
        key = (name, shape, np.dtype(dtype).str)
        buf = self._buffers.get(key)
        if buf is None:
            buf = self._buffers[key] = np.empty(shape, dtype)
        return buf

    def _noise_window(self, rng: np.random.Generator, n: int) -> np.ndarray:
        """``n`` float32 standard normal deviates ``(n,)`` for one frame: a window of the
        shared pre-drawn table (:data:`_NOISE_TABLE_MIN` entries or four frames' worth,
        drawn once from the sensor's ``noise_rng``) at an offset drawn from ``rng``.

        Why a table: fresh Gaussian samples for 921,600 values cost ~6 ms a frame on one
        core, a window costs nothing (the kernel reads it). Statistics: within a frame all
        values are distinct table entries (independent); a pixel's values in two frames
        are entries ``off1 + i`` and ``off2 + i``, distinct unless the offsets coincide
        (probability ~1 / 3 million per pair of frames at 640x480), so its temporal
        noise is independent too. The only structure is that two frames whose windows
        overlap share a *shifted* copy of noise (value ``i`` of one is value ``i + d`` of
        the other for a random ``d``): no statistic of a pixel, of neighbouring pixels
        or channels, or of one pixel over time sees it.
        """
        table = self._buffers.get(("noise_table",))
        if table is None or len(table) < 4 * n:
            size = max(_NOISE_TABLE_MIN, 4 * n)
            table = self._buffers[("noise_table",)] = self.noise_rng.standard_normal(size, dtype=np.float32)
        off = int(rng.integers(0, len(table) - n + 1))
        return table[off: off + n]

    def frame(self, radiance: np.ndarray, rng: np.random.Generator | None, wb: WhiteBalance | None,
              psf_sigma_px: float = 0.0, n_subframes: int = 1, out: np.ndarray | None = None,
              ae: AutoExposure | None = None) -> np.ndarray:
        """Radiance at the image -> the camera's 8-bit frame, optics blur included (fast path).

        The same model as ``cv2.GaussianBlur`` then :meth:`electrons` then
        :meth:`to_frame` (the reference implementation, kept for tests), arranged for
        speed on one core, ~10x faster: channels are dropped first (alpha of an RGBA
        read-back; all but red in ``ir`` mode), the exposure scale (and 1 / number of
        sub-frames) is folded into the blur kernel, the kernel's negligible outer taps
        are dropped (:func:`gaussian_half_kernel`), noise, full-well clip, gain x white
        balance and the gamma-table index are one compiled pass (:func:`_noisy_index`),
        the gamma table look-up another (:func:`_gather`), the normal deviates are a
        window of a pre-drawn table (:meth:`_noise_window`), and work arrays are reused.
        Noise-free output equals the reference's within one grey level (float rounding
        at table index boundaries); with noise, the same distribution, not the same draws.

        Parameters
        ----------
        radiance : (H, W, C) float32, C in 1, 3, 4 (RGBA read-back), or (H, W): the sum
            of ``n_subframes`` sub-frames' linear radiance at the (distorted) image
        rng : the frame's generator (draws one integer, the noise table offset), or
            None for no noise
        wb : the camera's white balance (ignored in ``ir`` mode)
        psf_sigma_px : Gaussian optics blur in pixels (0: none)
        n_subframes : number of shutter sub-frames summed in ``radiance``
        out : (H, W, 3) uint8 C-contiguous array to write the frame into (saves a copy of
            a new array), or None
        ae : the camera's auto exposure (its gain multiplies ``gain``; metered here), or None

        Returns
        -------
        (H, W, 3) uint8 RGB frame (equal channels in ``ir`` mode): ``out`` when given
        """
        cfg = self.cfg
        mono = cfg.mode == "ir"
        rad = self._channels(radiance, mono)
        H, W = rad.shape[:2]
        e = self._exposed(rad, (H, W) if mono else (H, W, 3), psf_sigma_px, n_subframes)
        flat = e.reshape(-1)
        noisy = rng is not None and (cfg.shot_noise or cfg.read_noise_e > 0)
        z = self._noise_window(rng, flat.size) if noisy else flat  # (unread without noise)
        shot = np.float32(1.0 if cfg.shot_noise else 0.0)
        read_var = np.float32(cfg.read_noise_e**2)
        full_well = np.float32(cfg.full_well_e)
        top = 2**_LUT_BITS - 1
        k_idx, noisy = self._index_scale(e, flat, z, noisy, shot, read_var, full_well, top, mono, wb, ae)
        # Per-value index scale, the channel pattern repeated over one kernel block.
        kk = np.resize(np.asarray(k_idx, np.float32).reshape(-1), _BLOCK)
        idx = self._buffer("idx", (flat.size,), np.uint16)
        _noisy_index(flat, z, noisy, shot, read_var, full_well, kk, np.float32(top), idx)
        if ae is not None:
            ae.update(float(idx[::7].mean()) / top)
        frame = self._gamma(idx, mono, H, W, out)
        if cfg.jpeg_quality > 0:
            frame[...] = self.compress(frame)
        return frame

    def _channels(self, radiance: np.ndarray, mono: bool) -> np.ndarray:
        """:meth:`frame`'s first step: the radiance's channels the sensor sees, ``(H, W)`` red
        in ``ir`` mode, else ``(H, W, 3)`` (the alpha of an RGBA read-back dropped)."""
        rad = radiance if radiance.ndim == 3 else radiance[..., None]
        if mono:
            rad = rad[..., 0] if rad.shape[2] == 1 else cv2.extractChannel(np.ascontiguousarray(rad), 0)
        elif rad.shape[2] == 4:
            rad = cv2.cvtColor(rad, cv2.COLOR_RGBA2RGB, dst=self._buffer("rgb", rad.shape[:2] + (3,), np.float32))
        return rad

    def _exposed(self, rad: np.ndarray, shape: tuple[int, ...], psf_sigma_px: float, n_subframes: int) -> np.ndarray:
        """:meth:`frame`'s electrons before noise, ``shape`` float32 (a work buffer): the optics
        blur with the exposure scale and 1 / ``n_subframes`` folded into its kernel, then
        vignetting."""
        H, W = shape[:2]
        scale = np.float32(self.scale / np.float32(n_subframes))
        e = self._buffer("e", shape, np.float32)
        if psf_sigma_px > 0:
            k = gaussian_half_kernel(psf_sigma_px)
            k = np.concatenate([k[:0:-1], k]).astype(np.float32)
            cv2.sepFilter2D(rad, cv2.CV_32F, k * scale, k, dst=e, borderType=cv2.BORDER_REFLECT_101)
        else:
            np.multiply(rad, scale, out=e)
        if self.cfg.vignetting > 0:
            e *= self._vignetting(H, W).reshape((H, W) + (1,) * (e.ndim - 2))
        return e

    def _index_scale(self, e: np.ndarray, flat: np.ndarray, z: np.ndarray, noisy: bool, shot: np.float32,
                     read_var: np.float32, full_well: np.float32, top: int, mono: bool, wb: WhiteBalance | None,
                     ae: AutoExposure | None) -> tuple[np.ndarray, bool]:
        """:meth:`frame`'s gain x white balance: the scale from electrons to gamma-table index,
        a float32 scalar or per channel ``(3,)``, and whether noise is still to be added. Auto
        exposure starts from this frame if it has not; grey-world white balance meters the
        clipped noisy linear frame, so the noise is added to ``flat`` (``e``) here, in place."""
        cfg = self.cfg
        if ae is not None and not ae.started:
            ae.start(float(np.mean(np.minimum(flat[::7], cfg.full_well_e))) * cfg.gain / cfg.full_well_e)
        k_idx = np.float32(cfg.gain * (ae.gain if ae is not None else 1.0) / cfg.full_well_e * top)
        if not mono and wb is not None:
            if wb.mode == "fixed":
                k_idx = (wb.gains * k_idx).astype(np.float32)
            else:  # grey world sees the clipped noisy linear frame, subsampled as the reference does
                _noisy_electrons(flat, z, noisy, shot, read_var, full_well)
                noisy = False
                k_idx = (wb.update_means(e.reshape(-1, 3)[::7].mean(axis=0)) * k_idx).astype(np.float32)
        return k_idx, noisy

    def _gamma(self, idx: np.ndarray, mono: bool, H: int, W: int, out: np.ndarray | None) -> np.ndarray:
        """:meth:`frame`'s gamma step: the table levels of the indices ``idx`` as the ``(H, W, 3)``
        uint8 frame, written into ``out`` if given (checked) else a new array."""
        if out is None:
            frame = np.empty((H, W, 3), np.uint8)
        elif out.shape != (H, W, 3) or out.dtype != np.uint8 or not out.flags.c_contiguous:
            raise ValueError(f"out must be a C-contiguous ({H}, {W}, 3) uint8 array")
        else:
            frame = out
        if mono:
            level = self._buffer("level", (H, W), np.uint8)
            _gather(idx, self.lut, level.reshape(-1))
            cv2.cvtColor(level, cv2.COLOR_GRAY2RGB, dst=frame)
        else:
            _gather(idx, self.lut, frame.reshape(-1))
        return frame

    def _vignetting(self, height: int, width: int) -> np.ndarray:
        key = ("vignetting", height, width)
        v = self._buffers.get(key)
        if v is None:
            v = self._buffers[key] = vignetting_map(height, width, self.cfg.vignetting)
        return v

    # ------------------------------------------------------------ reference
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
        if cfg.vignetting > 0:
            e *= vignetting_map(e.shape[0], e.shape[1], cfg.vignetting)[..., None]
        if rng is not None and (cfg.shot_noise or cfg.read_noise_e > 0):
            std = (e + np.float32(cfg.read_noise_e**2)) if cfg.shot_noise else np.full_like(e, cfg.read_noise_e**2)
            np.maximum(std, 0, out=std)
            np.sqrt(std, out=std)
            noise = standard_normal_f32(rng, e.shape)
            noise *= std
            e += noise
        np.clip(e, 0, cfg.full_well_e, out=e)
        return e

    def to_frame(self, electrons: np.ndarray, wb: WhiteBalance | None, ae: AutoExposure | None = None) -> np.ndarray:
        """Electrons ``(H, W, C)`` -> uint8 ``(H, W, 3)`` (RGB order)."""
        cfg = self.cfg
        top = 2**_LUT_BITS - 1
        if ae is not None and not ae.started:
            ae.start(float(np.mean(electrons.reshape(-1)[::7])) * cfg.gain / cfg.full_well_e)
        k = np.float32(cfg.gain * (ae.gain if ae is not None else 1.0) / cfg.full_well_e * top)
        if electrons.shape[2] == 3 and wb is not None:
            # Auto white balance looks at the linear image before its gains.
            k = (wb.update(electrons) * k).astype(np.float32)
        x = electrons * k
        x += np.float32(0.5)
        np.clip(x, 0, top, out=x)
        if ae is not None:
            ae.update(float(np.floor(x).reshape(-1)[::7].mean()) / top)
        frame = np.take(self.lut, x.astype(np.uint16))
        if frame.shape[2] == 1:
            frame = np.repeat(frame, 3, axis=2)
        return self.compress(frame)

    def compress(self, frame: np.ndarray) -> np.ndarray:
        """JPEG round trip of an RGB frame ``(H, W, 3)`` uint8 if configured (else the frame)."""
        q = self.cfg.jpeg_quality
        if q > 0:
            ok, enc = cv2.imencode(".jpg", frame[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, q])
            if not ok:
                raise RuntimeError("JPEG encoding failed")
            frame = cv2.imdecode(enc, cv2.IMREAD_COLOR)[..., ::-1]
        return np.ascontiguousarray(frame)
