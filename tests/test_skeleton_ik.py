"""Skeleton solving: Pinocchio IK recovers known humanoid poses from noisy markers.

Ground truth comes from MuJoCo forward kinematics of the same MJCF (the bench's humanoid
with the Plug-in Gait marker sites); the solver only sees marker positions.
"""

from __future__ import annotations

import mujoco
import numpy as np
import pinocchio as pin
import pytest
from scipy.spatial.transform import Rotation

from mocap.errors import MocapInputError
from mocap.skeleton import IKParams, SkeletonSolver, solve_skeleton
from mocap.skeleton_fit import mujoco_from_pinocchio_q, pinocchio_from_mujoco_q
from mocap.skeleton_bridge import bridge_undetermined_hinges
from mocap.subject import SubjectModel
from mocap.types import Trajectories
from simbench.scenes.humanoid import BODY_NAMES, HINGE_NAMES, BodyParams, humanoid_mjcf

NOISE_M = 0.001
# Joints whose angle 1 mm of marker noise determines to better than 1 deg (predicted by the
# solver's own covariance) are "well constrained"; the acceptance is RMSE < 2 deg on them.
WELL_CONSTRAINED_STD_DEG = 1.0
# Hinges the Plug-in Gait set must constrain well (the set has no marker on the abdomen,
# so the lumbar/thorax split of the axial twist is not among them).
CORE_HINGES = [
    "neck_x", "neck_y", "neck_z",
    "shoulder_l_x", "shoulder_l_y", "shoulder_l_z", "elbow_l",
    "shoulder_r_x", "shoulder_r_y", "shoulder_r_z", "elbow_r",
    "hip_l_y", "knee_l", "ankle_l_y", "hip_r_y", "knee_r", "ankle_r_y",
]


@pytest.fixture(scope="module")
def humanoid():
    xml = humanoid_mjcf(BodyParams(), marker_set="plugin_gait_full")
    model = mujoco.MjModel.from_xml_string(xml)
    subject = SubjectModel.from_mjcf_text(xml, name="pig")
    return xml, model, subject


def _fk(model: mujoco.MjModel, qpos: np.ndarray) -> tuple[list[str], np.ndarray, np.ndarray]:
    """Marker sites ``(F, M, 3)`` and body origins ``(F, 16, 3)`` for MuJoCo qpos ``(F, 40)``."""
    data = mujoco.MjData(model)
    sites = np.zeros((len(qpos), model.nsite, 3))
    bodies = np.zeros((len(qpos), model.nbody - 1, 3))
    for f, q in enumerate(qpos):
        data.qpos[:] = q
        mujoco.mj_kinematics(model, data)
        sites[f] = data.site_xpos
        bodies[f] = data.xpos[1:]
    return [model.site(i).name for i in range(model.nsite)], sites, bodies


def _smooth_motion(model: mujoco.MjModel, rng: np.random.Generator, n_frames: int, rate_hz: float, amplitude: float) -> np.ndarray:
    """Every hinge a sinusoid of random phase and frequency around the middle of its range;
    the root walks forward while turning."""
    t = np.arange(n_frames) / rate_hz
    lo, hi = model.jnt_range[1:, 0], model.jnt_range[1:, 1]
    phase = rng.uniform(0, 2 * np.pi, len(lo))
    freq = rng.uniform(0.3, 1.2, len(lo))
    qpos = np.zeros((n_frames, model.nq))
    qpos[:, 7:] = (lo + hi) / 2 + amplitude * (hi - lo) / 2 * np.sin(2 * np.pi * freq * t[:, None] + phase)
    yaw = 0.8 * t
    qpos[:, 3] = np.cos(yaw / 2)
    qpos[:, 6] = np.sin(yaw / 2)
    qpos[:, 0] = 0.5 * t
    qpos[:, 2] = 0.95 + 0.02 * np.sin(2 * np.pi * t)
    return qpos


def _random_poses(model: mujoco.MjModel, rng: np.random.Generator, n: int, fraction: float) -> np.ndarray:
    lo, hi = model.jnt_range[1:, 0], model.jnt_range[1:, 1]
    qpos = np.zeros((n, model.nq))
    qpos[:, 7:] = (lo + hi) / 2 + fraction * (hi - lo) / 2 * rng.uniform(-1, 1, (n, len(lo)))
    qpos[:, 3:7] = Rotation.from_euler("zyx", rng.uniform([-np.pi, -0.3, -0.3], [np.pi, 0.3, 0.3], (n, 3))).as_quat(scalar_first=True)
    qpos[:, :3] = rng.uniform([-2, -2, 0.6], [2, 2, 1.2], (n, 3))
    return qpos


def _angle_rmse_deg(fit, qpos: np.ndarray) -> np.ndarray:
    err = fit.joint_angles_rad - qpos[:, 7:]
    return np.degrees(np.sqrt(np.nanmean(err**2, axis=0)))


# ------------------------------------------------------------------------------ model
def test_model_matches_mujoco(humanoid):
    """Pinocchio model of the solver: hinge names, axes, offsets and marker FK equal MuJoCo's."""
    xml, model, subject = humanoid
    solver = SkeletonSolver(subject)
    tree = solver.tree
    assert tree.body_names == list(BODY_NAMES)
    assert tree.hinge_names == list(HINGE_NAMES)
    np.testing.assert_allclose(tree.offsets_m[1:], model.body_pos[2:], atol=1e-12)
    np.testing.assert_allclose(tree.hinge_axes, model.jnt_axis[1:], atol=1e-12)
    np.testing.assert_allclose(tree.lower_rad, model.jnt_range[1:, 0])
    np.testing.assert_allclose(tree.upper_rad, model.jnt_range[1:, 1])
    assert [tree.body_names[b] for b in tree.hinge_bodies] == [model.body(model.jnt_bodyid[j]).name for j in range(1, model.njnt)]

    qpos = _random_poses(model, np.random.default_rng(0), 5, 1.0)
    names, sites, bodies = _fk(model, qpos)
    assert solver.marker_labels == names
    q = pinocchio_from_mujoco_q(qpos)
    np.testing.assert_allclose(mujoco_from_pinocchio_q(q), qpos)
    np.testing.assert_allclose(solver.marker_positions(q), sites, atol=1e-12)
    for f in range(len(q)):
        np.testing.assert_allclose(solver.joint_centres(q[f]), bodies[f], atol=1e-12)


def test_marker_jacobian_is_pinocchio_frame_jacobian(humanoid):
    """The vectorised marker Jacobian equals getFrameJacobian(LOCAL_WORLD_ALIGNED) and finite differences."""
    _, model, subject = humanoid
    solver = SkeletonSolver(subject)
    q = pinocchio_from_mujoco_q(_random_poses(model, np.random.default_rng(1), 1, 0.8)[0])
    p, jac = solver._markers_and_jacobian(q)
    pin.computeJointJacobians(solver.model, solver.data, q)
    pin.updateFramePlacements(solver.model, solver.data)
    for i, fid in enumerate(solver._marker_frames):
        ref = pin.getFrameJacobian(solver.model, solver.data, fid, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)[:3]
        np.testing.assert_allclose(jac[i], ref, atol=1e-12)
        np.testing.assert_allclose(p[i], solver.data.oMf[fid].translation, atol=1e-12)
    eps = 1e-6
    for k in (0, 4, 10, 20, 38):
        dv = np.zeros(solver.model.nv)
        dv[k] = eps
        fd = (solver.marker_positions(pin.integrate(solver.model, q, dv)) - solver.marker_positions(pin.integrate(solver.model, q, -dv))) / (2 * eps)
        np.testing.assert_allclose(jac[:, :, k], fd, atol=1e-7)


# ------------------------------------------------------------------------------ accuracy
def test_recovers_smooth_motion_from_noisy_markers(humanoid):
    """Acceptance: 1 mm noise -> well-constrained joint angles RMSE < 2 deg, joint centres RMSE < 10 mm."""
    _, model, subject = humanoid
    rng = np.random.default_rng(2)
    qpos = _smooth_motion(model, rng, n_frames=150, rate_hz=100.0, amplitude=0.5)
    names, sites, bodies = _fk(model, qpos)
    traj = Trajectories(names, sites + rng.normal(0, NOISE_M, sites.shape), np.arange(len(qpos)) / 100.0)
    fit = solve_skeleton(traj, subject)

    assert fit.valid.all() and fit.q.shape == (150, 40) and fit.qpos.shape == (150, 40)
    np.testing.assert_allclose(fit.qpos[:, 7:], fit.joint_angles_rad)
    np.testing.assert_allclose(np.linalg.norm(fit.qpos[:, 3:7], axis=1), 1.0, atol=1e-9)
    rmse = _angle_rmse_deg(fit, qpos)
    std_deg = np.degrees(np.median(fit.angle_std_rad, axis=0))
    well = fit.well_constrained(WELL_CONSTRAINED_STD_DEG)
    np.testing.assert_array_equal(well, std_deg < WELL_CONSTRAINED_STD_DEG)
    names_well = [n for n, w in zip(fit.hinge_names, well) if w]
    print(f"\nwell-constrained hinges: {len(names_well)}/33; angle RMSE over them {np.sqrt(np.mean(rmse[well] ** 2)):.2f} deg, "
          f"max {rmse[well].max():.2f} deg ({fit.hinge_names[int(np.argmax(np.where(well, rmse, -1)))]})")
    assert set(CORE_HINGES) <= set(names_well)
    assert len(names_well) >= 20
    assert rmse[well].max() < 2.0, dict(zip(fit.hinge_names, rmse.round(2)))
    # The predicted spread is honest: for every hinge the markers constrain at all, the
    # measured RMSE agrees with the RMS over frames of the predicted standard deviation.
    predicted = np.degrees(np.sqrt(np.mean(fit.angle_std_rad**2, axis=0)))
    constrained = predicted < 3.0
    ratio = rmse[constrained] / predicted[constrained]
    print(f"measured / predicted angle error: {ratio.min():.2f} .. {ratio.max():.2f} over {constrained.sum()} hinges")
    assert np.all((ratio > 0.5) & (ratio < 1.5))
    # The unconstrained split of the trunk's axial twist is flagged as such.
    assert std_deg[fit.hinge_names.index("lumbar_z")] > 5.0

    centre_err = np.linalg.norm(fit.joint_centres_m - bodies, axis=2)
    centre_rmse_mm = 1000 * np.sqrt(np.mean(centre_err**2))
    print(f"joint-centre RMSE {centre_rmse_mm:.2f} mm; marker residual RMS {np.mean(fit.marker_rms_mm):.2f} mm; "
          f"median LM iterations {np.median(fit.iterations):.0f}")
    assert centre_rmse_mm < 10.0
    # Residual of a least-squares fit to 1 mm noise: below sqrt(3) mm, well above 0.
    assert 0.8 < np.mean(fit.marker_rms_mm) < 1.8
    assert np.isnan(fit.marker_errors_mm).sum() == 0


def test_recovers_independent_random_poses_from_cold_starts(humanoid):
    """Each pose solved alone (no warm start): rigid root fit + grid search + LM finds it."""
    _, model, subject = humanoid
    rng = np.random.default_rng(3)
    qpos = _random_poses(model, rng, 25, fraction=0.7)
    names, sites, bodies = _fk(model, qpos)
    noisy = sites + rng.normal(0, NOISE_M, sites.shape)
    solver = SkeletonSolver(subject)
    fits = [solver.solve(Trajectories(names, noisy[f : f + 1], [0.0])) for f in range(len(qpos))]
    rms = np.array([f.marker_rms_mm[0] for f in fits])
    angles = np.concatenate([f.joint_angles_rad for f in fits])
    std = np.concatenate([f.angle_std_rad for f in fits])
    centres = np.concatenate([f.joint_centres_m for f in fits])
    well = np.degrees(std) < WELL_CONSTRAINED_STD_DEG
    err_deg = np.degrees(np.abs(angles - qpos[:, 7:]))
    rmse_well = np.sqrt(np.mean(err_deg[well] ** 2))
    centre_rmse_mm = 1000 * np.sqrt(np.mean(np.sum((centres - bodies) ** 2, axis=2)))
    print(f"\ncold starts: marker RMS max {rms.max():.2f} mm; well-constrained angle RMSE {rmse_well:.2f} deg; joint-centre RMSE {centre_rmse_mm:.2f} mm")
    assert rms.max() < 2.5  # every pose found (a local minimum leaves centimetres)
    assert rmse_well < 2.0
    assert centre_rmse_mm < 10.0


def test_gaps_and_too_few_markers(humanoid):
    """Missing markers are skipped; frames with fewer than min_markers are NaN and the solve recovers after."""
    _, model, subject = humanoid
    rng = np.random.default_rng(4)
    qpos = _smooth_motion(model, rng, n_frames=40, rate_hz=100.0, amplitude=0.3)
    names, sites, bodies = _fk(model, qpos)
    xyz = sites + rng.normal(0, NOISE_M, sites.shape)
    # Random dropouts (20 % of marker-frames), and frames 15-17 with only 3 markers.
    drop = rng.random(xyz.shape[:2]) < 0.2
    xyz[drop] = np.nan
    xyz[15:18, 3:] = np.nan
    # Labels in another order plus one the subject does not know: matched by name.
    order = rng.permutation(len(names))
    traj = Trajectories([names[i] for i in order] + ["EXTRA"], np.concatenate([xyz[:, order], np.zeros((40, 1, 3))], axis=1), np.arange(40) / 100.0)
    fit = solve_skeleton(traj, subject, IKParams(min_markers=6))
    assert not fit.valid[15:18].any() and fit.valid[:15].all() and fit.valid[18:].all()
    assert np.isnan(fit.q[15:18]).all() and np.isnan(fit.joint_centres_m[15:18]).all()
    np.testing.assert_array_equal(fit.n_markers, np.isfinite(xyz).all(axis=2).sum(axis=1))
    np.testing.assert_array_equal(np.isnan(fit.marker_errors_mm[fit.valid]), ~np.isfinite(xyz[fit.valid]).all(axis=2))
    ok = fit.valid
    centre_rmse_mm = 1000 * np.sqrt(np.mean(np.sum((fit.joint_centres_m[ok] - bodies[ok]) ** 2, axis=2)))
    assert centre_rmse_mm < 10.0


def test_joint_limits_hold_when_markers_ask_beyond(humanoid):
    """Markers generated with the knees hyper-extended beyond their range: the fit stops at the limit."""
    xml, model, subject = humanoid
    # A model without limits generates the markers; the subject (with limits) solves.
    free_model = mujoco.MjModel.from_xml_string(xml.replace('limited="true"', 'limited="false"'))
    knee_l, knee_r = HINGE_NAMES.index("knee_l"), HINGE_NAMES.index("knee_r")
    lo = model.jnt_range[1:, 0]
    qpos = np.zeros((3, 40))
    qpos[:, 3] = 1.0
    qpos[:, 2] = 0.95
    qpos[:, 7 + knee_l] = lo[knee_l] - np.radians([10, 20, 30])
    qpos[:, 7 + knee_r] = lo[knee_r] - np.radians([10, 20, 30])
    names, sites, _ = _fk(free_model, qpos)
    fit = solve_skeleton(Trajectories(names, sites, np.arange(3) / 100.0), subject)
    angles = fit.joint_angles_rad
    assert np.all(angles >= model.jnt_range[1:, 0] - 1e-9) and np.all(angles <= model.jnt_range[1:, 1] + 1e-9)
    np.testing.assert_allclose(angles[:, knee_l], lo[knee_l], atol=np.radians(0.5))
    np.testing.assert_allclose(angles[:, knee_r], lo[knee_r], atol=np.radians(0.5))


def test_no_common_labels_is_a_clear_error(humanoid):
    _, _, subject = humanoid
    traj = Trajectories(["A", "B"], np.zeros((2, 2, 3)), [0.0, 0.01])
    with pytest.raises(MocapInputError, match="subject"):
        solve_skeleton(traj, subject)


def test_invalid_params_rejected():
    with pytest.raises(ValueError, match="min_markers"):
        IKParams(min_markers=0)
    with pytest.raises(ValueError, match="regularization_m_per_rad"):
        IKParams(regularization_m_per_rad=-1.0)


# ------------------------------------------------------------------------------ bridging
LEFT_LEG = ["LTHI", "LKNE", "LTIB", "LANK", "LHEE", "LTOE"]


def test_hidden_leg_is_bridged_across_its_gap(humanoid):
    """Every left-leg marker hidden for 6 frames of a 30 Hz motion: the per-frame fit holds the
    leg's hinges near their last values (its regularisation), the bridged fit interpolates
    them through the frames on both sides and follows the true swing."""
    _, model, subject = humanoid
    rng = np.random.default_rng(7)
    qpos = _smooth_motion(model, rng, n_frames=60, rate_hz=30.0, amplitude=0.5)
    names, sites, _ = _fk(model, qpos)
    xyz = sites + rng.normal(0, NOISE_M, sites.shape)
    gap = np.arange(25, 31)
    xyz[np.ix_(gap, [names.index(n) for n in LEFT_LEG])] = np.nan
    traj = Trajectories(names, xyz, np.arange(60) / 30.0)
    bridged = solve_skeleton(traj, subject)
    frozen = solve_skeleton(traj, subject, IKParams(bridge_max_frames=0))

    leg = [bridged.hinge_names.index(h) for h in ("hip_l_x", "hip_l_y", "knee_l", "ankle_l_y")]
    err_bridged = np.degrees(np.abs(bridged.joint_angles_rad[np.ix_(gap, leg)] - qpos[np.ix_(gap, [7 + j for j in leg])]))
    err_frozen = np.degrees(np.abs(frozen.joint_angles_rad[np.ix_(gap, leg)] - qpos[np.ix_(gap, [7 + j for j in leg])]))
    print(f"\nleft leg in the gap: bridged max {err_bridged.max():.2f} deg, held {err_frozen.max():.2f} deg")
    assert np.degrees(frozen.angle_std_rad[np.ix_(gap, leg)]).min() > 5.0      # the markers do not determine them
    assert err_bridged.max() < 2.0
    assert err_frozen.max() > 3 * err_bridged.max()
    # Outside the gap, and for every marker measured inside it, nothing changes.
    other = np.setdiff1d(np.arange(60), gap)
    np.testing.assert_array_equal(bridged.q[other], frozen.q[other])
    measured = np.isfinite(bridged.marker_errors_mm[gap])
    assert np.all(np.abs(bridged.marker_errors_mm[gap][measured] - frozen.marker_errors_mm[gap][measured]) <= 1.0)
    # The bridged frames keep their honest spread: still flagged as undetermined there.
    np.testing.assert_array_equal(bridged.angle_std_rad, frozen.angle_std_rad)


def test_bridge_interpolates_only_short_runs_between_determined_frames():
    """Known values: a hinge moving linearly is reproduced exactly across a short run (PCHIP is
    exact on lines); runs at the ends, longer runs and unsolved frames are left alone."""
    F = 40
    t = np.arange(F) / 30.0
    q = np.zeros((F, 9))
    q[:, 7] = 0.3 + 1.5 * t
    q[:, 8] = -0.2 + 0.5 * t
    std = np.full((F, 2), np.radians(0.5))
    std[10:14, 0] = np.radians(20.0)      # 4 undetermined frames between determined ones: bridged
    std[0:3, 1] = np.radians(20.0)        # at the start: not bridged
    std[20:35, 1] = np.radians(20.0)      # 15 frames, longer than 10: not bridged
    valid = np.ones(F, bool)
    valid[12] = False                     # an unsolved frame inside the run stays unsolved
    out = bridge_undetermined_hinges(q, std, valid, t, np.radians(5.0), max_frames=10)
    expected = np.full((F, 2), np.nan)
    expected[[10, 11, 13], 0] = q[[10, 11, 13], 7]
    np.testing.assert_allclose(out, expected, atol=1e-12)
    # With a longer limit the 15-frame run is bridged too.
    out = bridge_undetermined_hinges(q, std, valid, t, np.radians(5.0), max_frames=15)
    np.testing.assert_allclose(out[20:35, 1], q[20:35, 8], atol=1e-12)
    assert np.isnan(out[0:3, 1]).all()


def test_frame_whose_cold_start_failed_is_solved_again_from_the_next(humanoid):
    """A cold start that settles far off (here: the first frame's cold start handed the right arm
    turned 150 deg and one iteration) is solved again from the next frame's solution, which the
    warm-started frames reach: the first frame ends at the noise level and on the true pose,
    and frames that were right are not touched."""
    _, model, subject = humanoid
    rng = np.random.default_rng(11)
    qpos = _smooth_motion(model, rng, n_frames=12, rate_hz=30.0, amplitude=0.3)
    names, sites, _ = _fk(model, qpos)
    traj = Trajectories(names, sites + rng.normal(0, NOISE_M, sites.shape), np.arange(12) / 30.0)
    solver = SkeletonSolver(subject, IKParams(cold_start_iterations=1))
    arm = [7 + solver.tree.hinge_names.index(h) for h in ("shoulder_r_x", "shoulder_r_y", "shoulder_r_z")]
    calls = []

    def bad_first_cold_start(obs, ok):
        q0 = pinocchio_from_mujoco_q(qpos[0])
        if not calls:                    # only the first frame's: later restarts start right
            q0[arm] += np.radians(150.0)
        calls.append(1)
        return q0

    solver._cold_start = bad_first_cold_start
    fit = solver.solve(traj, bridge=False)
    err_deg = np.degrees(np.abs(fit.joint_angles_rad[0, [a - 7 for a in arm]] - qpos[0, arm]))
    print(f"\nframe 0 after the backward pass: {fit.marker_rms_mm[0]:.2f} mm RMS, right shoulder off by {err_deg.max():.2f} deg")
    assert fit.marker_rms_mm[0] < 2.0
    assert err_deg.max() < 2.0
    assert np.all(fit.marker_rms_mm < 2.0)
