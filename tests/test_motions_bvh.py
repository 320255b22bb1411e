"""BVH parsing and retargeting onto the humanoid, on the six shared CMU clips (three cgspeed
MotionBuilder/3dsMax-friendly, three Daz/Poser-friendly) and on small hand-written files whose
forward kinematics is known.

Joint centres of the humanoid come from MuJoCo forward kinematics (body origins); the BVH's
own joint positions come from its forward kinematics, brought into the bench world with the
scale and rotation the retargeting reports.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from mocap.errors import InputFileError
from simbench.scenes.bvh import retarget_bvh, retarget_bvh_keys
from simbench.scenes.bvh_file import load_bvh
from simbench.scenes.bvh_mapping import map_bvh_joints
from simbench.scenes.humanoid import BODY_NAMES, HINGE_NAMES, BodyParams
from simbench.scenes.motions import HumanoidKinematics, make_motion

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "bvh"
WALK = DATA / "131_01.bvh"
JACKS = DATA / "13_29_jumping_jacks_frames0-599.bvh"
HOPS = DATA / "01_01.bvh"
SALSA = DATA / "60_10_salsa_daz.bvh"
KICK = DATA / "135_04_front_kick_daz.bvh"
DANCE = DATA / "94_15_indian_dance_daz.bvh"
ALL_CLIPS = [WALK, JACKS, HOPS, SALSA, KICK, DANCE]
DAZ_CLIPS = [SALSA, KICK, DANCE]
PARAMS = BodyParams()
B = {name: i for i, name in enumerate(BODY_NAMES)}
LIMB_SEGMENTS = [
    ("upperarm_l", "forearm_l"), ("forearm_l", "hand_l"), ("upperarm_r", "forearm_r"), ("forearm_r", "hand_r"),
    ("thigh_l", "shank_l"), ("shank_l", "foot_l"), ("thigh_r", "shank_r"), ("shank_r", "foot_r"),
]


def _retargeted(path: Path):
    """The clip, its retargeted keys and their body positions and rotations."""
    clip = load_bvh(path)
    keys = retarget_bvh_keys(clip, PARAMS)
    pos, rot = keys.kinematics.forward(keys.qpos)
    return clip, keys, pos, rot


@pytest.fixture(scope="module")
def walk():
    return _retargeted(WALK)


@pytest.fixture(scope="module")
def jacks():
    return _retargeted(JACKS)


# ----------------------------------------------------------------------------- parsing


def test_cmu_files_parse_with_their_channel_layouts():
    walk, jacks = load_bvh(WALK), load_bvh(JACKS)
    assert (walk.n_frames, walk.frames.shape[1], walk.n_joints) == (994, 96, 31)  # mixed CRLF/LF file
    assert (jacks.n_frames, jacks.frames.shape[1], jacks.n_joints) == (600, 96, 31)
    assert walk.frame_time_s == pytest.approx(1 / 120, rel=1e-3)
    assert walk.channels[0] == ("Xposition", "Yposition", "Zposition", "Zrotation", "Yrotation", "Xrotation")
    assert walk.channels[walk.joint_index("LeftElbow")] == ("Zrotation", "Xrotation", "Yrotation")
    assert walk.channels[walk.joint_index("LeftKnee")] == ("Zrotation", "Yrotation", "Xrotation")
    np.testing.assert_allclose(walk.offsets[walk.joint_index("LeftElbow")], [0.0, -4.25106, 0.0])
    assert len(walk.end_site_parents) == 7
    np.testing.assert_allclose(walk.frames[0, :3], [5.2300, 16.9002, -33.8986])
    np.testing.assert_allclose(jacks.frames[0, :3], [-0.0035, 15.8971, 2.2953])
    assert "LeftUpLeg" in jacks.joint_names and "LeftHip" in walk.joint_names


_SMALL = """HIERARCHY
ROOT hips
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Yrotation Xrotation Zrotation
  JOINT arm
  {
    OFFSET 1 2 0
    CHANNELS 6 Xposition Yposition Zposition Xrotation Zrotation Yrotation
    JOINT hand
    {
      OFFSET 0 3 0
      CHANNELS 3 Zrotation Xrotation Yrotation
      End Site
      {
        OFFSET 0 0 1
      }
    }
  }
}
MOTION
Frames: 2
Frame Time: 0.04
1 2 3 90 0 0 0.5 2 0 0 90 0 0 0 0
0 0 0 0 0 0 1 2 0 0 0 0 30 40 50
"""


def _write(tmp_path: Path, text: str, newline: str = "\n", name: str = "clip.bvh") -> Path:
    path = tmp_path / name
    path.write_bytes(text.replace("\n", newline).encode())
    return path


@pytest.mark.parametrize("newline", ["\n", "\r\n", "\r"])
def test_forward_kinematics_of_a_small_file_matches_hand_computation(tmp_path, newline):
    clip = load_bvh(_write(tmp_path, _SMALL, newline))
    assert clip.joint_names == ("hips", "arm", "hand")
    assert clip.frame_time_s == pytest.approx(0.04) and clip.n_frames == 2
    pose = clip.forward_kinematics()
    # frame 0: root at (1,2,3) turned 90 deg about Y; the arm's position channels replace its offset
    r_root = Rotation.from_euler("YXZ", [90, 0, 0], degrees=True).as_matrix()
    r_arm = Rotation.from_euler("XZY", [0, 90, 0], degrees=True).as_matrix()
    arm = np.array([1, 2, 3]) + r_root @ [0.5, 2.0, 0.0]
    hand = arm + r_root @ r_arm @ [0, 3, 0]
    np.testing.assert_allclose(pose.positions[0], [[1, 2, 3], arm, hand], atol=1e-12)
    np.testing.assert_allclose(pose.end_positions[0, 0], hand + r_root @ r_arm @ [0, 0, 1], atol=1e-12)
    # frame 1: only the hand rotates (Z 30, X 40, Y 50 in that order)
    r_hand = Rotation.from_euler("ZXY", [30, 40, 50], degrees=True).as_matrix()
    np.testing.assert_allclose(pose.rotations[1, 2], r_hand, atol=1e-12)
    np.testing.assert_allclose(pose.end_positions[1, 0], [1, 5, 0] + r_hand @ [0, 0, 1], atol=1e-12)


@pytest.mark.parametrize(
    "edit, line, words",
    [
        (("1 2 3 90 0 0 0.5 2 0 0 90 0 0 0 0", "1 2 3 90 0 0 0.5 2 0 0 90 0 0 0"), 24, "15 channels"),
        (("0 0 0 0 0 0 1 2 0 0 0 0 30 40 50", "0 0 0 0 0 0 1 2 0 0 0 0 30 x 50"), 25, "not a finite number"),
        (("Frames: 2", "Frames: 3"), 22, "only 2 data lines"),
        (("CHANNELS 3 Zrotation Xrotation Yrotation", "CHANNELS 3 Zrotation Xrotation Wrotation"), 13, "unknown channel 'Wrotation'"),
        (("    OFFSET 0 3 0", "    OFFSET 0 three 0"), 12, "OFFSET of joint 'hand'"),
        (("Frame Time: 0.04", "Frame Time: -1"), 23, "Frame Time"),
    ],
)
def test_malformed_files_name_the_file_and_the_line(tmp_path, edit, line, words):
    path = _write(tmp_path, _SMALL.replace(*edit))
    with pytest.raises(InputFileError) as err:
        load_bvh(path)
    message = str(err.value)
    assert str(path) in message and f"line {line}" in message and words in message


def test_missing_and_truncated_files_are_input_errors(tmp_path):
    with pytest.raises(InputFileError, match="cannot read"):
        load_bvh(tmp_path / "nope.bvh")
    with pytest.raises(InputFileError, match="MOTION"):
        load_bvh(_write(tmp_path, _SMALL.split("MOTION")[0]))
    with pytest.raises(InputFileError, match="HIERARCHY"):
        load_bvh(_write(tmp_path, "hello\n"))


# ----------------------------------------------------------------------------- mapping


def test_both_cmu_naming_schemes_map_onto_the_humanoid():
    walk_map, jacks_map = map_bvh_joints(load_bvh(WALK)), map_bvh_joints(load_bvh(JACKS))
    assert walk_map["upperarm_l"] == "LeftShoulder" and walk_map["forearm_r"] == "RightElbow"  # 3dsMax style
    assert walk_map["thigh_l"] == "LeftHip" and walk_map["abdomen"] == "Chest" and walk_map["thorax"] == "Chest2"
    assert jacks_map["upperarm_l"] == "LeftArm" and jacks_map["forearm_r"] == "RightForeArm"  # MotionBuilder style
    assert jacks_map["thigh_l"] == "LeftUpLeg" and jacks_map["abdomen"] == "Spine" and jacks_map["thorax"] == "Spine1"
    assert set(walk_map) == set(jacks_map) == set(BODY_NAMES)


def test_prefixed_names_map_like_plain_ones_and_unknown_skeletons_fail_clearly(tmp_path):
    text = JACKS.read_text()
    clip = load_bvh(JACKS)
    prefixed = text
    for name in sorted(clip.joint_names, key=len, reverse=True):
        prefixed = prefixed.replace(f"JOINT {name}\n", f"JOINT mixamorig:{name}\n").replace(f"ROOT {name}\n", f"ROOT mixamorig:{name}\n")
    mapping = map_bvh_joints(load_bvh(_write(tmp_path, prefixed, name="prefixed.bvh")))
    assert mapping == {k: f"mixamorig:{v}" for k, v in map_bvh_joints(clip).items()}
    with pytest.raises(InputFileError, match=r"no joint found for humanoid bodies \['head'\].*name_map"):
        map_bvh_joints(load_bvh(_write(tmp_path, text.replace("JOINT Head\n", "JOINT Skull\n"), name="skull.bvh")))
    fixed = map_bvh_joints(load_bvh(tmp_path / "skull.bvh"), name_map={"head": "Skull"})
    assert fixed["head"] == "Skull"


# ----------------------------------------------------------------------------- retargeting


def test_inserted_t_pose_is_detected_and_skipped(walk, jacks):
    assert jacks[1].frames[0] == 1  # converter T-pose in frame 0
    assert walk[1].frames[0] == 0  # 131_01's frame 0 is a captured frame
    forced = retarget_bvh_keys(load_bvh(WALK), PARAMS, skip_frames=1)
    assert forced.frames[0] == 1 and len(forced.frames) == 993


@pytest.mark.parametrize("which", ["walk", "jacks"])
def test_retargeted_limbs_point_along_the_bvh_bones(which, request):
    clip, keys, pos, _ = request.getfixturevalue(which)
    assert np.all(np.isfinite(keys.qpos))
    bvh_world = keys.to_world(clip.forward_kinematics(clip.frames[keys.frames]).positions)
    for a, b in LIMB_SEGMENTS:
        ja, jb = clip.joint_index(keys.joint_map[a]), clip.joint_index(keys.joint_map[b])
        d_bvh = bvh_world[:, jb] - bvh_world[:, ja]
        d_ours = pos[:, B[b]] - pos[:, B[a]]
        cos = np.sum(d_bvh * d_ours, axis=1) / np.linalg.norm(d_bvh, axis=1) / np.linalg.norm(d_ours, axis=1)
        error_deg = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
        print(f"{which} {a}: median {np.median(error_deg):.3f} deg, 95th pct {np.percentile(error_deg, 95):.3f} deg, "
              f"max {error_deg.max():.1f} deg")
        assert np.median(error_deg) < 1.0
        assert np.mean(error_deg < 5.0) > 0.9  # the rest: joint limits of the humanoid


def test_jumping_jacks_raise_both_wrists_above_the_head_about_four_times(jacks):
    # "Above the head" = above the head joint: our head body's origin (the neck joint of the
    # spec) and the BVH's Head joint (CMU's hands reach about 10 cm above it, below the vertex).
    clip, keys, pos, _ = jacks
    head = pos[:, B["head"], 2]
    ours = (pos[:, B["hand_l"], 2] > head) & (pos[:, B["hand_r"], 2] > head)
    p = clip.forward_kinematics(clip.frames[keys.frames]).positions
    theirs = (p[:, clip.joint_index("LeftHand"), 1] > p[:, clip.joint_index("Head"), 1]) & (
        p[:, clip.joint_index("RightHand"), 1] > p[:, clip.joint_index("Head"), 1])

    def cycles(flags):
        return int(np.sum(flags[1:] & ~flags[:-1]) + flags[0])

    print(f"jumping jacks: wrists above head {cycles(ours)} times (BVH: {cycles(theirs)}), "
          f"{ours.mean():.0%} of frames")
    assert cycles(ours) == cycles(theirs)
    assert 3 <= cycles(ours) <= 5
    motion = keys.motion()
    assert motion.duration_s == pytest.approx((599 - 1) / 120, rel=1e-3)


def test_walk_travels_more_than_three_metres_facing_plus_x(walk):
    clip, keys, pos, rot = walk
    motion = keys.motion()
    t = np.arange(0.0, motion.duration_s, 0.25)
    xy = motion.qpos(t)[:, :2]
    path_m = np.linalg.norm(np.diff(xy, axis=0), axis=1).sum()
    print(f"131_01: root path {path_m:.2f} m, start-to-end {np.linalg.norm(xy[-1] - xy[0]):.2f} m, "
          f"{keys.scale_m_per_unit * 100:.3f} cm per BVH unit")
    assert path_m > 3.0
    assert xy[-1, 0] - xy[0, 0] > 2.0  # walks forwards, i.e. along +X
    forward = rot[:30, B["pelvis"], :, 0]
    assert np.degrees(np.abs(np.arctan2(forward[:, 1], forward[:, 0]))).mean() < 15.0


@pytest.mark.parametrize("which", ["walk", "jacks"])
def test_feet_are_on_the_floor(which, request):
    _, keys, _, _ = request.getfixturevalue(which)
    lowest = keys.kinematics.sole_points(keys.qpos)[:, :, 2].min(axis=1)
    print(f"{which}: lowest sole 5/50/95th pct {np.percentile(lowest, [5, 50, 95]).round(3)} m")
    assert np.mean(np.abs(lowest) < 0.03) > 0.6
    assert np.percentile(lowest, 50) > -0.01


def test_units_do_not_matter(tmp_path):
    # the same clip in metres (CMU unit = 1/0.45 inch): identical retargeted motion
    clip = load_bvh(JACKS)
    metres_per_unit = 0.0254 / 0.45
    lines = JACKS.read_text().splitlines()
    out = []
    in_motion = False
    for line in lines:
        words = line.split()
        if words and words[0] == "OFFSET":
            line = "OFFSET " + " ".join(f"{float(v) * metres_per_unit:.9g}" for v in words[1:])
        elif in_motion and words and not line.startswith(("Frames", "Frame Time")):
            values = np.array(words, dtype=float)
            values[:3] *= metres_per_unit
            line = " ".join(f"{v:.9g}" for v in values)
        in_motion = in_motion or line.strip() == "MOTION"
        out.append(line)
    metric = load_bvh(_write(tmp_path, "\n".join(out) + "\n", name="metres.bvh"))
    a = retarget_bvh_keys(clip, PARAMS)
    b = retarget_bvh_keys(metric, PARAMS)
    assert b.scale_m_per_unit == pytest.approx(a.scale_m_per_unit / metres_per_unit, rel=1e-6)
    np.testing.assert_allclose(b.qpos, a.qpos, atol=1e-6)


def test_motion_interpolates_between_frames_without_jumps(jacks):
    _, keys, _, _ = jacks
    motion = retarget_bvh(load_bvh(JACKS), PARAMS)
    np.testing.assert_allclose(motion.qpos(keys.times_s[:50]), keys.qpos[:50], atol=1e-9)
    fine = motion.qpos(np.arange(0.0, 1.0, 1.0 / 960.0))  # 8 sub-frames per BVH frame
    assert np.all(np.isfinite(fine))
    hinge_step = np.abs(np.diff(fine[:, 7:], axis=0)).max()
    key_step = np.abs(np.diff(keys.qpos[:121, 7:], axis=0)).max()
    assert hinge_step <= key_step / 8 * 3.0  # PCHIP: slope at most 3x the secant between keys
    quat_dot = np.sum(fine[1:, 3:7] * fine[:-1, 3:7], axis=1)
    assert quat_dot.min() > np.cos(0.01)  # root orientation: under 0.02 rad per 1/960 s, no sign flips


def test_a_different_body_scales_the_clip(tmp_path):
    small = retarget_bvh_keys(load_bvh(JACKS), BodyParams(height_m=1.5))
    large = retarget_bvh_keys(load_bvh(JACKS), BodyParams(height_m=2.0))
    assert large.scale_m_per_unit / small.scale_m_per_unit == pytest.approx(2.0 / 1.5, rel=1e-6)
    np.testing.assert_allclose(large.qpos[:, 7:], small.qpos[:, 7:], atol=1e-9)  # same angles
    rise_small = np.ptp(small.qpos[:, 2])
    rise_large = np.ptp(large.qpos[:, 2])
    assert rise_large / rise_small == pytest.approx(2.0 / 1.5, rel=1e-6)


def _humanoid_bvh(path: Path, kin, times: np.ndarray, qpos: np.ndarray) -> Path:
    """Write poses of our own humanoid as a Z-up BVH in centimetres (our body names, our hinges as channels)."""
    model = kin.model
    cm = 100.0
    ends = {
        "head": [0.0, 0.0, 0.25],
        "hand_l": [0.0, 0.18, 0.0],
        "hand_r": [0.0, -0.18, 0.0],
        "foot_l": list(kin.ball_of_foot_local),
        "foot_r": list(kin.ball_of_foot_local * [1.0, -1.0, 1.0]),
    }
    hinges_of = {b: [] for b in BODY_NAMES}
    for j in range(1, model.njnt):
        hinges_of[model.body(model.jnt_bodyid[j]).name].append(j)
    lines = ["HIERARCHY"]
    columns = []
    root_euler = Rotation.from_quat(qpos[:, 3:7], scalar_first=True).as_euler("ZYX", degrees=True)

    def emit(body: str, depth: int) -> None:
        pad = "  " * depth
        offset = [0.0, 0.0, 0.0] if body == "pelvis" else model.body_pos[model.body(body).id] * cm
        lines.append(f"{pad}{'ROOT' if body == 'pelvis' else 'JOINT'} {body}")
        lines.append(f"{pad}{{")
        lines.append(f"{pad}  OFFSET {' '.join(f'{v:.9g}' for v in offset)}")
        if body == "pelvis":
            lines.append(f"{pad}  CHANNELS 6 Xposition Yposition Zposition Zrotation Yrotation Xrotation")
            columns.extend([qpos[:, 0] * cm, qpos[:, 1] * cm, qpos[:, 2] * cm, *root_euler.T])
        else:
            names = []
            for j in hinges_of[body]:
                names.append("XYZ"[int(np.argmax(model.jnt_axis[j]))] + "rotation")
                columns.append(np.degrees(qpos[:, model.jnt_qposadr[j]]))
            lines.append(f"{pad}  CHANNELS {len(names)} {' '.join(names)}")
        kids = [b for b in BODY_NAMES if model.body(b).parentid == model.body(body).id]
        for kid in kids:
            emit(kid, depth + 1)
        if not kids:
            lines.extend([f"{pad}  End Site", f"{pad}  {{", f"{pad}    OFFSET {' '.join(f'{v * cm:.9g}' for v in ends[body])}", f"{pad}  }}"])
        lines.append(f"{pad}}}")

    emit("pelvis", 0)
    lines += ["MOTION", f"Frames: {len(times)}", f"Frame Time: {times[1] - times[0]:.9g}"]
    lines += [" ".join(f"{v:.12g}" for v in row) for row in np.stack(columns, axis=1)]
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.mark.parametrize("clip", ["squash_forehand", "walk_in_place"])
def test_our_own_humanoid_written_as_bvh_retargets_onto_itself(tmp_path, clip):
    # End to end check of the retargeting maths: a BVH of our own skeleton (rest = T-pose,
    # same bone lengths in cm, Z-up) must come back as the very poses that wrote it.
    times = np.arange(0.0, 3.0, 1.0 / 60.0)
    qpos = make_motion(clip, PARAMS, 3.0).qpos(times)
    keys = retarget_bvh_keys(
        load_bvh(_humanoid_bvh(tmp_path / "own.bvh", HumanoidKinematics(PARAMS), times, qpos)),
        PARAMS, up_axis="z", face_plus_x=False, center_xy=False, skip_frames=0, foot_contact=False,
    )
    assert keys.joint_map == {b: b for b in BODY_NAMES}
    assert keys.scale_m_per_unit == pytest.approx(0.01, rel=1e-9)
    np.testing.assert_allclose(keys.qpos[:, 7:], qpos[:, 7:], atol=1e-6)
    np.testing.assert_allclose(np.abs(np.sum(keys.qpos[:, 3:7] * qpos[:, 3:7], axis=1)), 1.0, atol=1e-9)
    np.testing.assert_allclose(keys.qpos[:, :2], qpos[:, :2], atol=1e-9)
    dz = keys.qpos[:, 2] - qpos[:, 2]
    np.testing.assert_allclose(dz, dz[0], atol=1e-9)  # only the floor offset differs ...
    assert abs(dz[0]) < 0.005  # ... and the clip already stood on the floor


# ----------------------------------------------------------------------------- all six shared clips


@pytest.fixture(scope="module")
def retargeted():
    """Every shared clip parsed and retargeted once: {path: (clip, keys)}."""
    out = {}
    for path in ALL_CLIPS:
        clip = load_bvh(path)
        out[path] = (clip, retarget_bvh_keys(clip, PARAMS))
    return out


@pytest.mark.parametrize("path, frames, joints, channels, end_sites", [
    (HOPS, 2752, 31, 96, 7), (SALSA, 1198, 43, 132, 14), (KICK, 1317, 43, 132, 14), (DANCE, 2212, 43, 132, 14),
])
def test_more_cmu_clips_parse(path, frames, joints, channels, end_sites):
    # counts from the shared data's README; the Daz files mix CRLF and LF and put a tab after "Frames:"
    clip = load_bvh(path)
    assert (clip.n_frames, clip.n_joints, clip.frames.shape[1], len(clip.end_site_parents)) == (frames, joints, channels, end_sites)
    assert clip.frame_time_s == pytest.approx(1 / 120, rel=1e-3)


def test_daz_skeletons_map_onto_the_humanoid():
    mapping = map_bvh_joints(load_bvh(KICK))
    assert mapping == {
        "pelvis": "hip", "abdomen": "abdomen", "thorax": "chest", "head": "head",
        "upperarm_l": "lShldr", "forearm_l": "lForeArm", "hand_l": "lHand",
        "upperarm_r": "rShldr", "forearm_r": "rForeArm", "hand_r": "rHand",
        "thigh_l": "lThigh", "shank_l": "lShin", "foot_l": "lFoot",
        "thigh_r": "rThigh", "shank_r": "rShin", "foot_r": "rFoot",
    }


def _largest_channel_step_deg(clip, start: int, stop: int) -> np.ndarray:
    """Largest change of any rotation channel between consecutive frames start..stop (wraps folded)."""
    rot = np.array([c.lower().endswith("rotation") for names in clip.channels for c in names])
    d = np.abs(np.diff(clip.frames[start:stop + 1, rot], axis=0))
    return np.minimum(d, 360.0 - d).max(axis=1)


@pytest.mark.parametrize("path, dropped", [(WALK, 0), (JACKS, 1), (HOPS, 1), (SALSA, 7), (KICK, 7), (DANCE, 7)])
def test_converter_lead_in_is_dropped(retargeted, path, dropped):
    # The shared data's README: cgspeed inserts a T-pose as frame 0 (131_01's frame 0 is continuous
    # with frame 1 and is kept); in the Daz files joints then turn 20-40 deg per frame for a few
    # frames, where the capture itself turns a few degrees.
    clip, keys = retargeted[path]
    assert keys.frames[0] == dropped
    steps_in = _largest_channel_step_deg(clip, 0, dropped)
    steps_after = _largest_channel_step_deg(clip, dropped, dropped + 30)
    print(f"{path.name}: dropped {dropped} frames, their steps {steps_in.round(1)} deg; next 0.25 s at most {steps_after.max():.1f} deg")
    assert steps_after.max() < 5.0
    if dropped:
        assert steps_in[0] > 20.0


def _source_foot_heights(clip, keys) -> tuple[np.ndarray, np.ndarray]:
    """Independent reading of "the source's lowest foot point above the floor" per kept frame:
    every foot point (foot joints, the joints below them, their End Sites) measured, in metres
    along the file's up axis, from its own floor-contact height (its 5th percentile over the
    kept frames); returns (lowest over both feet (K,), lowest per foot (K, 2))."""
    pose = clip.forward_kinematics(clip.frames[keys.frames])
    per_foot = []
    for body in ("foot_l", "foot_r"):
        root = clip.joint_index(keys.joint_map[body])
        joints = [j for j in range(clip.n_joints) if j == root or root in _ancestors(clip.parents, j)]
        sites = [e for e, parent in enumerate(clip.end_site_parents) if parent in joints]
        up = np.concatenate([pose.positions[:, joints, 1], pose.end_positions[:, sites, 1]], axis=1) * keys.scale_m_per_unit
        per_foot.append((up - np.percentile(up, 5.0, axis=0)).min(axis=1))
    per_foot = np.stack(per_foot, axis=1)
    return per_foot.min(axis=1), per_foot


def _ancestors(parents: np.ndarray, j: int) -> list[int]:
    out = []
    while parents[j] >= 0:
        j = int(parents[j])
        out.append(j)
    return out


@pytest.mark.parametrize("path", ALL_CLIPS, ids=[p.stem for p in ALL_CLIPS])
def test_soles_never_sink_below_the_sources_feet(retargeted, path):
    # The issue: retargeting the kick let a sole sink 92 mm below the floor while the source's
    # feet stayed above it.  Now, at every frame: our lowest sole point is at most 10 mm below
    # the source's lowest foot point, and on or above the floor whenever that point is.
    clip, keys = retargeted[path]
    source, _ = _source_foot_heights(clip, keys)
    ours = keys.kinematics.sole_points(keys.motion().qpos(keys.times_s))[:, :, 2].min(axis=1)
    below_source = ours - source
    print(f"{path.stem}: source lowest foot point {source.min() * 1000:.0f}..{source.max() * 1000:.0f} mm, "
          f"our lowest sole {ours.min() * 1000:.1f}..{ours.max() * 1000:.0f} mm, ours - source >= "
          f"{below_source.min() * 1000:.1f} mm; root lifted {keys.root_lift_m.min() * 1000:.0f}..{keys.root_lift_m.max() * 1000:.0f} mm")
    assert below_source.min() > -0.010
    assert ours[source >= 0.0].min() > -0.0005
    # ... and the feet are not floating instead: where the source stands on the floor, so do we
    assert np.all(ours[source < 0.005] < 0.010)


def test_floor_contact_moves_only_the_root_height_and_the_legs(retargeted):
    clip, keys = retargeted[KICK]
    raw = retarget_bvh_keys(clip, PARAMS, foot_contact=False)
    legs = np.array([i for i, h in enumerate(HINGE_NAMES) if h.startswith(("hip", "knee", "ankle"))])
    others = np.array([i for i in range(len(HINGE_NAMES)) if i not in legs])
    assert len(legs) == 12  # hip x y z, knee, ankle y x per side
    np.testing.assert_allclose(keys.qpos[:, 7 + others], raw.qpos[:, 7 + others], atol=1e-12)  # trunk, neck, arms
    np.testing.assert_allclose(keys.qpos[:, :2], raw.qpos[:, :2], atol=1e-12)  # root x, y
    np.testing.assert_allclose(keys.qpos[:, 3:7], raw.qpos[:, 3:7], atol=1e-12)  # root orientation
    hips = clip.forward_kinematics(clip.frames[keys.frames]).positions[:, [clip.joint_index("lThigh"), clip.joint_index("rThigh")]]
    np.testing.assert_allclose(keys.qpos[:, 2], keys.to_world(hips.mean(axis=1))[:, 2] + keys.root_lift_m, atol=1e-9)
    # hips and knees bend only where a foot is near the floor (the ankles level every foot)
    hips_knees = np.array([i for i, h in enumerate(HINGE_NAMES) if h.startswith(("hip", "knee"))])
    changed = np.abs(keys.qpos[:, 7 + hips_knees] - raw.qpos[:, 7 + hips_knees]).max(axis=1) > 1e-9
    print(f"135_04: hips and knees re-solved in {changed.mean():.0%} of the frames")
    assert 0.0 < changed.mean() < 1.0


def test_each_foot_stands_where_the_sources_foot_stands(retargeted):
    # Per foot, not just the lowest one: where the source's foot is on the floor, ours is too
    # (the kick's back foot, which our ankle range leaves on its toe corner, used to hold the
    # root up so that the front foot hovered 9 cm above the floor it stands on in the source).
    for path in ALL_CLIPS:
        clip, keys = retargeted[path]
        _, per_foot = _source_foot_heights(clip, keys)
        ours = keys.kinematics.sole_points(keys.qpos)[:, :, 2].reshape(-1, 2, 4).min(axis=2)
        standing = per_foot < 0.005
        height = ours[standing]
        print(f"{path.stem}: our foot where the source's stands: median {np.median(height) * 1000:.1f} mm, "
              f"90th pct {np.percentile(height, 90) * 1000:.1f} mm")
        assert np.percentile(height, 90) < 0.010


def _standing_foot_tilt_deg(clip, keys) -> np.ndarray:
    """Lateral tilt (deg) of our feet in the frames where the source's same foot is on the floor."""
    _, per_foot = _source_foot_heights(clip, keys)
    _, rot = keys.kinematics.forward(keys.qpos)
    return np.concatenate([np.degrees(np.arcsin(np.abs(rot[per_foot[:, side] < 0.005, B[body], 2, 1])))
                           for side, body in enumerate(("foot_l", "foot_r"))])


@pytest.mark.parametrize("path", ALL_CLIPS, ids=[p.stem for p in ALL_CLIPS])
def test_feet_on_the_floor_are_level_across(retargeted, path):
    # A foot's roll about its long axis is invisible in the BVH's foot points, and the joint
    # rotations that carry it roll standing feet by up to 30 deg (13_29, 135_04), which put our
    # soles on one edge.  Ours stay level across where the source's foot is on the floor (tilt
    # remains where the ankle is at its range, or a pitched foot points elsewhere than the
    # source's, our ankle having no twist).
    clip, keys = retargeted[path]
    ours = _standing_foot_tilt_deg(clip, keys)
    joints = _standing_foot_tilt_deg(clip, retarget_bvh_keys(clip, PARAMS, foot_contact=False))
    print(f"{path.stem}: lateral tilt of standing feet, median / 90th pct: {np.median(ours):.1f} / "
          f"{np.percentile(ours, 90):.1f} deg (source joint rotations: {np.median(joints):.1f} / {np.percentile(joints, 90):.1f} deg)")
    assert np.median(ours) < 1.5
    assert np.median(ours) < 0.5 * np.median(joints)
