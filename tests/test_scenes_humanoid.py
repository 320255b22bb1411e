"""Humanoid MJCF: MuJoCo vs Pinocchio kinematics, T-pose geometry, body proportions."""

from __future__ import annotations

import mujoco
import numpy as np
import pinocchio as pin
import pytest
from scipy.spatial.transform import Rotation

from simbench.scenes.anthropometry import body_dimensions
from simbench.scenes.humanoid import (
    BODY_NAMES,
    HINGE_NAMES,
    NQ,
    BodyParams,
    humanoid_mjcf,
    joint_qpos_index,
    joint_ranges,
    mujoco_to_pinocchio_q,
    pinocchio_to_mujoco_q,
    tpose_qpos,
)


def _models(params: BodyParams, tmp_path, marker_set=None):
    xml = humanoid_mjcf(params, marker_set)
    path = tmp_path / "humanoid.xml"
    path.write_text(xml)
    return mujoco.MjModel.from_xml_string(xml), pin.buildModelFromMJCF(str(path))


def _random_qpos(rng: np.random.Generator, model: mujoco.MjModel, n: int) -> np.ndarray:
    lo, hi = model.jnt_range[1:, 0], model.jnt_range[1:, 1]
    q = np.zeros((n, model.nq))
    q[:, :3] = rng.uniform(-2.0, 2.0, size=(n, 3))
    quat = rng.normal(size=(n, 4))
    q[:, 3:7] = quat / np.linalg.norm(quat, axis=1, keepdims=True)
    q[:, 7:] = rng.uniform(lo, hi, size=(n, len(lo)))
    return q


def test_names_and_order():
    assert len(HINGE_NAMES) == 33 and NQ == 40
    m = mujoco.MjModel.from_xml_string(humanoid_mjcf(BodyParams()))
    assert [m.body(i).name for i in range(1, m.nbody)] == list(BODY_NAMES)
    idx = joint_qpos_index(m)
    assert idx["root"] == 0
    assert [idx[n] for n in HINGE_NAMES] == list(range(7, 40))
    assert m.jnt_limited[1:].all()
    rng = joint_ranges()
    for j, name in enumerate(HINGE_NAMES):
        assert tuple(m.jnt_range[j + 1]) == pytest.approx(rng[name])
        # the T-pose (all zeros) lies inside every range
        assert m.jnt_range[j + 1, 0] <= 0.0 <= m.jnt_range[j + 1, 1], name


@pytest.mark.parametrize("height", [1.55, 1.95])
def test_mujoco_pinocchio_fk_agree(height, tmp_path):
    params = BodyParams(height_m=height, mass_kg=50.0 + 20.0 * (height - 1.5))
    m, pm = _models(params, tmp_path, marker_set="plugin_gait_full")
    pd = pm.createData()
    d = mujoco.MjData(m)

    # joint ordering by name: Pinocchio groups a body's hinges into one composite joint
    # named after its first hinge; its q block must start at that hinge's MuJoCo qpos
    # address and span exactly the body's hinges.
    idx = joint_qpos_index(m)
    covered = []
    for j in range(1, pm.njoints):
        name = pm.names[j].removeprefix("Composite_")
        if name == "root":
            assert pm.idx_qs[j] == 0 and pm.nqs[j] == 7
            continue
        assert pm.idx_qs[j] == idx[name], name
        body = m.body(m.jnt_bodyid[m.joint(name).id])
        assert pm.nqs[j] == body.jntnum[0], name
        covered.extend(range(pm.idx_qs[j], pm.idx_qs[j] + pm.nqs[j]))
    assert sorted(covered) == list(range(7, 40))

    frame_ids = [pm.getFrameId(b, pin.BODY) for b in BODY_NAMES]
    body_ids = [m.body(b).id for b in BODY_NAMES]
    site_names = [m.site(i).name for i in range(m.nsite)]
    assert len(site_names) == 39
    site_frames = [pm.getFrameId(n) for n in site_names]
    q_all = _random_qpos(np.random.default_rng(7), m, 200)
    worst_pos, worst_rot = 0.0, 0.0
    for q in q_all:
        d.qpos[:] = q
        mujoco.mj_kinematics(m, d)
        qp = mujoco_to_pinocchio_q(q)
        pin.framesForwardKinematics(pm, pd, qp)
        for f, b in zip(frame_ids, body_ids):
            worst_pos = max(worst_pos, np.abs(pd.oMf[f].translation - d.xpos[b]).max())
            worst_rot = max(worst_rot, np.abs(pd.oMf[f].rotation - d.xmat[b].reshape(3, 3)).max())
        for i, f in enumerate(site_frames):  # marker sites become Pinocchio frames
            worst_pos = max(worst_pos, np.abs(pd.oMf[f].translation - d.site_xpos[i]).max())
    print(f"height {height}: max |dpos| = {worst_pos:.2e} m, max |dR| = {worst_rot:.2e}")
    assert worst_pos < 1e-9
    assert worst_rot < 1e-9
    np.testing.assert_array_equal(pinocchio_to_mujoco_q(mujoco_to_pinocchio_q(q_all)), q_all)


def _tpose_world(params):
    m = mujoco.MjModel.from_xml_string(humanoid_mjcf(params))
    d = mujoco.MjData(m)
    d.qpos[:] = tpose_qpos(params)
    mujoco.mj_kinematics(m, d)
    return m, d


def test_hinge_convention_matches_contract():
    """3-DoF joints compose as Rx @ Ry @ Rz (scipy intrinsic XYZ), right-hand rule."""
    params = BodyParams()
    m, d = _tpose_world(params)
    angles = np.array([0.3, -0.7, 0.5])
    idx = joint_qpos_index(m)
    d.qpos[[idx["shoulder_l_x"], idx["shoulder_l_y"], idx["shoulder_l_z"]]] = angles
    mujoco.mj_kinematics(m, d)
    R_rel = d.xmat[m.body("thorax").id].reshape(3, 3).T @ d.xmat[m.body("upperarm_l").id].reshape(3, 3)
    np.testing.assert_allclose(R_rel, Rotation.from_euler("XYZ", angles).as_matrix(), atol=1e-12)
    # left elbow flexion (negative) brings the left hand forward (+X)
    d.qpos[:] = tpose_qpos(params)
    d.qpos[idx["elbow_l"]] = -np.pi / 2
    d.qpos[idx["elbow_r"]] = +np.pi / 2
    mujoco.mj_kinematics(m, d)
    for side in "lr":
        hand = d.xpos[m.body(f"hand_{side}").id] - d.xpos[m.body(f"forearm_{side}").id]
        assert hand[0] > 0.95 * np.linalg.norm(hand)
    # arms down: left shoulder_x = -pi/2, right = +pi/2; hip flexion (hip_y < 0) moves the knee forward
    d.qpos[:] = tpose_qpos(params)
    d.qpos[idx["shoulder_l_x"]] = -np.pi / 2
    d.qpos[idx["shoulder_r_x"]] = +np.pi / 2
    d.qpos[idx["hip_l_y"]] = -0.5
    mujoco.mj_kinematics(m, d)
    for side in "lr":
        elbow = d.xpos[m.body(f"forearm_{side}").id] - d.xpos[m.body(f"upperarm_{side}").id]
        assert elbow[2] < -0.99 * np.linalg.norm(elbow)
    knee = d.xpos[m.body("shank_l").id] - d.xpos[m.body("thigh_l").id]
    assert knee[0] > 0.4 * np.linalg.norm(knee)


@pytest.mark.parametrize("height", [1.55, 1.75, 1.95])
def test_tpose_geometry(height):
    params = BodyParams(height_m=height)
    dims = body_dimensions(params)
    m, d = _tpose_world(params)
    pos = {b: d.xpos[m.body(b).id].copy() for b in BODY_NAMES}
    # every body frame is world-aligned in the T-pose
    for b in BODY_NAMES:
        np.testing.assert_allclose(d.xmat[m.body(b).id].reshape(3, 3), np.eye(3), atol=1e-12)
    # feet flat on the floor: the bottom of the foot boxes at z = 0
    for side in "lr":
        g = m.geom(f"foot_{side}_col")
        bottom = d.geom_xpos[g.id][2] - m.geom_size[g.id][2]
        assert abs(bottom) < 2e-3
    # the head reaches the stated height (vertex = neck joint + head length)
    assert pos["head"][2] + dims.head == pytest.approx(height, abs=1e-9)
    # arms horizontal along +Y (left) and -Y (right), at shoulder height
    for side, sign in (("l", 1), ("r", -1)):
        chain = np.array([pos[f"upperarm_{side}"], pos[f"forearm_{side}"], pos[f"hand_{side}"]])
        np.testing.assert_allclose(chain[:, 2], chain[0, 2], atol=1e-12)
        np.testing.assert_allclose(chain[:, 0], 0.0, atol=1e-12)
        assert (np.sign(np.diff(chain[:, 1])) == sign).all()
    # fingertip-to-fingertip span is about the height (Vitruvian ratio ~1.0 to 1.06)
    span = (pos["hand_l"][1] + dims.hand) - (pos["hand_r"][1] - dims.hand)
    print(f"height {height} m: hand span {span:.3f} m, ratio {span / height:.3f}")
    assert 0.98 * height < span < 1.07 * height
    # facing +X: toes ahead of the ankles
    for side in "lr":
        g = m.geom(f"foot_{side}_col")
        assert d.geom_xpos[g.id][0] > pos[f"foot_{side}"][0]


def test_segment_lengths_follow_params():
    for height, thigh_frac in ((1.55, 0.245), (1.95, 0.26)):
        params = BodyParams(height_m=height, thigh_frac=thigh_frac)
        m, d = _tpose_world(params)
        p = {b: d.xpos[m.body(b).id] for b in BODY_NAMES}
        assert np.linalg.norm(p["thigh_l"] - p["shank_l"]) == pytest.approx(thigh_frac * height, abs=1e-12)
        assert np.linalg.norm(p["shank_r"] - p["foot_r"]) == pytest.approx(0.246 * height, abs=1e-12)
        assert np.linalg.norm(p["upperarm_l"] - p["forearm_l"]) == pytest.approx(0.172 * height, abs=1e-12)
        assert np.linalg.norm(p["forearm_r"] - p["hand_r"]) == pytest.approx(0.146 * height, abs=1e-12)
        assert p["foot_l"][2] == pytest.approx(0.039 * height, abs=1e-12)
        assert np.linalg.norm(p["thigh_l"] - p["thigh_r"]) == pytest.approx(0.10 * height, abs=1e-12)
        # total height stays exact whatever the proportions (the head takes the rest)
        assert p["head"][2] + body_dimensions(params).head == pytest.approx(height, abs=1e-12)
    total = mujoco.MjModel.from_xml_string(humanoid_mjcf(BodyParams(mass_kg=80.0))).body_subtreemass[1]
    assert total == pytest.approx(80.0, rel=1e-9)  # Winter's segment mass fractions sum to 1


def test_bad_params_raise_clear_errors():
    with pytest.raises(ValueError, match="height_m"):
        BodyParams(height_m=175.0)
    with pytest.raises(ValueError, match="head"):
        BodyParams(thorax_frac=0.4)
    with pytest.raises(ValueError, match="q_mj"):
        mujoco_to_pinocchio_q(np.zeros(39))
