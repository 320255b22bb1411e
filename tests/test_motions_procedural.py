"""Procedural clips: continuity, joint limits, T-pose start, feet on the floor, and character.

Joint centres come from MuJoCo forward kinematics of the humanoid (body origins); joint
ranges are read from a MuJoCo model built here from the MJCF, independently of the motion
code.
"""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from simbench.scenes.humanoid import BODY_NAMES, HINGE_NAMES, BodyParams, humanoid_mjcf, tpose_qpos
from simbench.scenes.motions import MOTIONS, T_POSE_BLEND_S, T_POSE_HOLD_S, HumanoidKinematics, Motion, make_motion

FPS = 240.0
DURATION_S = 6.0
SETTLED_S = T_POSE_HOLD_S + T_POSE_BLEND_S + 0.2  # after the blend from the T-pose
PARAMS = BodyParams()
B = {name: i for i, name in enumerate(BODY_NAMES)}


@pytest.fixture(scope="module")
def model() -> mujoco.MjModel:
    return mujoco.MjModel.from_xml_string(humanoid_mjcf(PARAMS))


@pytest.fixture(scope="module")
def kin() -> HumanoidKinematics:
    return HumanoidKinematics(PARAMS)


@pytest.fixture(scope="module")
def clips(kin):
    """name -> (times (F,), qpos (F, 40), body positions (F, 16, 3), body rotations (F, 16, 3, 3))."""
    out = {}
    for name in MOTIONS:
        t, q = make_motion(name, PARAMS, DURATION_S).sample(FPS)
        pos, rot = kin.forward(q)
        out[name] = (t, q, pos, rot)
    return out


def _speed(p: np.ndarray, fps: float) -> np.ndarray:
    return np.linalg.norm(np.diff(p, axis=0), axis=1) * fps


def _reversals_per_s(p: np.ndarray, fps: float) -> float:
    """Direction reversals per second along the main axis of a point's path ``(F, 3)``."""
    centred = p - p.mean(axis=0)
    axis = np.linalg.svd(centred, full_matrices=False)[2][0]
    velocity = np.diff(centred @ axis)
    return float(np.sum(np.diff(np.sign(velocity)) != 0) / (len(p) / fps))


def _head_top(pos, rot, model) -> np.ndarray:
    """Vertex of the head ``(F,)`` z: head origin plus the head length along the head's z axis."""
    data = mujoco.MjData(model)
    data.qpos[:] = tpose_qpos(PARAMS)
    mujoco.mj_kinematics(model, data)
    head_len = PARAMS.height_m - data.xpos[model.body("head").id][2]
    return pos[:, B["head"], 2] + head_len * rot[:, B["head"], 2, 2]


def _count_rising(flags: np.ndarray) -> int:
    return int(np.sum(flags[1:] & ~flags[:-1]) + flags[0])


def test_registry_lists_the_required_clips():
    required = {"tpose", "wave_slow", "zigzag_fast", "swing_accelerating", "jumping_jacks", "squash_forehand", "walk_in_place"}
    assert required <= set(MOTIONS)
    assert all(MOTIONS[n].description for n in MOTIONS)


@pytest.mark.parametrize("name", sorted(MOTIONS))
def test_clip_is_finite_continuous_and_within_joint_ranges(name, clips, model):
    t, q, _, _ = clips[name]
    assert np.all(np.isfinite(q))
    assert q.shape == (len(t), model.nq)
    np.testing.assert_allclose(np.linalg.norm(q[:, 3:7], axis=1), 1.0, atol=1e-12)
    lo, hi = model.jnt_range[[model.joint(n).id for n in HINGE_NAMES]].T
    hinges = q[:, 7:]
    assert np.all(hinges >= lo - 1e-12) and np.all(hinges <= hi + 1e-12)
    # continuity: no hinge moves more than 0.05 rad in 1/240 s (12 rad/s) ...
    step = np.abs(np.diff(hinges, axis=0)).max()
    assert step < 0.05, step
    # ... and C1: the per-sample change itself changes smoothly (no velocity jumps).
    accel = np.abs(np.diff(hinges, n=2, axis=0)).max()
    assert accel < 0.01, accel
    assert np.abs(np.diff(q[:, :3], axis=0)).max() < 0.01


@pytest.mark.parametrize("name", sorted(MOTIONS))
def test_clip_starts_in_the_t_pose_with_feet_on_the_floor(name, clips, kin):
    t, q, _, _ = clips[name]
    np.testing.assert_allclose(q[0], tpose_qpos(PARAMS), atol=1e-12)  # humanoid module's own T-pose
    near_start = (t <= 0.3)
    assert np.abs(q[near_start, 7:]).max() < 0.25  # within ~14 deg of the T-pose for 0.3 s
    sole_z = kin.sole_points(q)[:, :, 2].min(axis=1)
    if name == "jumping_jacks":
        assert abs(sole_z.min()) < 0.003
        assert sole_z.max() > 0.03  # hops
    else:
        np.testing.assert_allclose(sole_z, 0.0, atol=0.005)


def test_tpose_is_static(clips):
    _, q, _, _ = clips["tpose"]
    np.testing.assert_array_equal(q, np.broadcast_to(q[0], q.shape))


def test_zigzag_is_much_faster_and_turns_more_often_than_wave(clips):
    out = {}
    for name in ("wave_slow", "zigzag_fast"):
        t, _, pos, _ = clips[name]
        wrist = pos[t >= SETTLED_S, B["hand_l"]]
        out[name] = (_speed(wrist, FPS).max(), _reversals_per_s(wrist, FPS))
    (wave_speed, wave_rev), (zig_speed, zig_rev) = out["wave_slow"], out["zigzag_fast"]
    print(f"wrist peak speed: wave {wave_speed:.2f} m/s, zigzag {zig_speed:.2f} m/s; "
          f"reversals: wave {wave_rev:.2f}/s, zigzag {zig_rev:.2f}/s")
    assert 0.2 < wave_speed < 1.0  # slow but visibly waving
    assert zig_speed > 4.0 * wave_speed
    assert zig_rev >= 3.0 and zig_rev > 2.5 * wave_rev


def test_wave_slow_waves_one_hand_above_the_shoulder_and_relaxes_the_other(clips):
    t, _, pos, _ = clips["wave_slow"]
    settled = t >= SETTLED_S
    shoulder_z = pos[settled, B["upperarm_l"], 2]
    assert np.all(pos[settled, B["hand_l"], 2] > shoulder_z + 0.15)
    assert np.all(pos[settled, B["hand_r"], 2] < pos[settled, B["pelvis"], 2])  # hanging down
    assert _speed(pos[settled, B["hand_r"]], FPS).max() < 0.1
    assert 0.8 < _reversals_per_s(pos[settled, B["hand_l"]], FPS) < 2.0  # a slow wave (~0.6 Hz)


def test_swing_accelerating_speeds_up(clips):
    t, _, pos, _ = clips["swing_accelerating"]
    speed = _speed(pos[:, B["hand_r"]], FPS)
    early = speed[(t[1:] >= SETTLED_S) & (t[1:] < SETTLED_S + 1.0)].max()
    late = speed[t[1:] >= DURATION_S - 1.0].max()
    print(f"right wrist peak speed: early {early:.2f} m/s, late {late:.2f} m/s")
    assert late > 1.6 * early
    # the swing period shrinks: reversals along the swing axis are more frequent late
    assert _reversals_per_s(pos[t >= DURATION_S - 2.0, B["hand_r"]], FPS) > 1.5 * _reversals_per_s(
        pos[(t >= SETTLED_S) & (t < SETTLED_S + 2.0), B["hand_r"]], FPS
    )


def test_jumping_jacks_raise_both_wrists_above_the_head_once_per_cycle(clips, model):
    t, _, pos, rot = clips["jumping_jacks"]
    top = _head_top(pos, rot, model)
    above = (pos[:, B["hand_l"], 2] > top) & (pos[:, B["hand_r"], 2] > top)
    cycles = _count_rising(above)
    print(f"jumping_jacks: {cycles} cycles with both wrists above the head in {DURATION_S} s")
    assert cycles in (5, 6)  # 1 Hz after the blend-in
    feet_apart = pos[:, B["foot_l"], 1] - pos[:, B["foot_r"], 1]
    hip_width = pos[0, B["thigh_l"], 1] - pos[0, B["thigh_r"], 1]
    assert feet_apart.max() > 1.8 * hip_width  # legs open


def test_walk_in_place_marches_without_travelling(clips, kin):
    t, q, pos, _ = clips["walk_in_place"]
    assert np.linalg.norm(q[:, :2] - q[0, :2], axis=1).max() < 0.3
    settled = t >= SETTLED_S
    sole = kin.sole_points(q)[:, :, 2]
    lift_l, lift_r = sole[settled, :4].min(axis=1), sole[settled, 4:].min(axis=1)
    assert lift_l.max() > 0.1 and lift_r.max() > 0.1
    assert np.all(np.minimum(lift_l, lift_r) < 0.005)  # always one foot on the floor
    steps_l = _count_rising(lift_l > 0.05)
    steps_r = _count_rising(lift_r > 0.05)
    assert abs(steps_l - steps_r) <= 1 and steps_l >= 3
    # arms counter-swing: the left wrist is forward while the right knee is up
    right_up = lift_r > 0.1
    assert np.mean(pos[settled, B["hand_l"], 0][right_up] > pos[settled, B["hand_r"], 0][right_up]) > 0.95


def test_squash_forehand_rotates_the_trunk_and_swings_the_racket_arm_across(clips):
    t, _, pos, rot = clips["squash_forehand"]
    settled = t >= SETTLED_S
    thorax_x = rot[settled, B["thorax"], :, 0]
    yaw = np.degrees(np.arctan2(thorax_x[:, 1], thorax_x[:, 0]))
    assert yaw.max() - yaw.min() > 60.0
    # right wrist relative to the pelvis: back behind the body, then forward across it
    rel = pos[settled, B["hand_r"]] - pos[settled, B["pelvis"]]
    assert rel[:, 0].min() < -0.2 and rel[:, 0].max() > 0.3
    assert rel[:, 1].max() > 0.0  # crosses the midline in the follow-through
    speed = _speed(pos[settled, B["hand_r"]], FPS)
    assert speed.max() > 5.0 and speed.max() > 3.0 * np.median(speed)  # a fast stroke, not a steady sweep


def test_qpos_accepts_scalars_arrays_and_holds_outside_the_clip():
    m = make_motion("wave_slow", PARAMS, 2.0)
    assert m.qpos(0.5).shape == (40,)
    assert m.qpos(np.zeros((3, 4))).shape == (3, 4, 40)
    np.testing.assert_array_equal(m.qpos(5.0), m.qpos(2.0))
    np.testing.assert_array_equal(m.qpos(-1.0), m.qpos(0.0))
    times, q = m.sample(30.0)
    assert len(times) == 61 and times[-1] == pytest.approx(2.0)
    np.testing.assert_array_equal(q, m.qpos(times))
    with pytest.raises(ValueError, match="finite"):
        m.qpos(np.nan)


def test_variation_is_drawn_from_the_given_generator_only():
    a = make_motion("walk_in_place", PARAMS, 3.0, rng=np.random.default_rng(7)).qpos(np.linspace(0, 3, 50))
    b = make_motion("walk_in_place", PARAMS, 3.0, rng=np.random.default_rng(7)).qpos(np.linspace(0, 3, 50))
    c = make_motion("walk_in_place", PARAMS, 3.0, rng=np.random.default_rng(8)).qpos(np.linspace(0, 3, 50))
    d = make_motion("walk_in_place", PARAMS, 3.0).qpos(np.linspace(0, 3, 50))
    np.testing.assert_array_equal(a, b)
    assert np.abs(a - c).max() > 0.01 and np.abs(a - d).max() > 0.01
    np.testing.assert_array_equal(d, make_motion("walk_in_place", PARAMS, 3.0).qpos(np.linspace(0, 3, 50)))


@pytest.mark.parametrize("height_m", [1.5, 2.0])
def test_other_body_sizes_stand_on_the_floor(height_m):
    params = BodyParams(height_m=height_m)
    kin = HumanoidKinematics(params)
    m = make_motion("walk_in_place", params, 3.0)
    q = m.qpos(np.linspace(0.0, 3.0, 200))
    assert q[0, 2] == pytest.approx(tpose_qpos(params)[2], abs=1e-9)
    sole = kin.sole_points(q)[:, :, 2].min(axis=1)
    np.testing.assert_allclose(sole, 0.0, atol=0.005)


def test_bad_requests_name_the_allowed_values():
    with pytest.raises(ValueError, match="wave_slow"):
        make_motion("moonwalk", PARAMS, 2.0)
    with pytest.raises(ValueError, match="duration_s"):
        make_motion("tpose", PARAMS, 0.0)


def test_from_samples_interpolates_keys_smoothly_and_clamps(kin):
    times = np.arange(5) / 120.0
    q = np.tile(tpose_qpos(PARAMS), (5, 1))
    elbow = 7 + HINGE_NAMES.index("elbow_l")
    q[:, elbow] = [-0.1, -0.2, -0.4, -0.5, -3.5]  # the last is beyond the -2.6 limit
    q[:, 0] = np.linspace(0.0, 0.04, 5)
    m = Motion.from_samples("keys", times, q, kin)
    np.testing.assert_allclose(m.qpos(times[:4])[:, elbow], q[:4, elbow], atol=1e-12)
    assert m.qpos(times[4])[elbow] == pytest.approx(kin.hinge_range("elbow_l")[0])
    mid = m.qpos(0.5 * (times[1] + times[2]))[elbow]
    assert -0.4 < mid < -0.2  # monotone between keys (no overshoot)
    assert m.duration_s == pytest.approx(times[-1])


def test_from_samples_keeps_the_root_quaternion_continuous_through_a_full_turn(kin):
    times = np.linspace(0.0, 2.0, 41)
    q = np.tile(tpose_qpos(PARAMS), (41, 1))
    yaw = np.linspace(0.0, 2.5 * np.pi, 41)  # w = cos(yaw / 2) changes sign
    q[:, 3], q[:, 6] = np.cos(yaw / 2), np.sin(yaw / 2)
    q[20:, 3:7] *= -1.0  # keys with arbitrary signs
    fine = Motion.from_samples("turn", times, q, kin).qpos(np.linspace(0.0, 2.0, 801))
    steps = np.sum(fine[1:, 3:7] * fine[:-1, 3:7], axis=1)
    assert steps.min() > np.cos(0.02)  # < 0.04 rad per step and never a sign flip
    turned = np.unwrap(2.0 * np.arctan2(fine[:, 6], fine[:, 3]))
    np.testing.assert_allclose(turned[-1] - turned[0], 2.5 * np.pi, atol=1e-9)
