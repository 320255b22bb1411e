"""Triangulation: exactness, noise against theory, outlier rejection, epipolar distances."""

from __future__ import annotations

import numpy as np
import pytest

from mocap.calibration import Calibration, Camera
from mocap.triangulation import (
    epipolar_distances,
    normalized_coordinates,
    refine_points,
    reprojection_residuals,
    triangulate,
    triangulate_dlt,
)
from mocap.calib.synthetic import look_at


def ring_rig(n: int = 4, radius: float = 4.0, height: float = 2.2, f: float = 600.0, dist=(-0.12, 0.03, 0.001, -0.0015, 0.0)) -> Calibration:
    cams = []
    for i, a in enumerate(np.linspace(0, 2 * np.pi, n, endpoint=False) + 0.4):
        R, t = look_at([radius * np.cos(a), radius * np.sin(a), height], [0.0, 0.0, 1.0])
        cams.append(Camera(f"cam{i}", (640, 480), [[f, 0, 320], [0, f * 1.01, 240], [0, 0, 1]], dist, R, t))
    return Calibration(tuple(cams))


def points_in_volume(rng: np.random.Generator, n: int) -> np.ndarray:
    return rng.uniform([-0.8, -0.8, 0.1], [0.8, 0.8, 1.9], (n, 3))


def test_exact_projections_give_the_points_back() -> None:
    rng = np.random.default_rng(0)
    cal = ring_rig()
    X = points_in_volume(rng, 500)
    p2ds = cal.project(X)
    assert np.abs(triangulate_dlt(p2ds, cal) - X).max() < 1e-9
    res = triangulate(p2ds, cal)
    assert np.abs(res.points - X).max() < 1e-9
    assert np.all(res.n_views == 4) and np.nanmax(res.residual_px) < 1e-6
    # Two views suffice; one view does not.
    p2 = p2ds.copy()
    p2[2:] = np.nan
    assert np.abs(triangulate_dlt(p2, cal) - X).max() < 1e-9
    p2[1, :10] = np.nan
    assert np.isnan(triangulate_dlt(p2, cal)[:10]).all()
    assert np.isnan(triangulate(p2, cal).points[:10]).all()


def _theory_rms(X: np.ndarray, cal: Calibration, sigma_px: float) -> np.ndarray:
    """Per-point RMS 3D error of the maximum-likelihood estimate, first order:
    sqrt(trace(sigma^2 (J^T J)^-1)) with J the stacked pixel Jacobians (numerical)."""
    eps = 1e-6
    J = np.zeros((len(X), 2 * len(cal), 3))
    for k in range(3):
        d = np.zeros(3)
        d[k] = eps
        J[:, :, k] = ((cal.project(X + d) - cal.project(X - d)) / (2 * eps)).transpose(1, 0, 2).reshape(len(X), -1)
    cov = sigma_px**2 * np.linalg.inv(J.transpose(0, 2, 1) @ J)
    return np.sqrt(np.trace(cov, axis1=1, axis2=2))


def test_noise_error_matches_first_order_theory() -> None:
    rng = np.random.default_rng(1)
    cal = ring_rig()
    X = points_in_volume(rng, 4000)
    sigma = 0.5
    p2ds = cal.project(X) + rng.normal(0, sigma, (len(cal), len(X), 2))
    theory = np.sqrt(np.mean(_theory_rms(X, cal, sigma) ** 2))
    dlt = np.sqrt(np.mean(np.sum((triangulate_dlt(p2ds, cal) - X) ** 2, axis=1)))
    ml = np.sqrt(np.mean(np.sum((triangulate(p2ds, cal, max_residual_px=np.inf).points - X) ** 2, axis=1)))
    # 4000 samples: the RMS estimate itself is good to about 2 %.
    assert 0.93 * theory < ml < 1.07 * theory, (ml, theory)
    assert 0.93 * theory < dlt < 1.15 * theory, (dlt, theory)
    assert ml <= dlt * 1.005


def test_weights_downweight_a_noisy_view() -> None:
    rng = np.random.default_rng(2)
    cal = ring_rig()
    X = points_in_volume(rng, 2000)
    p2ds = cal.project(X)
    p2ds[0] += rng.normal(0, 3.0, p2ds[0].shape)
    p2ds[1:] += rng.normal(0, 0.2, p2ds[1:].shape)
    w = np.ones((4, len(X)))
    w[0] = 0.2 / 3.0  # inverse noise std
    err_eq = np.linalg.norm(triangulate(p2ds, cal, max_residual_px=np.inf).points - X, axis=1)
    err_w = np.linalg.norm(triangulate(p2ds, cal, w, max_residual_px=np.inf).points - X, axis=1)
    assert np.sqrt(np.mean(err_w**2)) < 0.6 * np.sqrt(np.mean(err_eq**2))
    # Zero weight is the same as a missing view.
    w0 = np.ones((4, len(X)))
    w0[0] = 0.0
    p_missing = p2ds.copy()
    p_missing[0] = np.nan
    np.testing.assert_allclose(triangulate_dlt(p2ds, cal, w0), triangulate_dlt(p_missing, cal), atol=1e-12)


def test_outlier_view_is_rejected() -> None:
    rng = np.random.default_rng(3)
    cal = ring_rig()
    X = points_in_volume(rng, 300)
    p2ds = cal.project(X) + rng.normal(0, 0.1, (4, 300, 2))
    bad_cam = rng.integers(0, 4, 300)
    wrong = rng.random(300) < 0.5
    offsets = rng.normal(0, 1, (300, 2))
    offsets = 12.0 * offsets / np.linalg.norm(offsets, axis=1, keepdims=True)
    p2ds[bad_cam[wrong], np.flatnonzero(wrong)] += offsets[wrong]
    res = triangulate(p2ds, cal, max_residual_px=1.5)
    assert not res.used[bad_cam[wrong], np.flatnonzero(wrong)].any()
    assert np.all(res.n_views[wrong] == 3) and np.all(res.n_views[~wrong] == 4)
    err = np.linalg.norm(res.points - X, axis=1)
    assert err.max() < 0.004
    assert np.nanmax(res.residual_px) < 1.5
    # Without rejection the outliers pull the points by centimetres.
    naive = np.linalg.norm(triangulate(p2ds, cal, max_residual_px=np.inf).points - X, axis=1)
    assert np.median(naive[wrong]) > 5 * np.median(err[wrong])


def test_two_disagreeing_views_are_rejected() -> None:
    cal = ring_rig()
    X = np.array([[0.1, 0.2, 1.0], [0.0, 0.0, 1.5]])
    p2ds = cal.project(X)
    p2ds[2:] = np.nan
    p2ds[0, 0] += [0.0, 20.0]
    res = triangulate(p2ds, cal, max_residual_px=2.0)
    assert np.isnan(res.points[0]).all() and res.n_views[0] == 0
    assert np.abs(res.points[1] - X[1]).max() < 1e-9 and res.n_views[1] == 2


def test_refinement_and_residuals() -> None:
    rng = np.random.default_rng(4)
    cal = ring_rig()
    X = points_in_volume(rng, 100)
    p2ds = cal.project(X)
    start = X + rng.normal(0, 0.02, X.shape)
    assert np.abs(refine_points(start, p2ds, cal, iterations=4) - X).max() < 1e-8
    shifted = p2ds.copy()
    shifted[1, :, 0] += 3.0
    shifted[1, :, 1] += 4.0
    r = reprojection_residuals(X, shifted, cal)
    np.testing.assert_allclose(r[1], 5.0, atol=1e-9)
    np.testing.assert_allclose(r[[0, 2, 3]], 0.0, atol=1e-9)
    shifted[3, 5] = np.nan
    assert np.isnan(reprojection_residuals(X, shifted, cal)[3, 5])


def test_epipolar_distance_of_a_known_offset() -> None:
    rng = np.random.default_rng(5)
    cal = ring_rig()
    X = points_in_volume(rng, 50)
    d = epipolar_distances(normalized_coordinates(cal.project(X), cal), cal)
    diag = np.eye(4, dtype=bool)
    assert np.nanmax(d[~diag]) < 1e-6 and np.isnan(d[diag]).all()
    # Rectified stereo pair (same K, baseline along x): epipolar lines are image rows,
    # so moving a point 5 px vertically in one view puts it 5 px from the line in that
    # view and its partner 5 px from the back-projected line in the other.
    K = [[500, 0, 320], [0, 500, 240], [0, 0, 1]]
    stereo = Calibration((Camera("L", (640, 480), K), Camera("R", (640, 480), K, t=[-0.3, 0.0, 0.0])))
    Xs = np.column_stack([rng.uniform(-0.5, 0.5, 50), rng.uniform(-0.4, 0.4, 50), rng.uniform(2, 4, 50)])
    p2 = stereo.project(Xs)
    p2[1, :, 1] += 5.0
    p2[1, :10] = np.nan
    ds = epipolar_distances(normalized_coordinates(p2, stereo), stereo)
    np.testing.assert_allclose(ds[0, 1, 10:], 5.0, atol=1e-9)
    np.testing.assert_allclose(ds[1, 0, 10:], 5.0, atol=1e-9)
    assert np.isnan(ds[0, 1, :10]).all()


def test_shape_errors_name_the_problem() -> None:
    cal = ring_rig()
    with pytest.raises(ValueError, match="3 cameras but the calibration has 4"):
        triangulate_dlt(np.zeros((3, 5, 2)), cal)
    with pytest.raises(ValueError, match=r"\(C, N, 2\)"):
        triangulate_dlt(np.zeros((4, 5, 3)), cal)
    with pytest.raises(ValueError, match="weights"):
        triangulate_dlt(np.zeros((4, 5, 2)), cal, np.ones((4, 4)))
    with pytest.raises(ValueError, match="min_views"):
        triangulate(np.zeros((4, 5, 2)), cal, min_views=1)
