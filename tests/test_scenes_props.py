"""Scene assembly, props physics and the simulation driver (kinematic humanoid)."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from simbench.scenes.humanoid import BODY_NAMES, NQ, BodyParams, joint_qpos_index, tpose_qpos
from simbench.scenes.props import BallProp, BarrierProp, MovingProp
from simbench.scenes.scene import build_scene
from simbench.scenes.simulation import simulate

PARAMS = BodyParams()
Q_T = tpose_qpos(PARAMS)


def _still(t: float) -> np.ndarray:
    return Q_T


def _ball_track(states, name="ball"):
    pos = states.prop_poses[name][:, :3, 3]
    vel = np.gradient(pos, states.times, axis=0)
    return pos, vel


def test_scene_layout_and_contacts():
    props = [BallProp(), BarrierProp(), MovingProp()]
    scene = build_scene(PARAMS, "sparse_joints", shirt=True, props=props)
    m = scene.model
    assert m.body("pelvis").id == 1 and m.jnt_qposadr[m.joint("root").id] == 0
    assert [scene.body_id(n) for n in BODY_NAMES] == list(range(1, 17))
    assert m.nq == NQ + 7 + 1  # ball free joint, mover slide; barrier welded
    assert scene.marker_names == [m_.name for m_ in scene.marker_specs] and len(scene.marker_specs) == 15
    assert [p.body for p in scene.surface_parts] == list(BODY_NAMES)
    assert any((p.face_patch >= 0).any() for p in scene.surface_parts)
    # humanoid below the floor (deep squat, feet through it): no humanoid-floor contact
    d = mujoco.MjData(m)
    d.qpos[:NQ] = Q_T
    d.qpos[2] = 0.2
    mujoco.mj_forward(m, d)
    floor = m.geom("floor").id
    humanoid_geoms = {m.geom(f"{b}_col").id for b in BODY_NAMES}
    pairs = {(c.geom1, c.geom2) for c in d.contact[: d.ncon]}
    assert not any(floor in p and (set(p) & humanoid_geoms) for p in pairs)
    with pytest.raises(ValueError, match="unique"):
        build_scene(PARAMS, None, props=[BallProp(), BallProp()])
    with pytest.raises(ValueError, match="thorax"):
        build_scene(PARAMS, None, props=[BallProp(name="thorax")])


def test_ball_hits_standing_humanoid_and_bounces():
    ball = BallProp(position=(2.0, 0.0, 1.3), velocity=(-5.0, 0.0, 1.0), radius_m=0.11)
    scene = build_scene(PARAMS, None, props=[ball])
    t = np.arange(0.0, 0.8, 0.002)
    st = simulate(scene, _still, t)
    pos, vel = _ball_track(st)
    i_hit = int(np.argmax(vel[:, 0] > 0))
    assert i_hit > 0, "the ball never came back"
    before, after = vel[i_hit - 10], vel[i_hit + 15]
    # the ball turned round at the front of the torso, not at the origin or behind it
    chest_front = st.body_xpos[0, scene.body_id("thorax"), 0] + 0.10
    print(f"ball: vx {before[0]:.2f} -> {after[0]:.2f} m/s at x = {pos[i_hit, 0]:.3f} m (t = {t[i_hit]:.3f} s)")
    assert before[0] < -4.5 and after[0] > 1.0
    assert pos[:, 0].min() > chest_front + ball.radius_m - 0.03
    # no energy from nowhere (a static body cannot speed the ball up)
    assert np.linalg.norm(after) < 1.05 * np.linalg.norm(before)
    # the humanoid did not move: kinematic drive
    np.testing.assert_array_equal(st.qpos[:, :NQ], np.broadcast_to(Q_T, (len(t), NQ)))


def test_ball_bounces_on_floor_with_its_restitution():
    for e in (0.5, 0.8):
        ball = BallProp(position=(3.0, 3.0, 1.0), velocity=(0.0, 0.0, 0.0), restitution=e, radius_m=0.1)
        scene = build_scene(PARAMS, None, props=[ball])
        st = simulate(scene, _still, np.arange(0.0, 1.6, 0.001))
        z = st.prop_poses["ball"][:, 2, 3]
        i_low = int(np.argmin(z[: len(z) // 2]))
        apex = z[i_low:].max() - 0.1
        drop = 1.0 - 0.1
        measured = np.sqrt(apex / drop)
        print(f"restitution {e}: bounce height {apex:.3f} m of {drop:.3f} m -> e = {measured:.3f}")
        assert measured == pytest.approx(e, abs=0.06)
        assert z.min() > 0.1 - 0.02  # penetration under 2 cm


def test_moving_arm_bats_the_ball():
    """A ball hanging in front of the left arm is batted forward by the arm's sweep: the
    contact sees the limb's velocity (finite differences of the kinematic drive)."""
    idx = joint_qpos_index(build_scene(PARAMS).model)

    def swing(t: float) -> np.ndarray:
        q = Q_T.copy()
        q[idx["shoulder_l_z"]] = 0.3 - 6.0 * t  # forward sweep at 6 rad/s
        return q

    ball = BallProp(position=(0.17, 0.62, 1.41), velocity=(0.0, 0.0, 0.0), radius_m=0.06)
    scene = build_scene(PARAMS, None, props=[ball])
    t = np.arange(0.0, 0.3, 0.001)
    st = simulate(scene, swing, t)
    pos, vel = _ball_track(st)
    # speed of the arm's surface at the ball's distance from the shoulder
    arm_speed = 6.0 * np.linalg.norm(np.array(ball.position[:2]) - st.body_xpos[0, scene.body_id("upperarm_l"), :2])
    print(f"arm surface speed {arm_speed:.2f} m/s; ball vx after {vel[-1, 0]:.2f} m/s")
    assert vel[-1, 0] > arm_speed  # batted away faster than the arm moves
    assert vel[-1, 0] < 2.2 * arm_speed


def test_barrier_is_static_and_stops_the_ball():
    barrier = BarrierProp(size_m=(0.05, 1.0, 1.2), position=(-1.5, 0.0, 0.6), yaw_deg=30.0)
    ball = BallProp(position=(-0.5, 0.0, 0.6), velocity=(-4.0, 0.0, 1.0), radius_m=0.1)
    scene = build_scene(PARAMS, None, props=[barrier, ball])
    st = simulate(scene, _still, np.linspace(0.0, 1.0, 101))
    poses = st.prop_poses["barrier"]
    np.testing.assert_array_equal(poses, np.broadcast_to(poses[0], poses.shape))
    np.testing.assert_allclose(poses[0], barrier.pose(), atol=1e-12)
    assert poses[0][0, 0] == pytest.approx(np.cos(np.deg2rad(30.0)))
    pos, vel = _ball_track(st)
    assert pos[:, 0].min() > -1.5 - 0.1  # did not go through
    assert vel[-1, 0] > 0.0
    np.testing.assert_allclose(barrier.mesh().extents, barrier.size_m)


def test_mover_keeps_its_velocity():
    mover = MovingProp(size_m=(0.3, 0.2, 0.4), start=(1.0, -2.0, 1.0), velocity=(0.3, 1.5, 0.2))
    scene = build_scene(PARAMS, None, props=[mover])
    t = np.array([0.0, 0.0125, 0.5, 1.3337, 2.0])
    st = simulate(scene, _still, t)
    expected = np.asarray(mover.start) + t[:, None] * np.asarray(mover.velocity)
    np.testing.assert_allclose(st.prop_poses["mover"][:, :3, 3], expected, atol=1e-6)
    np.testing.assert_allclose(st.prop_poses["mover"][:, :3, :3], np.broadcast_to(np.eye(3), (5, 3, 3)), atol=1e-12)


_IDX = joint_qpos_index(mujoco.MjModel.from_xml_string(build_scene(PARAMS).mjcf_xml))


def _motion(t):
    """Walk forward waving both arms; works for one time (40,) or many (n, 40)."""
    t = np.asarray(t, dtype=np.float64)
    q = np.broadcast_to(Q_T, t.shape + (NQ,)).copy()
    q[..., 0] = 0.3 * t
    q[..., _IDX["shoulder_l_x"]] = -1.2 * np.sin(3.0 * t)
    q[..., _IDX["shoulder_r_x"]] = 1.2 * np.sin(3.0 * t)
    return q


def test_simulate_is_deterministic_and_sampling_independent():
    props = [BallProp(position=(2.0, 0.2, 1.2), velocity=(-5.0, 0.0, 1.5)), MovingProp(), BarrierProp(position=(0.0, 2.5, 0.6))]
    scene = build_scene(PARAMS, "plugin_gait_full", props=props)
    rng = np.random.default_rng(3)
    t = np.sort(rng.uniform(0.0, 1.2, 40))
    a = simulate(scene, _motion, t)
    b = simulate(scene, _motion, t)
    for field in ("times", "qpos", "body_xpos", "body_xmat", "marker_xpos", "joint_centres"):
        np.testing.assert_array_equal(getattr(a, field), getattr(b, field))
    for name in a.prop_poses:
        np.testing.assert_array_equal(a.prop_poses[name], b.prop_poses[name])
    # asking for more (sub-frame) instants does not change the states at the others
    dense = np.sort(np.concatenate([t, rng.uniform(0.0, 1.2, 60)]))
    c = simulate(scene, _motion, dense)
    keep = np.searchsorted(dense, t)
    np.testing.assert_array_equal(c.qpos[keep], a.qpos)
    np.testing.assert_array_equal(c.prop_poses["ball"][keep], a.prop_poses["ball"])
    # a motion that takes one time at a time gives the very same states (the batched
    # evaluation of the physics grid is an optimisation only)
    d = simulate(scene, lambda x: _motion(float(x)), t)
    np.testing.assert_array_equal(d.qpos, a.qpos)
    np.testing.assert_array_equal(d.body_xpos, a.body_xpos)
    # the humanoid is exactly where the motion puts it, markers and joints follow
    np.testing.assert_array_equal(a.qpos[:, :NQ], np.stack([_motion(x) for x in t]))
    assert a.marker_xpos.shape == (len(t), 39, 3) and a.joint_centres.shape == (len(t), 16, 3)
    m = mujoco.MjModel.from_xml_string(scene.humanoid_mjcf())
    d = mujoco.MjData(m)
    for i in (0, len(t) // 2, len(t) - 1):
        d.qpos[:] = _motion(t[i])
        mujoco.mj_kinematics(m, d)
        np.testing.assert_allclose(a.joint_centres[i], d.xpos[1:17], atol=1e-12)
        sites = [m.site(n).id for n in a.marker_names]  # MJCF sites are in body order
        np.testing.assert_allclose(a.marker_xpos[i], d.site_xpos[sites], atol=1e-12)


def test_simulate_rejects_bad_input():
    scene = build_scene(PARAMS, None, props=[BallProp()])
    with pytest.raises(ValueError, match="increasing"):
        simulate(scene, _still, [0.0, 0.2, 0.1])
    with pytest.raises(ValueError, match="t = 0"):
        simulate(scene, _still, [-0.1, 0.2])
    with pytest.raises(ValueError, match="40"):
        simulate(scene, lambda t: np.zeros(39), [0.0, 0.1])
    with pytest.raises(ValueError, match="radius_m"):
        BallProp(radius_m=-1.0)
    with pytest.raises(ValueError, match="size_m"):
        BarrierProp(size_m=(0.0, 1.0, 1.0))
