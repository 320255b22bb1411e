"""Colour model, white balance and classification of the colour-shirt pipeline against known values."""

from __future__ import annotations

import numpy as np
import pytest

from mocap.errors import MocapInputError
from mocap.shirt.classify import assign_patches, classify_gaussian, classify_pose_assisted, patch_centroids
from mocap.shirt.colour_model import (NOT_SHIRT, ColourModel, ReferenceIlluminations, labelled_colour_means,
                                      solve_white_balance, train_colour_model, train_other_colours)


def _to_srgb_codes(lin: np.ndarray) -> np.ndarray:
    """Linear RGB -> nearest 8-bit sRGB codes (IEC 61966-2-1)."""
    x = np.clip(lin, 0.0, 1.0)
    v = np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055)
    return np.round(v * 255).astype(np.uint8)


def _model(rng: np.random.Generator, K: int = 4) -> ColourModel:
    means = np.array([[0.2, 0.02, 0.02], [0.02, 0.15, 0.02], [0.02, 0.02, 0.2], [0.15, 0.15, 0.15]])[:K]
    covs = []
    for _ in range(K):
        A = rng.normal(0, 0.004, (3, 3))
        covs.append(A @ A.T + 1e-5 * np.eye(3))
    return ColourModel(means, np.array(covs), tuple(f"c{k}" for k in range(K)))


def test_mahalanobis_distances_match_the_definition():
    rng = np.random.default_rng(0)
    cm = _model(rng)
    W = np.eye(3) + rng.normal(0, 0.1, (3, 3))
    x = rng.random((50, 3)).astype(np.float32) * 0.3
    D = cm.distances(x, W)
    for k in range(cm.n_colours):
        d = x.astype(float) @ W.T - cm.means[k]
        want = np.sqrt(np.einsum("ni,ij,nj->n", d, np.linalg.inv(cm.covariances[k]), d))
        np.testing.assert_allclose(D[:, k], want, rtol=1e-4)


def test_white_balance_is_recovered_exactly_from_colour_means():
    rng = np.random.default_rng(1)
    reference = rng.random((10, 3)) * 0.5
    W_true = np.array([[1.3, 0.1, -0.05], [0.02, 0.9, 0.1], [-0.1, 0.05, 1.6]])
    observed = reference @ np.linalg.inv(W_true).T  # W @ observed = reference
    observed[3] = np.nan  # a colour not seen
    W = solve_white_balance(observed, reference)
    np.testing.assert_allclose(W, W_true, atol=1e-10)
    # two colours only: per-channel gains
    Wd = solve_white_balance(observed[:2] * 0 + reference[:2] / [2.0, 1.0, 0.5], reference[:2])
    np.testing.assert_allclose(Wd, np.diag([2.0, 1.0, 0.5]), atol=1e-10)
    assert solve_white_balance(np.full((3, 3), np.nan), reference[:3]) is None


def test_white_balance_in_the_mahalanobis_metric_minimises_the_whitened_residuals():
    rng = np.random.default_rng(5)
    cm = _model(rng)
    W_true = np.array([[1.3, 0.1, -0.05], [0.02, 0.9, 0.1], [-0.1, 0.05, 1.6]])
    exact = cm.means @ np.linalg.inv(W_true).T
    # exact means: both metrics recover W
    np.testing.assert_allclose(solve_white_balance(exact, cm.means, whiten=cm.whiten), W_true, atol=1e-9)
    # perturbed means (no exact W): the result is the least-squares optimum of the
    # whitened residuals, as scipy's solver finds it, and beats the plain solution there
    observed = exact * (1 + rng.normal(0, 0.15, exact.shape))
    weights = np.array([1.0, 2.0, 0.5, 1.5])

    def whitened(w: np.ndarray) -> np.ndarray:
        e = observed @ w.reshape(3, 3).T - cm.means
        return (np.einsum("kij,kj->ki", cm.whiten, e) * weights[:, None]).ravel()

    from scipy.optimize import least_squares

    ref = least_squares(whitened, np.eye(3).ravel(), xtol=1e-14, ftol=1e-14, gtol=1e-14).x.reshape(3, 3)
    W = solve_white_balance(observed, cm.means, weights, whiten=cm.whiten)
    np.testing.assert_allclose(W, ref, atol=1e-6)
    plain = solve_white_balance(observed, cm.means, weights)
    assert np.sum(whitened(W.ravel()) ** 2) < np.sum(whitened(plain.ravel()) ** 2)
    # two colours: per-channel gains, exact when they explain the colours
    Wd = solve_white_balance(cm.means[:2] / [2.0, 1.0, 0.5], cm.means[:2], whiten=cm.whiten[:2])
    np.testing.assert_allclose(Wd, np.diag([2.0, 1.0, 0.5]), atol=1e-9)


def test_reference_illuminations_keep_matrices_farther_than_half_a_frobenius_unit():
    refs = ReferenceIlluminations(np.eye(3))
    assert not refs.offer(np.eye(3) * 1.2)  # ||0.2 I||_F = 0.35
    assert refs.offer(np.eye(3) * 1.4)  # 0.69
    assert not refs.offer(np.eye(3) * 1.5)  # 0.17 from the second
    assert len(refs) == 2


def test_colour_model_training_recovers_the_generating_gaussians():
    rng = np.random.default_rng(2)
    K, H, W = 3, 120, 120
    lin_means = np.array([[0.3, 0.05, 0.05], [0.05, 0.25, 0.05], [0.05, 0.05, 0.3]])
    labels = np.repeat(np.arange(K), H * W // K).reshape(H, W)
    lin = lin_means[labels] + rng.normal(0, 0.01, (H, W, 3))
    # to sRGB codes (the model works in linear RGB from 8-bit frames)
    codes = _to_srgb_codes(lin)
    cm = train_colour_model([codes], [labels], ("r", "g", "b"), erode_px=1)
    np.testing.assert_allclose(cm.means, lin_means, atol=0.004)
    np.testing.assert_allclose(np.sqrt(np.diagonal(cm.covariances, axis1=1, axis2=2)), 0.01, atol=0.003)
    means, counts = labelled_colour_means(codes, labels, K, erode_px=0, robust=True)
    np.testing.assert_allclose(means, lin_means, atol=0.004)
    assert counts.sum() == H * W
    with pytest.raises(MocapInputError, match="labelled pixels"):
        train_colour_model([codes], [np.full((H, W), -1)], ("r", "g", "b"))


def test_gaussian_classification_thresholds_and_respects_foreground_and_other_colours():
    rng = np.random.default_rng(3)
    cm = _model(rng)
    pix = np.array([cm.means[0], cm.means[2], cm.means[0] + 0.1, [0.4, 0.4, 0.4]], np.float32).reshape(2, 2, 3)
    out = classify_gaussian(pix, cm, np.eye(3), None, 3.0)
    assert out.colour.tolist() == [[0, 2], [-1, -1]]
    fg = np.array([[True, False], [True, True]])
    out = classify_gaussian(pix, cm, np.eye(3), fg, 3.0)
    assert out.colour.tolist() == [[0, -1], [-1, -1]] and out.classified_fraction == pytest.approx(1 / 3)
    # a not-shirt Gaussian right on the first pixel takes it away
    other = ColourModel(cm.means[:1], cm.covariances[:1] * 0.5, ("trousers",))
    out = classify_gaussian(pix, cm, np.eye(3), None, 3.0, other=other)
    assert out.colour[0, 0] == -1 and out.colour[0, 1] == 2


def test_pose_prior_resolves_an_ambiguous_pixel_and_removes_far_ones():
    # colours 0 and 1 identical: colour alone cannot decide; the rendered pose says colour 1 is here
    cov = np.array([np.eye(3) * 1e-4] * 2)
    cm = ColourModel(np.array([[0.2, 0.1, 0.1], [0.2, 0.1, 0.1]]), cov, ("a", "b"))
    pix = np.array([[[0.2, 0.1, 0.1], [0.2, 0.1, 0.1]]], np.float32)  # (1, 2, 3)
    dist = np.array([[50.0, 500.0], [0.0, 400.0]])  # (K, n) image px: pixel 0 on colour 1, pixel 1 far from both
    out = classify_pose_assisted(pix, cm, np.eye(3), dist, prior_weight=6.0 / 300.0, foreground=None, threshold=5.0)
    assert out.colour.tolist() == [[1, -1]]


def test_patches_of_one_colour_are_split_by_the_rendered_pose_and_centroids_are_exact():
    colour = np.full((10, 10), -1, np.int16)
    colour[1:3, 1:3] = 0  # near patch 0
    colour[7:9, 6:9] = 0  # near patch 2
    colour[5, 5] = 1
    idx = np.arange(100)
    ys, xs = np.divmod(idx, 10)
    centres = {0: (2, 2), 1: (5, 5), 2: (8, 7)}
    pdist = np.stack([np.hypot(xs - centres[p][0], ys - centres[p][1]) for p in range(3)]).astype(np.float32)
    pm = assign_patches(colour, idx, pdist, np.array([0, 1, 0]))
    assert set(np.unique(pm[1:3, 1:3])) == {0} and set(np.unique(pm[7:9, 6:9])) == {2} and pm[5, 5] == 1
    c, n = patch_centroids(pm, 3)
    np.testing.assert_allclose(c, [[1.5, 1.5], [5, 5], [7, 7.5]])
    assert n.tolist() == [4, 1, 6]
    # a stray pixel of colour 0 far from both of its patches is gated out
    colour[0, 9] = 0
    assert assign_patches(colour, idx, pdist, np.array([0, 1, 0]))[0, 9] >= 0
    assert assign_patches(colour, idx, pdist, np.array([0, 1, 0]), gate=3.0)[0, 9] == -1
    assert (assign_patches(colour, idx, pdist, np.array([0, 1, 0]), gate=3.0)[1:3, 1:3] == 0).all()


def test_other_colours_are_clustered_from_not_shirt_labels():
    rng = np.random.default_rng(4)
    H, W = 60, 60
    lin = np.where(np.arange(W)[None, :, None] < 30, [0.02, 0.02, 0.03], [0.4, 0.25, 0.18]) + rng.normal(0, 0.005, (H, W, 3))
    codes = _to_srgb_codes(lin)
    labels = np.full((H, W), NOT_SHIRT)
    other = train_other_colours([codes], [labels], [np.eye(3)], rng, n_clusters=2)
    order = np.argsort(other.means[:, 0])
    np.testing.assert_allclose(other.means[order], [[0.02, 0.02, 0.03], [0.4, 0.25, 0.18]], atol=0.01)
