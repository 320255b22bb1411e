"""Constant-velocity Kalman tracker (seed 000, section III-B), batched over markers.

Conventions are filterpy's (``filterpy.kalman.KalmanFilter``): state ``x`` per marker is
``[x, vx, y, vy]`` (px, px/s), covariance ``P``, transition ``F``, process noise ``Q``,
measurement matrix ``H`` (picks ``x, y``), measurement noise ``R``. Each marker's ``x``
and ``P`` equal those of a filterpy ``KalmanFilter`` fed the same inputs (filterpy's
Joseph-form update and the short form used here agree for the optimal gain).

``Q`` is filterpy's ``Q_discrete_white_noise(dim=2, dt, var)`` per axis (piecewise white
acceleration) with an acceleration standard deviation that grows with the marker's
speed, ``sigma_a = accel_std + speed_accel_gain * |v| / dt``: as seed 000 says, a faster
marker gets a larger ``Q``, hence a larger ``P`` and search area. The search area is the
innovation covariance ``S = H P H' + R`` (prior), gated at the chi-square quantile.

Why hand-written equations rather than ``filterpy.kalman.predict/update``: with ``F``,
``Q``, ``H`` and ``R`` block-diagonal per image axis, identical for both axes, and both
coordinates measured together, ``P`` is two equal 2x2 blocks. Keeping the three distinct
entries of that block as an ``(M, 3)`` array turns the filter into about fifteen numpy
calls for all markers at once (two of them small matrix products for ``F x`` and
``F P F'``) -- far cheaper than ``(M, 4, 4)`` matrix products, and than filterpy's
per-marker loop, the benchmark's reference.
"""

from __future__ import annotations

import numpy as np

from mocap.trackers.base import Tracker2D, check_nonnegative, check_positive
from mocap.trackers.registry import register_tracker


@register_tracker("kalman")
class KalmanTracker(Tracker2D):
    """Constant-velocity Kalman filter for M markers.

    Parameters
    ----------
    initial_xy : (M, 2) float
        First-frame pixel positions (NaN: label starts lost).
    dt : float
        Frame interval in seconds.
    rng : numpy.random.Generator
        Unused (deterministic filter), kept for the common constructor.
    measurement_std_px : float, default 0.5
        Standard deviation of a detection's centroid, px (``R = std**2 I``).
    accel_std : float, default 300.0
        Acceleration standard deviation of a still marker, px/s**2.
    speed_accel_gain : float, default 1.0
        Extra acceleration standard deviation per px/s of speed, per frame interval:
        ``sigma_a = accel_std + speed_accel_gain * |v| / dt``. At 1.0 the velocity may
        change by about its own magnitude within one frame at one standard deviation
        (a sharp turn stays inside the search area).
    initial_position_std_px : float, default 1.0
        Prior position standard deviation of a new label, px.
    initial_velocity_std : float, default 300.0
        Prior velocity standard deviation of a new label, px/s.
    **base_params
        ``max_coast_frames``, ``gate_probability``, ``min_gate_px``, ``max_gate_px``
        (see :class:`~mocap.trackers.base.Tracker2D`).
    """

    def __init__(
        self,
        initial_xy: np.ndarray,
        dt: float,
        rng: np.random.Generator,
        *,
        measurement_std_px: float = 0.5,
        accel_std: float = 300.0,
        speed_accel_gain: float = 1.0,
        initial_position_std_px: float = 1.0,
        initial_velocity_std: float = 300.0,
        **base_params,
    ) -> None:
        super().__init__(initial_xy, dt, rng, **base_params)
        check_positive(measurement_std_px=measurement_std_px, initial_position_std_px=initial_position_std_px,
                       initial_velocity_std=initial_velocity_std)
        check_nonnegative(accel_std=accel_std, speed_accel_gain=speed_accel_gain)
        self.r = float(measurement_std_px) ** 2  # px**2, R = r I
        self.accel_std = float(accel_std)
        self.speed_accel_gain = float(speed_accel_gain)
        self.p0 = (float(initial_position_std_px) ** 2, float(initial_velocity_std) ** 2)
        dt = self.dt
        M = self.n_markers
        # State (M, 4) stored as [x, y, vx, vy] (px, px/s) so that positions and
        # velocities are contiguous column pairs; the filterpy order is given by ``x``.
        self._s = np.zeros((M, 4))
        self._s[:, :2] = np.asarray(initial_xy, dtype=np.float64)
        # Covariance: both axes share one 2x2 block [[p00, p01], [p01, p11]] (same Q, R,
        # prior and measurements), stored as (M, 3) columns p00, p01, p11.
        self._p = np.empty((M, 3))
        self._p[:] = (self.p0[0], 0.0, self.p0[1])
        # x <- x F' for the stored order, and P <- P T, the block's F P F' as a linear
        # map on (p00, p01, p11): p00 + 2 dt p01 + dt^2 p11, p01 + dt p11, p11.
        self._FT = np.eye(4)
        self._FT[2, 0] = self._FT[3, 1] = dt
        self._T = np.array([[1.0, 0.0, 0.0], [2.0 * dt, 1.0, 0.0], [dt * dt, dt, 1.0]])
        # Q_discrete_white_noise(dim=2, dt, var=1) entries: [[dt^4/4, dt^3/2], [dt^3/2, dt^2]]
        self._qform = np.array([dt**4 / 4.0, dt**3 / 2.0, dt**2])
        self.q_var = np.zeros(M)  # (M,) acceleration variance used by the last predict
        self._svar = self._p[:, 0:1] + self.r
        self._set_info()

    # ------------------------------------------------------------ filterpy views
    @property
    def F(self) -> np.ndarray:
        """(4, 4) state transition for ``[x, vx, y, vy]``."""
        f = np.eye(4)
        f[0, 1] = f[2, 3] = self.dt
        return f

    @property
    def H(self) -> np.ndarray:
        """(2, 4) measurement matrix."""
        h = np.zeros((2, 4))
        h[0, 0] = h[1, 2] = 1.0
        return h

    @property
    def R(self) -> np.ndarray:
        """(2, 2) measurement noise covariance, px**2."""
        return self.r * np.eye(2)

    @property
    def x(self) -> np.ndarray:
        """(M, 4) state ``[x, vx, y, vy]`` per marker (px, px/s), filterpy's order."""
        return self._s[:, [0, 2, 1, 3]]

    @property
    def P(self) -> np.ndarray:
        """(M, 4, 4) state covariance per marker, filterpy's order."""
        P = np.zeros((self.n_markers, 4, 4))
        for i in (0, 2):
            P[:, i, i] = self._p[:, 0]
            P[:, i, i + 1] = P[:, i + 1, i] = self._p[:, 1]
            P[:, i + 1, i + 1] = self._p[:, 2]
        return P

    @property
    def Q(self) -> np.ndarray:
        """(M, 4, 4) process noise used by the last predict, filterpy's order."""
        q00, q01, q11 = self._qform
        block = np.array([[q00, q01], [q01, q11]])
        Q = np.zeros((self.n_markers, 4, 4))
        Q[:, 0:2, 0:2] = self.q_var[:, None, None] * block
        Q[:, 2:4, 2:4] = self.q_var[:, None, None] * block
        return Q

    # ------------------------------------------------------------ filter
    def _predict(self) -> None:
        s = self._s
        sa = np.hypot(s[:, 2], s[:, 3])  # speed, px/s
        sa *= self.speed_accel_gain / self.dt
        sa += self.accel_std
        qv = sa * sa  # acceleration variance, (px/s^2)^2
        self.q_var = qv
        self._s = s = s @ self._FT  # x = F x
        p = self._p @ self._T  # P = F P F' ...
        p += qv[:, None] * self._qform  # ... + Q
        self._p = p
        self._centre = s[:, :2].copy()
        self._svar = p[:, 0:1] + self.r  # S = H P H' + R (the same on both axes)

    def _correct(self, z: np.ndarray, has: np.ndarray | None) -> None:
        p = self._p
        y = z - self._s[:, :2]  # innovation, px
        k = p[:, 0:2] / (p[:, 0:1] + self.r)  # (M, 2) gains [k0, k1] = P H' S^-1 per axis
        if has is not None:
            k[~has] = 0.0  # no measurement: the prior stays
            y[~has] = 0.0
        s3 = self._s.reshape(-1, 2, 2)  # (M, [position, velocity], axis)
        s3 += k[:, :, None] * y[:, None, :]  # x = x + K y
        # P = (I - K H) P: p11 -= k1 p01, then (p00, p01) *= 1 - k0. For the optimal gain
        # this equals filterpy's Joseph form (I-KH)P(I-KH)' + KRK' to rounding.
        p[:, 2] -= k[:, 1] * p[:, 1]
        p[:, 0:2] *= 1.0 - k[:, 0:1]

    def _restart(self, mask: np.ndarray, xy: np.ndarray) -> None:
        self._s[mask, :2] = xy[mask]
        self._s[mask, 2:] = 0.0
        self._p[mask] = (self.p0[0], 0.0, self.p0[1])

    def _drop_velocity(self, mask: np.ndarray) -> None:
        self._s[mask, 2:] = 0.0
        self._p[mask, 1] = 0.0
        self._p[mask, 2] = self.p0[1]

    @property
    def x_est(self) -> np.ndarray:
        """(M, 2) float: posterior position in pixels."""
        return self._s[:, :2]
