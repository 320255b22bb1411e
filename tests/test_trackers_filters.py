"""Numeric identities of the batched filters against their references.

* the batched Kalman tracker gives each marker the same x and P as filterpy's
  KalmanFilter fed the same F, Q, H, R and measurements;
* the alpha-beta tracker follows seed 000's equations (1)-(3), computed here by hand;
* batched systematic resampling equals filterpy's on the same uniform draw;
* constant-velocity targets are predicted with an error that goes to zero.
"""

from __future__ import annotations

import numpy as np
import pytest
from filterpy.kalman import KalmanFilter
from filterpy.monte_carlo import resampling as fp_resampling

from mocap.trackers import (
    COASTING,
    TRACKED,
    AlphaBetaTracker,
    CondensationTracker,
    KalmanTracker,
    make_tracker,
    systematic_resample,
)

DT = 1.0 / 30.0


def _filterpy_twins(trk: KalmanTracker, initial_xy: np.ndarray) -> list[KalmanFilter]:
    filters = []
    for m in range(trk.n_markers):
        kf = KalmanFilter(dim_x=4, dim_z=2)
        kf.x = np.array([[initial_xy[m, 0]], [0.0], [initial_xy[m, 1]], [0.0]])
        kf.P = trk.P[m].copy()
        kf.F = trk.F
        kf.H = trk.H
        kf.R = trk.R
        filters.append(kf)
    return filters


def test_kalman_matches_filterpy_per_marker():
    rng = np.random.default_rng(1)
    M = 6
    x0 = rng.uniform(50, 600, (M, 2))
    vel = rng.uniform(-200, 200, (M, 2))  # px/s, so Q (speed-dependent) differs per marker
    trk = KalmanTracker(x0, DT, np.random.default_rng(0), max_coast_frames=1000, measurement_std_px=0.7)
    filters = _filterpy_twins(trk, x0)
    worst_x = worst_p = 0.0
    for f in range(1, 60):
        trk.predict()
        Q = trk.Q  # (M, 4, 4) the process noise this predict used (grows with speed)
        for m, kf in enumerate(filters):
            kf.predict(Q=Q[m])
        z = x0 + vel * f * DT + rng.normal(0, 0.5, (M, 2))
        z[rng.random(M) < 0.2] = np.nan  # some labels without a detection
        trk.update(z)
        for m, kf in enumerate(filters):
            kf.update(None if np.isnan(z[m, 0]) else z[m])
        x_ref = np.stack([kf.x[:, 0] for kf in filters])
        P_ref = np.stack([kf.P for kf in filters])
        np.testing.assert_allclose(trk.x, x_ref, rtol=1e-10, atol=1e-10)
        np.testing.assert_allclose(trk.P, P_ref, rtol=1e-10, atol=1e-10 * np.abs(P_ref).max())
        worst_x = max(worst_x, np.abs(trk.x - x_ref).max())
        worst_p = max(worst_p, (np.abs(trk.P - P_ref) / np.maximum(np.abs(P_ref), 1.0)).max())
    assert worst_x < 1e-10 and worst_p < 1e-10
    # The search area is the innovation covariance S = H P H' + R of the prior.
    trk.predict()
    for m, kf in enumerate(filters):
        kf.predict(Q=trk.Q[m])
    S_ref = np.stack([kf.H @ kf.P @ kf.H.T + kf.R for kf in filters])
    np.testing.assert_allclose(trk.gate().covariance, S_ref, rtol=1e-10)


def test_kalman_q_grows_with_speed():
    x0 = np.array([[100.0, 100.0], [300.0, 300.0]])
    trk = KalmanTracker(x0, DT, np.random.default_rng(0))
    for f in range(1, 20):  # marker 0 still, marker 1 moving at 300 px/s
        trk.step(x0 + np.array([[0.0, 0.0], [300.0 * f * DT, 0.0]]))
    trk.predict()
    assert trk.q_var[1] > 10 * trk.q_var[0]
    assert trk.search_radius[1] > 2 * trk.search_radius[0]


def test_alpha_beta_equations_by_hand():
    rng = np.random.default_rng(2)
    M, alpha, beta = 3, 0.7, 0.3
    x0 = rng.uniform(100, 500, (M, 2))
    trk = AlphaBetaTracker(x0, DT, np.random.default_rng(0), alpha=alpha, beta=beta)
    xs, vs = x0.copy(), np.zeros((M, 2))
    missed = np.zeros(M, dtype=int)  # frames without a measurement, per label
    for f in range(1, 12):
        z = x0 + np.array([40.0, -25.0]) * f * DT + rng.normal(0, 0.3, (M, 2))
        if f in (4, 5):
            z[1] = np.nan  # label 1 coasts two frames
        trk.predict()
        trk.update(z)
        for m in range(M):  # the seed's equations, one marker at a time
            xp = xs[m] + DT * vs[m]
            vp = vs[m]
            if np.isnan(z[m, 0]):
                xs[m], vs[m] = xp, vp
                missed[m] += 1
                continue
            r = z[m] - xp  # (1)
            xs[m] = xp + alpha * r  # (2)
            vs[m] = vp + beta / ((missed[m] + 1) * DT) * r  # (3); residual over missed+1 frames
            missed[m] = 0
        np.testing.assert_allclose(trk.x_est, xs, rtol=0, atol=1e-9)
        np.testing.assert_allclose(trk.v, vs, rtol=0, atol=1e-7)
        assert trk.status[1] == (COASTING if f in (4, 5) else TRACKED)


def test_alpha_beta_defaults_are_seed_000():
    trk = make_tracker("alpha_beta", np.zeros((1, 2)), DT, np.random.default_rng(0))
    assert (trk.alpha, trk.beta) == (1.0, 0.8)


def test_systematic_resample_matches_filterpy(monkeypatch):
    rng = np.random.default_rng(3)
    M, N = 5, 64
    weights = rng.random((M, N)) ** 3
    weights[2, 10:] = 0.0  # a degenerate row
    weights /= weights.sum(axis=1, keepdims=True)
    u = rng.random(M)
    ours = systematic_resample(weights, u)
    assert ours.shape == (M, N)
    for m in range(M):
        monkeypatch.setattr(fp_resampling, "random", lambda *a, _u=u[m]: _u)
        np.testing.assert_array_equal(ours[m], fp_resampling.systematic_resample(weights[m]))
    assert ours[2].max() < 10  # zero-weight particles are never selected


def test_condensation_uses_requested_particles_and_follows_a_still_marker():
    x0 = np.array([[200.0, 150.0], [400.0, 300.0]])
    trk = CondensationTracker(x0, DT, np.random.default_rng(4), n_particles=37)
    assert trk.particles.shape == (2, 37, 2)
    for _ in range(30):
        trk.step(x0 + np.random.default_rng(5).normal(0, 0.1, x0.shape))
    assert np.abs(trk.x_est - x0).max() < 1.0
    # The search area comes from the particle spread: a coasting label's gate grows.
    r0 = trk.search_radius.copy()
    for _ in range(5):
        trk.step(x0[1:])  # marker 0 disappears
    assert trk.status[0] == COASTING and trk.status[1] == TRACKED
    assert trk.search_radius[0] > 1.5 * r0[0]


@pytest.mark.parametrize("name", ["alpha_beta", "kalman", "imm"])
def test_constant_velocity_prediction_error_goes_to_zero(name):
    x0 = np.array([[100.0, 100.0], [300.0, 200.0], [500.0, 400.0]])
    v = np.array([[120.0, -60.0], [-90.0, 30.0], [0.0, 45.0]])  # px/s
    trk = make_tracker(name, x0, DT, np.random.default_rng(0))
    err = []
    for f in range(1, 60):
        trk.predict()
        err.append(np.abs(trk.x_pred - (x0 + v * f * DT)).max())
        trk.update(x0 + v * f * DT)
    assert err[0] > 1.0  # the first prediction does not know the velocity
    assert err[20] < 1e-2 * err[0]
    assert max(err[-10:]) < 1e-6


def test_condensation_prediction_error_stays_small_at_constant_velocity():
    x0 = np.array([[100.0, 100.0], [300.0, 200.0]])
    v = np.array([[120.0, -60.0], [-90.0, 30.0]])
    trk = make_tracker("condensation", x0, DT, np.random.default_rng(0))
    err = []
    for f in range(1, 80):
        trk.predict()
        err.append(np.linalg.norm(trk.x_pred - (x0 + v * f * DT), axis=1).max())
        trk.update(x0 + v * f * DT)
    assert np.mean(err[-40:]) < 3.0  # px; stochastic diffusion keeps it above zero
