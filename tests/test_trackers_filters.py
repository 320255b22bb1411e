"""Numeric identities of the batched filters against their references.

* the batched Kalman tracker gives each marker the same x and P as filterpy's
  KalmanFilter fed the same F, Q, H, R and measurements;
* the alpha-beta trackers follow seed 000's equations (1)-(3), computed here by hand
  (OpenMoCap's with its fixed search circle and inertia, the bench's adaptive one);
* OpenMoCap's Kalman filter equals OpenCV's ``cv2.KalmanFilter`` driven as OpenMoCap
  drives it (Q from the speed, search radius from the prior velocity variance);
* OpenMoCap's CONDENSATION trails a constant-velocity marker by twice its speed (its
  weighted mean sits halfway between the cloud and the last measurement);
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
    LOST,
    TRACKED,
    AdaptiveAlphaBetaTracker,
    AlphaBetaTracker,
    CondensationTracker,
    DriftCondensationTracker,
    KalmanTracker,
    OpenMoCapKalmanTracker,
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


def test_adaptive_alpha_beta_equations_by_hand():
    rng = np.random.default_rng(2)
    M, alpha, beta = 3, 0.7, 0.3
    x0 = rng.uniform(100, 500, (M, 2))
    trk = AdaptiveAlphaBetaTracker(x0, DT, np.random.default_rng(0), alpha=alpha, beta=beta)
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


def test_openmocap_alpha_beta_equations_fixed_circle_and_inertia():
    rng = np.random.default_rng(5)
    M, alpha, beta = 3, 0.9, 0.6
    x0 = rng.uniform(100, 500, (M, 2))
    trk = AlphaBetaTracker(x0, DT, np.random.default_rng(0), alpha=alpha, beta=beta, search_radius_px=33.0)
    xs, ds = x0.copy(), np.zeros((M, 2))  # position px, velocity px/frame
    for f in range(1, 40):
        z = x0 + np.array([7.0, -4.0]) * f + rng.normal(0, 0.3, (M, 2))
        if 5 <= f < 30:
            z[1] = np.nan  # label 1 sees nothing for 25 frames
        trk.predict()
        np.testing.assert_allclose(trk.search_radius, 33.0)  # fixed, whatever happens
        trk.update(z)
        for m in range(M):  # equations (1)-(3) with dt = one frame; inertia without a detection
            xp = xs[m] + ds[m]
            if np.isnan(z[m, 0]):
                xs[m] = xp
                continue
            r = z[m] - xp
            xs[m] = xp + alpha * r
            ds[m] = ds[m] + beta * r
        np.testing.assert_allclose(trk.x_est, xs, rtol=0, atol=1e-9)
        np.testing.assert_allclose(trk.v * DT, ds, rtol=0, atol=1e-9)
        assert trk.status[1] == (COASTING if 5 <= f < 30 else TRACKED)  # never given up, unlike the bench's


def test_alpha_beta_defaults_are_seed_000():
    trk = make_tracker("alpha_beta", np.zeros((1, 2)), DT, np.random.default_rng(0))
    assert (trk.alpha, trk.beta, trk.search_radius_px) == (1.0, 0.8, 40.0)  # 40 px: 5 % of 640x480's diagonal
    adaptive = make_tracker("alpha_beta_adaptive", np.zeros((1, 2)), DT, np.random.default_rng(0))
    assert (adaptive.alpha, adaptive.beta) == (1.0, 0.8)
    adaptive.predict()
    trk.predict()
    np.testing.assert_allclose(adaptive.search_radius, trk.search_radius)  # both start at the same circle


def test_openmocap_kalman_equals_opencv_driven_as_openmocap():
    cv2 = pytest.importorskip("cv2")
    rng = np.random.default_rng(8)
    M = 3
    x0 = rng.uniform(150, 450, (M, 2))
    trk = OpenMoCapKalmanTracker(x0, DT, np.random.default_rng(0))
    twins, vel = [], np.zeros((M, 2))
    for m in range(M):
        kf = cv2.KalmanFilter(4, 2, 0, cv2.CV_64F)
        kf.transitionMatrix = np.array([[1, 0, 1, 0], [0, 1, 0, 1], [0, 0, 1, 0], [0, 0, 0, 1]], dtype=np.float64)
        kf.measurementMatrix = np.array([[1, 0, 0, 0], [0, 1, 0, 0]], dtype=np.float64)
        kf.processNoiseCov = np.diag([0.0, 0.0, 0.2, 0.2])
        kf.measurementNoiseCov = np.diag([0.2845, 0.0455])
        kf.errorCovPost = np.diag([0.0, 0.0, 100.0, 100.0])
        kf.statePost = np.array([[x0[m, 0]], [x0[m, 1]], [0.0], [0.0]])
        twins.append(kf)
    v_true = rng.uniform(-15, 15, (M, 2))  # px/frame
    for f in range(1, 30):
        z = x0 + v_true * f + np.where(f % 7 == 0, 3.0 * np.sin(f), 0.0) + rng.normal(0, 0.3, (M, 2))
        if f in (10, 11, 12):
            z[2] = np.nan  # no detection: corrected with its own prediction
        trk.predict()
        for m, kf in enumerate(twins):
            pred = kf.predict()
            centre = np.trunc(pred[:2, 0])  # OpenMoCap: (int) of the prediction
            radius = np.trunc(100.0 * 0.5 * (np.sqrt(kf.errorCovPre[2, 2]) + np.sqrt(kf.errorCovPre[3, 3])))
            kf.processNoiseCov = np.diag([0.0, 0.0, 0.06 + 0.013 * abs(vel[m, 0]), 0.06 + 0.013 * abs(vel[m, 1])])
            np.testing.assert_allclose(trk.x_pred[m], centre, atol=1e-9)
            np.testing.assert_allclose(trk.search_radius[m], radius, atol=1e-9)
            post = kf.correct((centre if np.isnan(z[m, 0]) else z[m]).reshape(2, 1))
            vel[m] = post[2:, 0]
        trk.update(z)
        post = np.array([kf.statePost[:2, 0] for kf in twins])
        np.testing.assert_allclose(trk.x_state, post, atol=1e-7)
        np.testing.assert_allclose(trk.v * DT, vel, atol=1e-7)
        reported = np.where(np.isnan(z), np.trunc(np.array([kf.statePre[:2, 0] for kf in twins])), z)
        np.testing.assert_allclose(trk.x_est, reported, atol=1e-9)  # the detection, else the prediction


def test_openmocap_condensation_trails_a_moving_marker_by_twice_its_speed():
    M, v = 200, np.array([6.0, 0.0])  # many labels at once average the particle noise
    x0 = np.tile([[100.0, 240.0]], (M, 1))
    trk = CondensationTracker(x0, DT, np.random.default_rng(0))
    first = trk.particles
    assert first.shape == (M, 100, 2)
    assert first[..., 0].min() < 40 and first[..., 0].max() > 600  # the first cloud covers the image
    lag = []
    for f in range(1, 60):
        before = trk.particles
        trk.predict()
        # The search radius is the mean of the cloud's two standard deviations.
        np.testing.assert_allclose(trk.search_radius, 0.5 * before.std(axis=1).sum(axis=1), rtol=1e-9)
        lag.append((x0 + v * f - trk.x_pred).mean(axis=0))
        trk.update(x0 + v * f)
    lag = np.array(lag)[-30:].mean(axis=0)
    # Identity dynamics and weights as wide as the cloud: the weighted mean sits halfway
    # between the cloud and the last measurement, so the steady lag e solves e = v + e / 2.
    assert 1.8 * v[0] < lag[0] < 2.4 * v[0] and abs(lag[1]) < 1.0
    # Without a detection the estimate stays at the last one.
    trk.predict()
    trk.update(np.full((M, 2), np.nan))
    np.testing.assert_allclose(trk.x_est, x0 + v * 59)
    assert (trk.status == COASTING).all() and not (trk.status == LOST).any()


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


def test_drift_condensation_uses_requested_particles_and_follows_a_still_marker():
    x0 = np.array([[200.0, 150.0], [400.0, 300.0]])
    trk = DriftCondensationTracker(x0, DT, np.random.default_rng(4), n_particles=37)
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


@pytest.mark.parametrize("name", ["alpha_beta", "alpha_beta_adaptive", "kalman", "imm"])
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


def test_drift_condensation_prediction_error_stays_small_at_constant_velocity():
    x0 = np.array([[100.0, 100.0], [300.0, 200.0]])
    v = np.array([[120.0, -60.0], [-90.0, 30.0]])
    trk = make_tracker("condensation_drift", x0, DT, np.random.default_rng(0))
    err = []
    for f in range(1, 80):
        trk.predict()
        err.append(np.linalg.norm(trk.x_pred - (x0 + v * f * DT), axis=1).max())
        trk.update(x0 + v * f * DT)
    assert np.mean(err[-40:]) < 3.0  # px; stochastic diffusion keeps it above zero
