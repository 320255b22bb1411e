"""Smoothing (Butterworth, Kalman/RTS) and spline gap filling of trajectories."""

from __future__ import annotations

import numpy as np
import pytest
from filterpy.common import Q_discrete_white_noise
from filterpy.kalman import KalmanFilter, rts_smoother

from mocap.smoothing import butterworth_filtfilt, fill_gaps, finite_runs, rts_smooth

RATE = 200.0


def noisy_sines(rng: np.random.Generator, F: int = 400, M: int = 5, noise: float = 0.002):
    t = np.arange(F) / RATE
    freq = rng.uniform(0.5, 2.0, (M, 3))
    phase = rng.uniform(0, 2 * np.pi, (M, 3))
    clean = 0.1 * np.sin(2 * np.pi * freq[None] * t[:, None, None] + phase[None])
    return t, clean, clean + rng.normal(0, noise, clean.shape)


def rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.nanmean(x**2)))


def test_finite_runs() -> None:
    s, e = finite_runs(np.array([0, 1, 1, 0, 1, 0, 0, 1, 1, 1], bool))
    assert s.tolist() == [1, 4, 7] and e.tolist() == [3, 5, 10]
    s, e = finite_runs(np.zeros(4, bool))
    assert s.size == 0 and e.size == 0


def test_butterworth_reduces_noise_and_keeps_gaps() -> None:
    rng = np.random.default_rng(0)
    t, clean, noisy = noisy_sines(rng)
    noisy[100:130, 2, :] = np.nan      # an interior gap
    noisy[:5, 4, :] = np.nan           # a leading gap
    out = butterworth_filtfilt(noisy, RATE, cutoff_hz=6.0)
    assert np.array_equal(np.isnan(out), np.isnan(noisy))
    before, after = rms(noisy - clean), rms(out - clean)
    assert after < 0.5 * before, (before, after)
    # Away from run ends (where filtfilt's padding is a guess) the noise left is about
    # sqrt(bandwidth fraction) = sqrt(6 / 100) ~ 0.25 of the input.
    inner = rms((out - clean)[30:-30, [0, 1, 3]])
    assert inner < 0.3 * before, (before, inner)
    # Zero lag: a pure low-frequency sine passes unchanged (up to edge effects).
    s = np.sin(2 * np.pi * 0.5 * t)[:, None]
    np.testing.assert_allclose(butterworth_filtfilt(s, RATE, 6.0)[40:-40], s[40:-40], atol=2e-3)


def test_butterworth_rejects_bad_cutoff() -> None:
    with pytest.raises(ValueError, match="cutoff_hz"):
        butterworth_filtfilt(np.zeros((50, 1)), RATE, cutoff_hz=150.0)


def test_rts_matches_filterpy_and_reduces_noise() -> None:
    rng = np.random.default_rng(1)
    t, clean, noisy = noisy_sines(rng, F=200, M=2)
    noisy[50:60, 1, 0] = np.nan
    dt, acc, meas = 1.0 / RATE, 20.0, 0.002
    ours = rts_smooth(noisy, dt, acc, meas)
    assert np.array_equal(np.isnan(ours), np.isnan(noisy))
    # Same model with filterpy, one series at a time (predict through missing samples).
    for m, k in ((0, 0), (1, 0), (1, 2)):
        z = noisy[:, m, k]
        kf = KalmanFilter(dim_x=2, dim_z=1)
        kf.F = np.array([[1.0, dt], [0.0, 1.0]])
        kf.H = np.array([[1.0, 0.0]])
        kf.Q = Q_discrete_white_noise(2, dt, acc**2)
        kf.R = np.array([[meas**2]])
        first = z[np.isfinite(z)][0]
        kf.x = np.array([first, 0.0])
        kf.P = np.diag([1e3 * meas**2 + 1.0, 1e2])
        xs, Ps = [], []
        for i, zi in enumerate(z):
            if i > 0:
                kf.predict()
            if np.isfinite(zi):
                kf.update(np.array([zi]))
            xs.append(kf.x.copy())
            Ps.append(kf.P.copy())
        sm, _, _, _ = rts_smoother(np.array(xs), np.array(Ps), [kf.F] * len(z), [kf.Q] * len(z))
        ref = np.where(np.isfinite(z), sm[:, 0], np.nan)
        np.testing.assert_allclose(ours[:, m, k], ref, atol=1e-10, equal_nan=True)
    assert rms(ours - clean) < 0.6 * rms(noisy - clean)


def test_fill_gaps_short_filled_long_left() -> None:
    rng = np.random.default_rng(2)
    t, clean, _ = noisy_sines(rng, F=300, M=3)
    x = clean.copy()
    x[50:58, 0] = np.nan            # 8 frames: filled
    x[100:110, 1] = np.nan          # 10 frames = max: filled
    x[200:211, 1] = np.nan          # 11 frames: stays NaN
    x[:4, 2] = np.nan               # leading: stays NaN
    x[-3:, 2] = np.nan              # trailing: stays NaN
    out, filled = fill_gaps(x, t, max_gap_frames=10)
    assert filled[50:58, 0].all() and filled[100:110, 1].all()
    assert filled.sum() == 18
    assert np.isnan(out[200:211, 1]).all() and np.isnan(out[:4, 2]).all() and np.isnan(out[-3:, 2]).all()
    # Smooth motion (0.1 m at <= 2 Hz): a cubic spline's error across an 11-sample span
    # is about (5/384) h^4 max|x''''| ~ 1e-4 m at worst; it is tens of micrometres here.
    assert np.abs(out[filled] - clean[filled]).max() < 1e-4
    untouched = ~filled & np.isfinite(x).all(axis=2)
    np.testing.assert_array_equal(out[untouched], x[untouched])
    out0, filled0 = fill_gaps(x, t, max_gap_frames=0)
    assert not filled0.any() and np.array_equal(np.isnan(out0), np.isnan(x))


def test_fill_gaps_validates_shapes() -> None:
    with pytest.raises(ValueError, match="times"):
        fill_gaps(np.zeros((10, 2, 3)), np.arange(9), 3)
    with pytest.raises(ValueError, match=r"\(F, M, D\)"):
        fill_gaps(np.zeros((10, 3)), np.arange(10), 3)


def test_lsq_fill_beats_interpolation_on_noisy_points() -> None:
    """An interpolating spline through noisy samples carries the noise of its end slopes
    into the gap; a least-squares cubic averages it."""
    rng = np.random.default_rng(3)
    t, clean, noisy = noisy_sines(rng, F=300, M=3, noise=0.001)
    x = noisy.copy()
    gaps = [(s, s + 6) for s in range(20, 280, 36)]
    for s, e in gaps:
        x[s:e] = np.nan
    errs = {}
    for method in ("cubic", "lsq"):
        out, filled = fill_gaps(x, t, max_gap_frames=6, method=method)
        assert filled.sum() == 6 * len(gaps) * 3
        errs[method] = rms(out[filled] - clean[filled])
    assert errs["lsq"] < 0.6 * errs["cubic"], errs
    assert errs["lsq"] < 0.001
