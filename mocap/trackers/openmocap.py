"""Seed 000's three trackers as OpenMoCap had them, batched over markers.

Seed 000 (OpenMoCap, Section IV) names the settings it ran with -- alpha-beta with
alpha 1.0 and beta 0.8, a Kalman filter whose process noise ``Q`` and search area grow
with the marker's speed, CONDENSATION with 100 particles and a position-only state --
but not the rest. The rest is taken from OpenMoCap's own source, the software the paper
evaluates (github.com/davidflam/OpenMoCap, ``Src/Tracking``: ``AlphaBetaGammaFilter``,
``KalmanFilter``, ``Condensation``; the parameters below are its constants, the code is
written anew for :class:`~mocap.trackers.base.Tracker2D`). What OpenMoCap does there:

* everything is per **frame** (its Kalman filter has ``dT = 1``), not per second: the
  parameters below are in px and px/frame at the camera's frame rate;
* a label whose search area holds no detection keeps going on its prediction
  (*inertia*) and is never given up: ``max_coast_frames`` defaults to
  :data:`NEVER_LOST` here (the base class's loss handling is the bench's, not the
  paper's);
* association is the nearest detection inside the search circle, label by label; with
  one labelled marker (all of seed 000's videos) that is what the shared gated
  assignment of :class:`~mocap.trackers.base.Tracker2D` does too.

``alpha_beta`` -- :class:`AlphaBetaTracker`
    Equations (1)-(3) with alpha 1.0 and beta 0.8 (dt = one frame), search circle of a
    **fixed** radius: 5 % of the image diagonal, 40 px at 640x480. Without a detection
    the position moves on at the last velocity and the velocity is kept.
``kalman_openmocap`` -- :class:`OpenMoCapKalmanTracker`
    OpenCV's constant-velocity ``CvKalman`` with state (x, y, vx, vy), ``Q`` on the
    velocities only, ``Q_v = 0.06 + 0.013 |v|`` per axis (px/frame)**2 from the last
    velocity, ``R = diag(0.2845, 0.0455)`` px**2, ``P0 = diag(0, 0, 100, 100)``; search
    radius ``100 * mean(sigma_vx, sigma_vy)`` px from the prior covariance (so it grows
    with the speed through ``Q``); prediction truncated to whole pixels. Without a
    detection the filter is corrected with its own prediction.
``condensation`` -- :class:`CondensationTracker`
    OpenCV's ``CvConDensation`` with a position-only state and identity dynamics: each
    frame the particles are weighted by the label's last measured position (Gaussian of
    the particles' own variance per axis), their weighted mean is the prediction,
    they are resampled (systematic, offset 0) and diffused by uniform noise of half
    width ``image size / 1.5 / 5`` per axis (85.3 x 64 px at 640x480). Search radius:
    mean of the particles' standard deviations on the two axes. The first cloud is
    spread uniformly over the image.
"""

from __future__ import annotations

import numpy as np

from mocap.trackers.base import AlphaBetaFilter, Tracker2D, check_nonnegative, check_positive
from mocap.trackers.condensation import _particle_count, _systematic_flat
from mocap.trackers.registry import register_tracker

#: ``max_coast_frames`` of the OpenMoCap trackers: a label is never declared lost.
NEVER_LOST: int = 2**40

#: Default ``max_gate_px`` of the OpenMoCap trackers that set their own search radius: unbounded.
UNBOUNDED_GATE_PX: float = 1e6


class _OwnGateTracker(Tracker2D):
    """What OpenMoCap's Kalman filter and CONDENSATION share: ``_predict`` sets the search
    radius itself (:meth:`~mocap.trackers.base.Tracker2D._set_radius`), a label is never
    given up (``max_coast_frames`` :data:`NEVER_LOST`) and the radius is not bounded
    unless ``max_gate_px`` is given (default :data:`UNBOUNDED_GATE_PX`).

    Not a tracker of its own: a subclass passes its ``**base_params`` on to this
    constructor."""

    _sets_own_gate = True

    def __init__(
        self,
        initial_xy: np.ndarray,
        dt: float,
        rng: np.random.Generator,
        *,
        max_coast_frames: int = NEVER_LOST,
        **base_params,
    ) -> None:
        base_params.setdefault("max_gate_px", UNBOUNDED_GATE_PX)
        super().__init__(initial_xy, dt, rng, max_coast_frames=max_coast_frames, **base_params)


def _image_size(image_size_px: tuple[float, float]) -> tuple[float, float]:
    w, h = (float(v) for v in image_size_px)
    if not (w > 0 and h > 0):
        raise ValueError(f"image_size_px must be two positive sizes (width, height) in px, got {image_size_px!r}")
    return w, h


@register_tracker("alpha_beta")
class AlphaBetaTracker(AlphaBetaFilter):
    """Seed 000's alpha-beta filter with OpenMoCap's fixed search circle.

    Parameters
    ----------
    initial_xy : (M, 2) float
        First-frame pixel positions (NaN: label starts lost).
    dt : float
        Frame interval in seconds (the filter itself counts in frames).
    rng : numpy.random.Generator
        Unused (deterministic filter), kept for the common constructor.
    alpha : float, default 1.0
        Position gain, equation (2) (seed 000: 1.0).
    beta : float, default 0.8
        Velocity gain, equation (3) with dt = one frame (seed 000: 0.8).
    search_radius_px : float, default 40.0
        Fixed radius of the search circle, px: OpenMoCap's 5 % of the image diagonal
        (800 px at 640x480).
    max_coast_frames : int, default NEVER_LOST
        OpenMoCap never gives a label up (see the module docstring).
    **base_params
        ``gate_probability``, ``min_gate_px``, ``max_gate_px``
        (see :class:`~mocap.trackers.base.Tracker2D`).
    """

    def __init__(
        self,
        initial_xy: np.ndarray,
        dt: float,
        rng: np.random.Generator,
        *,
        alpha: float = 1.0,
        beta: float = 0.8,
        search_radius_px: float = 40.0,
        max_coast_frames: int = NEVER_LOST,
        **base_params,
    ) -> None:
        base_params.setdefault("max_gate_px", max(120.0, float(search_radius_px)))
        super().__init__(initial_xy, dt, rng, max_coast_frames=max_coast_frames, **base_params)
        self._start_filter(initial_xy, alpha, beta)  # the velocity d is in px/frame
        check_positive(search_radius_px=search_radius_px)
        self.search_radius_px = float(search_radius_px)
        self._radius = np.full(self.n_markers, self.search_radius_px)
        self._set_radius(self._radius)

    def _predict(self) -> None:
        self._x = self._centre = self._x + self._d  # x_p = x_s + v_s (one frame); v_p = v_s
        self._set_radius(self._radius)

    def _correct(self, z: np.ndarray, has: np.ndarray | None) -> None:
        r = z - self._x  # (1) residual, px
        if has is not None:
            r[~has] = 0.0  # inertia: x_s = x_p, v_s = v_p
        self._x = self._x + self.alpha * r  # (2)
        self._d = self._d + self.beta * r  # (3), dt = one frame

    def _restart(self, mask: np.ndarray, xy: np.ndarray) -> None:
        self._x = self._x.copy()
        self._x[mask] = xy[mask]
        self._d[mask] = 0.0


@register_tracker("kalman_openmocap")
class OpenMoCapKalmanTracker(_OwnGateTracker):
    """OpenMoCap's Kalman filter: constant velocity per frame, ``Q`` and the search
    radius growing with the speed.

    Parameters
    ----------
    initial_xy : (M, 2) float
        First-frame pixel positions (NaN: label starts lost).
    dt : float
        Frame interval in seconds (the filter itself counts in frames).
    rng : numpy.random.Generator
        Unused (deterministic filter), kept for the common constructor.
    velocity_noise : float, default 0.06
        Velocity process noise of a still marker, (px/frame)**2 per frame.
    velocity_noise_per_speed : float, default 0.013
        Extra velocity process noise per px/frame of the marker's speed on that axis.
    initial_velocity_noise : float, default 0.2
        Velocity process noise of the first prediction.
    measurement_var_px2 : (float, float), default (0.2845, 0.0455)
        Measurement noise variance on x and y, px**2 (OpenMoCap's ``R`` also has a
        0.0045 px**2 covariance, left out: a correlation of 0.04).
    initial_velocity_var : float, default 100.0
        Prior velocity variance of a new label, (px/frame)**2 (its position is certain).
    radius_per_velocity_std : float, default 100.0
        Search radius per px/frame of the prior velocity standard deviation (mean of the
        two axes), px.
    integer_pixels : bool, default True
        Truncate the prediction to whole pixels, as OpenMoCap does.
    **base_params
        ``max_coast_frames`` (default NEVER_LOST), ``gate_probability``, ``min_gate_px``,
        ``max_gate_px`` (default unbounded; see :class:`_OwnGateTracker`).
    """

    def __init__(
        self,
        initial_xy: np.ndarray,
        dt: float,
        rng: np.random.Generator,
        *,
        velocity_noise: float = 0.06,
        velocity_noise_per_speed: float = 0.013,
        initial_velocity_noise: float = 0.2,
        measurement_var_px2: tuple[float, float] = (0.2845, 0.0455),
        initial_velocity_var: float = 100.0,
        radius_per_velocity_std: float = 100.0,
        integer_pixels: bool = True,
        **base_params,
    ) -> None:
        super().__init__(initial_xy, dt, rng, **base_params)
        r = np.asarray(measurement_var_px2, dtype=np.float64)
        if r.shape != (2,) or not (r > 0).all():
            raise ValueError(f"measurement_var_px2 must be two positive variances (x, y) in px**2, got {measurement_var_px2!r}")
        check_nonnegative(velocity_noise=velocity_noise, velocity_noise_per_speed=velocity_noise_per_speed,
                          initial_velocity_noise=initial_velocity_noise)
        check_positive(initial_velocity_var=initial_velocity_var, radius_per_velocity_std=radius_per_velocity_std)
        self.velocity_noise = float(velocity_noise)
        self.velocity_noise_per_speed = float(velocity_noise_per_speed)
        self.initial_velocity_noise = float(initial_velocity_noise)
        self.r = r  # (2,) px**2 per image axis
        self.p0 = float(initial_velocity_var)
        self.radius_per_velocity_std = float(radius_per_velocity_std)
        self.integer_pixels = bool(integer_pixels)
        M = self.n_markers
        self._pos = np.array(initial_xy, dtype=np.float64)  # (M, 2) px
        self._vel = np.zeros((M, 2))  # (M, 2) px/frame
        # Per marker and axis the 2x2 covariance block [[p00, p01], [p01, p11]] of
        # (position, velocity): (M, 2 axes) arrays each.
        self._p00 = np.zeros((M, 2))
        self._p01 = np.zeros((M, 2))
        self._p11 = np.full((M, 2), self.p0)
        self._q = np.full((M, 2), float(initial_velocity_noise))  # Q_v of the next predict
        self._coords = self._pos.copy()  # (M, 2) reported position: the detection, else the prediction
        self._radius = np.full(M, self.max_gate_px)
        self._set_radius(self._radius)

    def _predict(self) -> None:
        # x = F x, P = F P F' + Q with F = [[1, 1], [0, 1]] per axis, Q = diag(0, q).
        self._pos = self._pos + self._vel
        p00, p01, p11 = self._p00, self._p01, self._p11
        self._p00 = p00 + 2.0 * p01 + p11
        self._p01 = p01 + p11
        self._p11 = p11 + self._q
        # OpenMoCap sets the next frame's Q after this prediction, from the velocity of
        # the last correction (which the prediction does not change).
        self._q = self.velocity_noise + self.velocity_noise_per_speed * np.abs(self._vel)
        radius = self.radius_per_velocity_std * np.sqrt(self._p11).mean(axis=1)
        centre = self._pos.copy()
        if self.integer_pixels:
            np.trunc(radius, out=radius)
            np.trunc(centre, out=centre)
        self._centre = centre
        self._radius = radius
        self._set_radius(radius)

    def _correct(self, z: np.ndarray, has: np.ndarray | None) -> None:
        if has is not None:
            # Without a detection OpenMoCap corrects with its own (whole-pixel) prediction.
            z = np.where(has[:, None], z, self._centre)
        self._coords = z
        s = self._p00 + self.r  # innovation variance per axis
        k0 = self._p00 / s
        k1 = self._p01 / s
        y = z - self._pos
        if self._any_lost:  # labels without a position (NaN) are left alone
            known = np.isfinite(y[:, 0])
            y[~known] = 0.0
            k0[~known] = 0.0
            k1[~known] = 0.0
        self._pos = self._pos + k0 * y
        self._vel = self._vel + k1 * y
        # P = (I - K H) P
        self._p11 = self._p11 - k1 * self._p01
        self._p01 = (1.0 - k0) * self._p01
        self._p00 = (1.0 - k0) * self._p00

    def _restart(self, mask: np.ndarray, xy: np.ndarray) -> None:
        self._pos = self._pos.copy()
        self._pos[mask] = xy[mask]
        self._coords = self._coords.copy()
        self._coords[mask] = xy[mask]
        self._vel[mask] = 0.0
        self._p00[mask] = 0.0
        self._p01[mask] = 0.0
        self._p11[mask] = self.p0
        self._q[mask] = self.initial_velocity_noise  # a new OpenCV filter

    def _drop_velocity(self, mask: np.ndarray) -> None:
        self._vel[mask] = 0.0
        self._p01[mask] = 0.0
        self._p11[mask] = self.p0

    @property
    def v(self) -> np.ndarray:
        """(M, 2) float: velocity estimate, px/s."""
        return self._vel / self.dt

    @property
    def x_state(self) -> np.ndarray:
        """(M, 2) float: the filter's posterior position, px."""
        return self._pos

    @property
    def x_est(self) -> np.ndarray:
        """(M, 2) float: the label's position as OpenMoCap reports it: the associated
        detection, else the (whole-pixel) prediction, px."""
        return self._coords


@register_tracker("condensation")
class CondensationTracker(_OwnGateTracker):
    """OpenMoCap's CONDENSATION: 100 position particles per label, identity dynamics,
    uniform diffusion, weights from the label's last measured position.

    Parameters
    ----------
    initial_xy : (M, 2) float
        First-frame pixel positions (NaN: label starts lost).
    dt : float
        Frame interval in seconds (unused: the dynamics are the identity).
    rng : numpy.random.Generator
        Source of the first cloud and of the diffusion.
    n_particles : int, default 100
        Particles per label (seed 000: 100).
    image_size_px : (float, float), default (640, 480)
        Image width and height, px: the first cloud covers the image and the diffusion
        is a fraction of its size.
    diffusion_fraction : float, default 1 / 7.5
        Half width of the uniform diffusion per axis as a fraction of the image size
        (OpenMoCap sets the sample bounds to ``[0, size / 1.5]``; OpenCV's
        ``cvConDensInitSampleSet`` then diffuses by a fifth of their width:
        ``size / 1.5 / 5``).
    **base_params
        ``max_coast_frames`` (default NEVER_LOST), ``gate_probability``, ``min_gate_px``,
        ``max_gate_px`` (default unbounded; see :class:`_OwnGateTracker`).
    """

    def __init__(
        self,
        initial_xy: np.ndarray,
        dt: float,
        rng: np.random.Generator,
        *,
        n_particles: int = 100,
        image_size_px: tuple[float, float] = (640.0, 480.0),
        diffusion_fraction: float = 1.0 / 7.5,
        **base_params,
    ) -> None:
        super().__init__(initial_xy, dt, rng, **base_params)
        N = _particle_count(n_particles)
        check_positive(diffusion_fraction=diffusion_fraction)
        self.n_particles = N
        self.image_size_px = _image_size(image_size_px)
        self.diffusion_fraction = float(diffusion_fraction)
        self._half_width = np.array(self.image_size_px) * self.diffusion_fraction  # (2,) px
        M = self.n_markers
        # Particles (2, M, N): axis, label, particle. The first cloud covers the image
        # in whole pixels (OpenMoCap: rand() % width, rand() % height).
        size = np.array(self.image_size_px)
        self.p = np.floor(rng.random((2, M, N)) * size[:, None, None])
        self._meas = np.array(initial_xy, dtype=np.float64)  # (M, 2) last measured position, px
        self._radius = np.zeros(M)
        self._set_radius(np.full(M, self.max_gate_px))

    @property
    def particles(self) -> np.ndarray:
        """(M, N, 2) float: particle positions in pixels."""
        return np.moveaxis(self.p, 0, -1).copy()

    def _predict(self) -> None:
        p = self.p
        _, M, N = p.shape
        var = p.var(axis=2)  # (2, M) per-axis particle variance, px**2
        np.maximum(var, 1e-12, out=var)
        self._radius = 0.5 * np.sqrt(var).sum(axis=0)  # mean of the two standard deviations
        # Observation of the last measured position: exp(-d**2 / (2 var)) per axis.
        d = p - self._meas.T[:, :, None]
        d *= d
        d /= var[:, :, None]
        d2 = d[0] + d[1]  # (M, N)
        d2 -= d2.min(axis=1, keepdims=True)  # the best particle gets exp(0): no underflow
        w = np.exp(-0.5 * d2)
        unknown = ~np.isfinite(self._meas[:, 0])  # labels that never had a position
        if unknown.any():
            w[unknown] = 1.0
        w /= w.sum(axis=1, keepdims=True)
        # The weighted mean is the prediction (state) of this frame; no gate (NaN) for a
        # label without a position, as the base class wants.
        centre = np.einsum("amn,mn->ma", p, w)
        centre[unknown] = np.nan
        self._centre = centre
        # Selection (systematic, offset 0, as OpenCV's cvConDensUpdateByTime) ...
        flat = _systematic_flat(w, np.zeros(M))
        p = p.reshape(2, M * N).take(flat, axis=1).reshape(2, M, N)
        # ... identity drift, uniform diffusion.
        p += (self.rng.random((2, M, N)) * 2.0 - 1.0) * self._half_width[:, None, None]
        self.p = p
        self._set_radius(self._radius)

    def _correct(self, z: np.ndarray, has: np.ndarray | None) -> None:
        if has is None:
            self._meas = z.copy()
        else:
            self._meas = np.where(has[:, None], z, self._meas)

    def _restart(self, mask: np.ndarray, xy: np.ndarray) -> None:
        self._meas = self._meas.copy()
        self._meas[mask] = xy[mask]

    @property
    def x_est(self) -> np.ndarray:
        """(M, 2) float: the label's last measured position, px (OpenMoCap keeps it while
        the marker is not found)."""
        return self._meas
