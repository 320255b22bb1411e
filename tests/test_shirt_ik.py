"""Step 4 of the colour-shirt pipeline: Pinocchio IK on patch centroids, and the training of its covariances."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from mocap.calibration import Camera
from mocap.shirt.classify import crop_view
from mocap.shirt.ik import Constraints, IKPriors, ShirtIK, train_priors
from mocap.shirt.kinematics import UPPER_NV
from simbench.render.camera import intrinsics_from_fov, look_at_rotation
from simbench.scenes.anthropometry import BodyParams
from simbench.pipelines.shirt_database import shirt_model


def _camera(name: str, position) -> Camera:
    R = look_at_rotation(np.asarray(position, float), np.array([0.0, 0.0, 1.2]))
    return Camera(name, (640, 480), intrinsics_from_fov(640, 480, 60.0), np.zeros(5), R, -R @ np.asarray(position, float))


@pytest.fixture(scope="module")
def rig():
    model = shirt_model(BodyParams())
    cams = [_camera("left", (2.1, 0.95, 1.55)), _camera("right", (2.1, -0.95, 1.55))]
    return model, cams, ShirtIK(model.kin, model.geometry.body_names, cams)


def _true_pose(model) -> np.ndarray:
    h = np.zeros(11)
    h[[3, 5, 6]] = [-0.9, -0.6, -0.9]  # left arm down and forward, elbow bent
    h[[7, 9, 10]] = [0.4, 0.3, 0.5]
    h[2] = 0.15
    R = pin.utils.rpyToMatrix(0.05, -0.05, 0.3)
    return model.kin.make_q(R, np.array([0.05, -0.02, 0.95]), h)


def _constraints(model, ik, cams, q) -> Constraints:
    """Exact centroid constraints of pose q: anchors from its id maps, targets from the model itself."""
    parts = []
    for ci, cam in enumerate(cams):
        view = crop_view(320, 220, 360, 120)
        rend = model.render_camera(q, cam, view)
        pa, ba, pt, wa = model.patch_anchors(rend)
        use = np.unique(pa)
        index = -np.ones(model.n_patches, int)
        index[use] = np.arange(use.size)
        parts.append(Constraints(np.full(use.size, ci), use, np.zeros((use.size, 2)), np.repeat(np.eye(2)[None], use.size, 0),
                                 np.full(use.size, 300.0), np.zeros(use.size, bool), index[pa], ba, pt, wa))
    cons = Constraints.concatenate(parts)
    cons.target_px = ik.centroids(q, cons)[0]
    return cons


def test_ik_recovers_a_pose_from_exact_centroids(rig):
    model, cams, ik = rig
    q_true = _true_pose(model)
    cons = _constraints(model, ik, cams, q_true)
    assert len(cons) >= 24
    rng = np.random.default_rng(0)
    for _ in range(3):
        dq = rng.normal(0.0, 0.12, UPPER_NV)
        dq[:3] = rng.normal(0.0, 0.03, 3)
        res = ik.solve(pin.integrate(model.kin.model, q_true, dq), cons, iterations=40)
        err = np.linalg.norm(model.kin.joint_centres(res.q) - model.kin.joint_centres(q_true), axis=1)
        assert err.max() < 2e-3, err
        assert res.centroid_rms_px < 0.05


def test_root_only_fit_moves_only_the_root(rig):
    model, cams, ik = rig
    q_true = _true_pose(model)
    cons = _constraints(model, ik, cams, q_true)
    q0 = q_true.copy()
    q0[:3] += [0.08, -0.05, 0.04]
    active = np.zeros(UPPER_NV, bool)
    active[:6] = True
    res = ik.solve(q0, cons, active=active, iterations=30)
    np.testing.assert_allclose(res.q[7:], q_true[7:])
    np.testing.assert_allclose(res.q[:3], q_true[:3], atol=1e-4)


def test_ik_jacobian_matches_finite_differences(rig):
    model, cams, ik = rig
    q = _true_pose(model)
    cons = _constraints(model, ik, cams, q)
    c0, J = ik.centroids(q, cons, jacobians=True)
    eps = 1e-6
    for k in (0, 4, 8, 12, 16):
        dq = np.zeros(UPPER_NV)
        dq[k] = eps
        c1, _ = ik.centroids(pin.integrate(model.kin.model, q, dq), cons)
        np.testing.assert_allclose((c1 - c0) / eps, J[:, :, k], atol=2e-3 * max(1.0, np.abs(J[:, :, k]).max()))


def test_priors_are_the_spread_of_the_training_terms():
    rng = np.random.default_rng(1)
    res = rng.normal(0.0, [0.02, 0.01], (4000, 2))
    res[:40] = 5.0  # a few patches swapped: the trimmed covariance ignores them
    patch = rng.integers(0, 20, 4000)
    blend = rng.normal(0.0, 0.3, (500, UPPER_NV))
    motion = rng.normal(0.0, 0.05, (500, UPPER_NV))
    pr = train_priors(patch, res, blend, motion, 20, 500, floor_std=0.0, floor_centroid=0.0)
    np.testing.assert_allclose(np.sqrt(np.diagonal(pr.centroid_cov, axis1=1, axis2=2)), np.broadcast_to([0.02, 0.01], (20, 2)), rtol=0.2)
    np.testing.assert_allclose(pr.blend_std, 0.3, rtol=0.15)
    np.testing.assert_allclose(pr.motion_std, 0.05, rtol=0.15)
    # a floor keeps joints the training never moved free
    pr = train_priors(patch, res, blend, np.zeros((10, UPPER_NV)), 20, 500, floor_std=0.03)
    assert np.all(pr.motion_std == 0.03)
    with pytest.raises(Exception, match="positive"):
        IKPriors(pr.centroid_cov, np.zeros(UPPER_NV), pr.motion_std)
