"""Temporal post-processing of 3D marker trajectories: smoothing and gap filling.

Three jobs, each on arrays of shape ``(F, ...)`` (frames first, any trailing shape such
as ``(M, 3)`` markers x coordinates, metres) with NaN marking missing samples:

* :func:`butterworth_filtfilt` -- zero-lag low-pass (``scipy.signal.butter`` +
  ``filtfilt``) applied to each finite run separately, so gaps are never bridged.
* :func:`rts_smooth` -- constant-velocity Kalman filter plus Rauch-Tung-Striebel
  backward pass, vectorised over every series at once (one ``(K, 2)`` state per series).
* :func:`fill_gaps` -- cubic spline (interpolating, or least-squares for raw data)
  across interior gaps of at most ``max_gap_frames`` frames; returns which samples
  were filled.

Missing samples stay NaN after smoothing; only :func:`fill_gaps` creates values.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from scipy.interpolate import CubicSpline

# scipy.signal is imported by butterworth_filtfilt when it runs, not here: importing it brings
# scipy.stats too (about 1.7 CPU-s of a process's start-up on a busy 2-core machine), and
# every marker capture imports this module while only smoothing="butterworth" filters.

__all__ = ["finite_runs", "butterworth_filtfilt", "rts_smooth", "fill_gaps"]


def finite_runs(valid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Start and stop indices of the runs of True in a 1D boolean array.

    Parameters
    ----------
    valid : (F,) bool

    Returns
    -------
    starts, stops : (R,) int
        Run ``r`` covers ``valid[starts[r]:stops[r]]`` (stop exclusive).
    """
    v = np.asarray(valid, dtype=bool).ravel()
    edges = np.diff(np.concatenate([[0], v.view(np.int8), [0]]))
    return np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)


def _series_view(x: np.ndarray) -> tuple[np.ndarray, tuple[int, ...]]:
    """``(F, ...)`` -> ``(F, K)`` float copy plus the original shape."""
    arr = np.array(x, dtype=np.float64, copy=True)
    if arr.ndim == 0:
        raise ValueError("expected an array with frames on axis 0, got a scalar")
    return arr.reshape(arr.shape[0], -1), arr.shape


def butterworth_filtfilt(
    x: np.ndarray, rate_hz: float, cutoff_hz: float, order: int = 4
) -> np.ndarray:
    """Zero-lag Butterworth low-pass along axis 0, run by run.

    Parameters
    ----------
    x : (F, ...) float
        Samples (any unit), NaN where missing.
    rate_hz : float
        Sampling rate.
    cutoff_hz : float
        -3 dB cut-off of the *single* pass (filtfilt squares the magnitude response,
        so the combined response is -6 dB at ``cutoff_hz``). Must be below Nyquist.
    order : int
        Butterworth order of the single pass.

    Returns
    -------
    (F, ...) float
        Filtered samples; NaN where ``x`` is NaN. Runs too short for the filter's
        padding (``<= 3 * (order + 1)`` samples) are returned unfiltered.
    """
    if not (0.0 < cutoff_hz < 0.5 * rate_hz):
        raise ValueError(f"cutoff_hz={cutoff_hz} must be in (0, rate_hz/2 = {0.5 * rate_hz}); lower the cut-off or check the frame rate")
    if order < 1:
        raise ValueError(f"order={order} must be >= 1")
    from scipy.signal import butter, filtfilt

    b, a = butter(order, cutoff_hz / (0.5 * rate_hz))
    series, shape = _series_view(x)
    out = series.copy()
    padlen = 3 * max(len(a), len(b))
    finite = np.isfinite(series)
    whole = finite.all(axis=0)
    if whole.any() and series.shape[0] > padlen:
        # Fully observed series: one vectorised call.
        out[:, whole] = filtfilt(b, a, series[:, whole], axis=0)
    # Series with gaps: one call per finite run (runs differ per series, so this loop is
    # over runs, not frames).
    for k in np.flatnonzero(~whole):
        starts, stops = finite_runs(finite[:, k])
        for s, e in zip(starts, stops):
            if e - s > padlen:
                out[s:e, k] = filtfilt(b, a, series[s:e, k])
    return out.reshape(shape)


def rts_smooth(
    x: np.ndarray,
    dt: float,
    accel_std: float,
    meas_std: float,
) -> np.ndarray:
    """Constant-velocity Kalman filter + Rauch-Tung-Striebel smoother, all series at once.

    Each series (column of ``x`` reshaped to ``(F, K)``) is an independent 1D
    constant-velocity model with state ``[position, velocity]``, process noise from a
    white acceleration of std ``accel_std`` (filterpy's ``Q_discrete_white_noise``
    convention) and measurement noise ``meas_std``. Missing samples are predicted
    through (no update). Same equations as ``filterpy.kalman.KalmanFilter`` +
    ``rts_smoother``, batched: filterpy would need one filter object per series.

    Parameters
    ----------
    x : (F, ...) float
        Measurements, NaN where missing (e.g. metres).
    dt : float
        Sample period in seconds.
    accel_std : float
        Std of the white acceleration (unit/s^2), e.g. 20 m/s^2 for marker motion.
    meas_std : float
        Std of the measurement noise (same unit as ``x``).

    Returns
    -------
    (F, ...) float
        Smoothed positions; NaN where ``x`` is NaN.
    """
    if dt <= 0 or accel_std <= 0 or meas_std <= 0:
        raise ValueError(f"rts_smooth needs dt, accel_std, meas_std > 0, got {dt}, {accel_std}, {meas_std}")
    z, shape = _series_view(x)
    F_len, K = z.shape
    finite = np.isfinite(z)
    out = np.full_like(z, np.nan)
    if F_len == 0 or not finite.any():
        return out.reshape(shape)
    A = np.array([[1.0, dt], [0.0, 1.0]])
    q = accel_std**2
    Q = q * np.array([[dt**4 / 4, dt**3 / 2], [dt**3 / 2, dt**2]])
    r = meas_std**2

    # Prior: first finite sample of each series, zero velocity, wide covariance.
    first = np.argmax(finite, axis=0)
    x0 = np.where(finite.any(axis=0), z[first, np.arange(K)], 0.0)
    xs = np.zeros((F_len, K, 2))          # filtered means
    Ps = np.zeros((F_len, K, 2, 2))       # filtered covariances
    xp_all = np.zeros((F_len, K, 2))      # predicted means
    Pp_all = np.zeros((F_len, K, 2, 2))   # predicted covariances
    xk = np.stack([x0, np.zeros(K)], axis=1)
    Pk = np.broadcast_to(np.diag([1e3 * r + 1.0, 1e2]), (K, 2, 2)).copy()
    for k in range(F_len):  # recursive in time; vectorised over the K series
        if k > 0:
            xk = xk @ A.T
            Pk = A @ Pk @ A.T + Q
        xp_all[k], Pp_all[k] = xk, Pk
        m = finite[k]
        if m.any():
            S = Pk[m, 0, 0] + r                      # (n,)
            gain = Pk[m, :, 0] / S[:, None]          # (n, 2)
            innov = z[k, m] - xk[m, 0]
            xk = xk.copy()
            xk[m] = xk[m] + gain * innov[:, None]
            # Joseph form (as filterpy) for symmetry: P = (I-KH)P(I-KH)' + KRK'
            IKH = np.eye(2)[None] - gain[:, :, None] * np.array([1.0, 0.0])[None, None, :]
            Pm = IKH @ Pk[m] @ IKH.transpose(0, 2, 1) + r * gain[:, :, None] * gain[:, None, :]
            Pk = Pk.copy()
            Pk[m] = Pm
        xs[k], Ps[k] = xk, Pk
    # Backward RTS pass.
    xsm, Psm = xs.copy(), Ps.copy()
    for k in range(F_len - 2, -1, -1):
        Pp = Pp_all[k + 1]
        G = Ps[k] @ A.T @ np.linalg.inv(Pp)                 # (K, 2, 2)
        xsm[k] = xs[k] + np.einsum("kij,kj->ki", G, xsm[k + 1] - xp_all[k + 1])
        Psm[k] = Ps[k] + G @ (Psm[k + 1] - Pp) @ G.transpose(0, 2, 1)
    out = np.where(finite, xsm[:, :, 0], np.nan)
    return out.reshape(shape)


def fill_gaps(
    xyz: np.ndarray,
    times: np.ndarray,
    max_gap_frames: int,
    method: Literal["cubic", "lsq"] = "cubic",
    context_frames: int = 10,
) -> tuple[np.ndarray, np.ndarray]:
    """Fill interior gaps of at most ``max_gap_frames`` frames with a cubic.

    Each gap is filled from the valid samples just before and after it:

    * ``"cubic"``: interpolating cubic spline (``scipy.interpolate.CubicSpline``) through
      the valid samples within ``context_frames`` frames of the gap. Exact on smooth data
      (e.g. after smoothing), but it passes through the noise of raw data, and the noise
      of its end slopes grows across the gap.
    * ``"lsq"``: least-squares cubic (a cubic spline without interior knots) over as
      many frames on each side as the gap is long (at least 4, at most
      ``context_frames``): it averages the noise of raw triangulations instead of
      following it, and its short support keeps the model bias small.

    Parameters
    ----------
    xyz : (F, M, D) float
        Trajectories (e.g. metres), NaN where missing. A sample is missing if any of its
        D coordinates is NaN.
    times : (F,) float
        Timestamps in seconds (strictly increasing).
    max_gap_frames : int
        Longest gap (consecutive missing frames) to fill; 0 fills nothing. Gaps at the
        start or end of a trajectory are never filled (that would be extrapolation).
    method : {"cubic", "lsq"}
    context_frames : int
        Largest number of frames on each side of a gap used for the fit.

    Returns
    -------
    filled_xyz : (F, M, D) float
        Copy of ``xyz`` with short gaps filled; longer gaps stay NaN.
    filled : (F, M) bool
        True where a value was created here.
    """
    p = np.array(xyz, dtype=np.float64, copy=True)
    if p.ndim != 3:
        raise ValueError(f"xyz must be (F, M, D), got shape {p.shape}")
    t = np.asarray(times, dtype=np.float64).ravel()
    _check_fill_args(p, t, max_gap_frames, method, context_frames)
    F, M, _ = p.shape
    valid = np.isfinite(p).all(axis=2)
    filled = np.zeros((F, M), dtype=bool)
    if max_gap_frames == 0 or F < 3:
        return p, filled
    missing = ~valid
    dt = float(np.median(np.diff(t)))
    if not dt > 0:
        raise ValueError("times must be strictly increasing")
    # Loop over markers with gaps and over their gaps (few), never over frames: each gap
    # has its own abscissae, so the spline solves cannot be shared.
    for m in np.flatnonzero(missing.any(axis=0) & (valid.sum(axis=0) >= 2)):
        starts, stops = finite_runs(missing[:, m])
        ok = (starts > 0) & (stops < F) & (stops - starts <= max_gap_frames)
        for s, e in zip(starts[ok], stops[ok]):
            p[s:e, m] = _gap_fit(p[:, m], valid[:, m], t, dt, s, e, method, context_frames)
            filled[s:e, m] = True
    return p, filled


def _check_fill_args(p: np.ndarray, t: np.ndarray, max_gap_frames: int, method: str, context_frames: int) -> None:
    """Raise ValueError on arguments :func:`fill_gaps` cannot use."""
    if t.shape[0] != p.shape[0]:
        raise ValueError(f"times has {t.shape[0]} entries but xyz has {p.shape[0]} frames")
    if max_gap_frames < 0:
        raise ValueError(f"max_gap_frames={max_gap_frames} must be >= 0")
    if method not in ("cubic", "lsq"):
        raise ValueError(f"method={method!r}: use 'cubic' or 'lsq'")
    if context_frames < 1:
        raise ValueError(f"context_frames={context_frames} must be >= 1")


def _gap_fit(x: np.ndarray, valid: np.ndarray, t: np.ndarray, dt: float, s: int, e: int, method: str,
             context_frames: int) -> np.ndarray:
    """``(e - s, D)`` values of one marker's track ``x (F, D)`` over its gap ``s:e`` (see
    :func:`fill_gaps`), fitted to its ``valid`` samples around the gap."""
    F = len(x)
    side = context_frames if method == "cubic" else int(np.clip(e - s, 4, max(4, context_frames)))
    lo, hi = max(0, s - side), min(F, e + side)
    ctx = lo + np.flatnonzero(valid[lo:hi])
    gap = np.arange(s, e)
    # Abscissa in frame periods from the gap start keeps the fit well scaled.
    u = (t - t[s]) / dt
    if method == "lsq" and ctx.size >= 6:
        coef = np.polynomial.polynomial.polyfit(u[ctx], x[ctx], 3)   # (4, D)
        return np.polynomial.polynomial.polyval(u[gap], coef).T
    return CubicSpline(u[ctx], x[ctx], axis=0)(u[gap])
