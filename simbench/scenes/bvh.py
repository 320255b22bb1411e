"""Retargeting a BVH clip (:mod:`simbench.scenes.bvh_file`) onto the humanoid (:func:`retarget_bvh`).

Retargeting, in short
---------------------
1. Map humanoid bodies to BVH joints by name (:func:`simbench.scenes.bvh_mapping.map_bvh_joints`;
   ``name_map`` overrides).
2. Reference pose (the OFFSETs, or frame 0): each of our bodies is turned so that its bone
   points along the BVH's reference bone (:func:`simbench.scenes.bvh_hinges.alignments`). The scale is the ratio of
   the limb lengths, so any unit works (CMU's 1/0.45 inch, centimetres, inches, metres).
3. Every frame, each body's target world rotation is the BVH joint's rotation since the
   reference, applied to that aligned body; trunk and neck hinges follow by XYZ decomposition
   relative to the realised parent; limbs are solved so that both segments point along the
   BVH bones (the 1-DoF elbow/knee picks the upper segment's twist), hands take the two
   wrist hinges that keep their long axis, feet the two ankle hinges that keep their sole's
   normal, the foot's target being the source's ankle -> toe bone kept level across
   (:func:`_level_foot`); everything is clamped to the ranges.
4. Root: hip-joint midpoint, scaled, Y-up to Z-up, turned to face +X; its height then puts
   our lowest sole point, frame by frame, where the source's lowest foot point is above the
   floor (each foot point measured from its own floor-contact height), never below z = 0,
   and each foot near the floor is brought to its own source foot's height by bending or
   stretching its leg (:func:`_place_feet`).  Where our joint ranges cannot follow the source
   (an ankle at its dorsiflexion limit in a deep crouch) that foot stands on its toe corner.

The converter's lead-in is dropped (:func:`simbench.scenes.bvh_file.converter_lead_in`).
A BVH written from our own humanoid (our body names, T-pose rest) retargets onto itself
exactly (``tests/test_motions_bvh.py``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np
from scipy.spatial.transform import Rotation

from mocap.errors import InputFileError
from simbench.scenes.bvh_file import BvhClip, BvhPose, converter_lead_in, is_descendant
from simbench.scenes.bvh_hinges import alignments, heading_angle, min_rotation, rz, solve_hinges, unit
from simbench.scenes.bvh_mapping import BONE_END, LIMBS, ROLES, map_bvh_joints
from simbench.scenes.humanoid import BODY_NAMES, HINGE_NAMES, BodyParams
from simbench.scenes.motions import HumanoidKinematics, Motion

__all__ = ["RetargetedBvh", "retarget_bvh", "retarget_bvh_keys"]

_BODY_INDEX = {name: i for i, name in enumerate(BODY_NAMES)}


# Floor contact: a foot point's height when its foot is on the floor is its 5th percentile
# over the clip (every clip has its feet on the floor for far more than 5 % of its frames).
_CONTACT_PERCENTILE = 5.0
# Legs are bent or stretched to put a foot at its source foot's height (_place_feet) where
# that foot is within 2 cm of the floor, blending out up to 6 cm (feet in the air keep the
# source's limb directions); for a 1.75 m subject, i.e. as fractions of the standing hip height
# (0.93 m), so that every body size gets the same joint angles.
_FOOT_IK_FULL = 0.02 / 0.93
_FOOT_IK_BLEND = 0.04 / 0.93


@dataclass(frozen=True)
class RetargetedBvh:
    """A BVH clip mapped onto the humanoid, as key poses plus what the mapping used.

    Attributes
    ----------
    name : str
    times_s : (K,) float
        Key times from 0, seconds (the BVH frame times of the kept frames).
    qpos : (K, 40) float
        Key poses (MuJoCo qpos).
    joint_map : dict[str, str]
        Humanoid body -> BVH joint it follows.
    frames : (K,) int
        BVH frame index of each key.
    scale_m_per_unit : float
        Metres per BVH unit found from the skeleton's limb lengths.
    world_from_file : (3, 3) float
        Rotation from BVH axes to the bench world (Y-up to Z-up and the heading turn).
    translation_m : (3,) float
        Offset added after scaling and rotating: ``world = scale * world_from_file @ p + translation``
        (:meth:`to_world`); its z puts the source's lowest foot-contact height on the floor.
    root_lift_m : (K,) float
        Height added to each key's root on top of the source's hip midpoint brought into the
        world (:meth:`to_world`), metres: what puts our soles where the source's feet are.
    source_foot_height_m : (K,) float
        Height of the source's feet above the floor per key, metres: the lowest of its foot
        points (foot joints, toes, End Sites), each measured from its own floor-contact
        height (its 5th percentile over the clip).  Negative where the source's feet go below
        their contact height.
    kinematics : HumanoidKinematics
    """

    name: str
    times_s: np.ndarray
    qpos: np.ndarray
    joint_map: dict[str, str]
    frames: np.ndarray
    scale_m_per_unit: float
    world_from_file: np.ndarray
    translation_m: np.ndarray
    root_lift_m: np.ndarray
    source_foot_height_m: np.ndarray
    kinematics: HumanoidKinematics

    def to_world(self, points: np.ndarray) -> np.ndarray:
        """BVH-space points ``(..., 3)`` (file units and axes) to bench world metres."""
        return self.scale_m_per_unit * np.asarray(points) @ self.world_from_file.T + self.translation_m

    def motion(self) -> Motion:
        """The clip as a :class:`Motion` (PCHIP / rotation-spline interpolation between keys)."""
        return Motion.from_samples(self.name, self.times_s, self.qpos, self.kinematics, description=f"BVH {self.name}")


def _chain_end(clip: BvhClip, pose_positions: np.ndarray, ends: np.ndarray, joint: int) -> np.ndarray:
    """Position ``(F, 3)`` of the first point below ``joint`` that is not at the joint itself.

    Follows the first child (or the End Site) until the offset is non-zero: CMU hands and
    necks have zero-length helper joints (``LeftFingerBase``, ``lhand``, ``Neck``).
    """
    j = joint
    while True:
        kids = clip.children(j)
        if kids:
            j = kids[0]
            if np.linalg.norm(clip.offsets[j]) > 1e-9:
                return pose_positions[:, j]
            continue
        sites = np.flatnonzero(clip.end_site_parents == j)
        if sites.size:
            return ends[:, sites[0]]
        raise InputFileError(clip.path, f"joint '{clip.joint_names[joint]}' has no child to give it a direction",
                             "add an End Site or map the body to another joint with name_map")


def retarget_bvh_keys(
    clip: BvhClip,
    params: BodyParams,
    *,
    skip_frames: int | None = None,
    reference: str = "rest",
    up_axis: str = "y",
    face_plus_x: bool = True,
    center_xy: bool = True,
    foot_contact: bool = True,
    name_map: Mapping[str, str] | None = None,
    name: str | None = None,
) -> RetargetedBvh:
    """Map every BVH frame onto the humanoid: see :func:`retarget_bvh` (same parameters)."""
    if reference not in ("rest", "first_frame"):
        raise ValueError(f"reference must be 'rest' or 'first_frame', got {reference!r}")
    if up_axis not in ("y", "z"):
        raise ValueError(f"up_axis must be 'y' or 'z', got {up_axis!r}")
    kin = HumanoidKinematics(params)
    joint_map = map_bvh_joints(clip, name_map)
    src = _Source.of(clip, joint_map, _kept_frames(clip, skip_frames), reference, up_axis)
    scale = _scale(kin, src)
    targets, directions, heading = _body_targets(kin, src, face_plus_x, foot_contact)
    world_from_file = heading @ src.axes
    hip_mid = 0.5 * (src.pose.positions[:, src.idx["thigh_l"]] + src.pose.positions[:, src.idx["thigh_r"]])
    qpos = np.zeros((len(src.keep), len(HINGE_NAMES) + 7))
    qpos[:, :3] = scale * hip_mid @ world_from_file.T
    qpos[:, 3:7] = Rotation.from_matrix(targets["pelvis"]).as_quat(scalar_first=True)
    qpos[:, 7:] = solve_hinges(kin, targets, directions)
    floor = _stand_on_the_floor(kin, src, qpos, scale, world_from_file, targets, directions, center_xy, foot_contact)
    return RetargetedBvh(
        name=name or clip.path.stem,
        times_s=(src.keep - src.keep[0]) * clip.frame_time_s,
        qpos=floor.qpos,
        joint_map=joint_map,
        frames=src.keep,
        scale_m_per_unit=float(scale),
        world_from_file=world_from_file,
        translation_m=floor.translation_m,
        root_lift_m=floor.root_lift_m,
        source_foot_height_m=floor.source_foot_height_m,
        kinematics=kin,
    )


def _kept_frames(clip: BvhClip, skip_frames: int | None) -> np.ndarray:
    """Indices of the frames kept: all but the converter's lead-in (or ``skip_frames``)."""
    first = converter_lead_in(clip) if skip_frames is None else int(skip_frames)
    if first < 0:
        raise ValueError(f"skip_frames must be >= 0, got {skip_frames!r}")
    if clip.n_frames - first < 2:
        raise InputFileError(clip.path, f"only {clip.n_frames} frame(s), {first} of them skipped",
                             "a motion needs at least two frames after the converter's T-pose and transition")
    return np.arange(first, clip.n_frames)


@dataclass(frozen=True)
class _Source:
    """The BVH side of a retargeting: joint of each body, axes, reference pose and kept frames."""

    clip: BvhClip
    idx: dict[str, int]      # humanoid body -> BVH joint index
    axes: np.ndarray         # (3, 3) BVH axes -> bench axes (Y-up files: the subject's up on +Y)
    ref: BvhPose             # the reference pose (one frame)
    pose: BvhPose            # the kept frames
    keep: np.ndarray         # (K,) BVH frame indices

    @classmethod
    def of(cls, clip: BvhClip, joint_map: dict[str, str], keep: np.ndarray, reference: str, up_axis: str) -> "_Source":
        axes = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]) if up_axis == "y" else np.eye(3)
        ref = clip.forward_kinematics(np.zeros((1, clip.frames.shape[1])) if reference == "rest" else clip.frames[:1])
        idx = {role: clip.joint_index(j) for role, j in joint_map.items()}
        return cls(clip, idx, axes, ref, clip.forward_kinematics(clip.frames[keep]), keep)

    def bone(self, p: BvhPose, role: str) -> np.ndarray:
        """BVH bone vector ``(F, 3)`` of a humanoid body, file units, bench axes."""
        start = p.positions[:, self.idx[role]]
        end_role = BONE_END[role]
        end = p.positions[:, self.idx[end_role]] if end_role else _chain_end(self.clip, p.positions, p.end_positions, self.idx[role])
        return (end - start) @ self.axes.T


def _scale(kin: HumanoidKinematics, src: _Source) -> float:
    """Metres per BVH unit: limb lengths of the model over those of the skeleton (any units).

    Limbs rather than stature: where a BVH's head end site sits varies between skeletons
    (CMU's is ~10 cm below the vertex), while joint-centre distances are what the retargeted
    motion must fit.
    """
    limbs = [r for u, m, *_ in LIMBS for r in (u, m)]
    bvh_total = sum(np.linalg.norm(src.bone(src.ref, r)[0]) for r in limbs)
    if not bvh_total > 0:
        raise InputFileError(src.clip.path, "the limbs of the skeleton have zero length", "check the OFFSETs of the arm and leg joints")
    body_pos = kin.model.body_pos
    return sum(np.linalg.norm(body_pos[kin.model.body(BONE_END[r]).id]) for r in limbs) / bvh_total


def _body_targets(kin: HumanoidKinematics, src: _Source, face_plus_x: bool,
                  foot_contact: bool) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray], np.ndarray]:
    """Target world rotation ``(K, 3, 3)`` and bone direction ``(K, 3)`` of every body, and the heading turn ``(3, 3)``.

    A body's target is the BVH joint's rotation since the reference pose, applied to our body
    as it sits in that reference pose; the clip is turned to face +X over its first 0.25 s.
    """
    left = (src.ref.positions[0, src.idx["thigh_l"]] - src.ref.positions[0, src.idx["thigh_r"]]) @ src.axes.T
    psi_ref = float(heading_angle(left)) - 0.5 * np.pi  # left side towards +Y means facing +X
    ref_dirs = {r: unit(src.bone(src.ref, r)[0]) for r in BONE_END}
    align = alignments(kin, ref_dirs, psi_ref)
    targets = {}
    for role in ROLES:
        relative = src.pose.rotations[:, src.idx[role]] @ src.ref.rotations[0, src.idx[role]].T
        targets[role] = src.axes @ relative @ src.axes.T @ align[role]
    heading = np.eye(3)
    if face_plus_x:
        n0 = max(1, min(len(src.keep), int(round(0.25 / src.clip.frame_time_s))))
        psi = heading_angle(targets["pelvis"][:n0, :, 0])
        heading = rz(-float(np.arctan2(np.mean(np.sin(psi)), np.mean(np.cos(psi)))))
    targets = {r: heading @ t for r, t in targets.items()}
    directions = {r: unit(src.bone(src.pose, r) @ heading.T) for r in BONE_END}
    if foot_contact:
        for foot in ("foot_l", "foot_r"):
            targets[foot] = _level_foot(targets[foot], directions[foot], float(ref_dirs[foot][2]))
    return targets, directions, heading


@dataclass(frozen=True)
class _Floor:
    qpos: np.ndarray                  # (K, 40) with the root's height and the legs placed
    translation_m: np.ndarray         # (3,) see RetargetedBvh.translation_m
    root_lift_m: np.ndarray           # (K,)
    source_foot_height_m: np.ndarray  # (K,)


def _stand_on_the_floor(kin: HumanoidKinematics, src: _Source, qpos: np.ndarray, scale: float, world_from_file: np.ndarray,
                        targets: dict[str, np.ndarray], directions: dict[str, np.ndarray], center_xy: bool,
                        foot_contact: bool) -> _Floor:
    """The root's height (and, with ``foot_contact``, the legs) that put the feet where the source's are.

    The source's feet: each foot point (ankle, toes, End Sites) measured from its own
    floor-contact height; the lowest of them per frame is how high the source's feet are above
    the floor. The file's own floor (y = 0) is not trusted: the Daz conversions stand 6-9 cm
    above or below it. ``scale`` (metres per file unit) and ``world_from_file`` ``(3, 3)`` take file points to the world.
    """
    per_foot = []  # (K,) per foot: its lowest point above its contact height, metres
    lowest_contact = np.inf
    for foot in ("foot_l", "foot_r"):
        heights = scale * (_foot_points(src.clip, src.pose, src.idx[foot]) @ world_from_file.T)[..., 2]  # (K, P) m
        contact = np.percentile(heights, _CONTACT_PERCENTILE, axis=0)  # (P,) m
        per_foot.append((heights - contact).min(axis=1))
        lowest_contact = min(lowest_contact, float(contact.min()))
    source_feet = np.stack(per_foot, axis=1)  # (K, 2)
    source_height = source_feet.min(axis=1)  # (K,)
    translation = np.zeros(3)
    translation[2] = -lowest_contact
    qpos = qpos.copy()
    if center_xy:
        translation[:2] = -0.5 * (qpos[:, :2].min(axis=0) + qpos[:, :2].max(axis=0))
    qpos[:, :3] += translation
    raw_z = qpos[:, 2].copy()
    if foot_contact:
        # Our lowest sole goes where the source's lowest foot point is, and never below the
        # floor (where the source's feet go below their contact height, e.g. CMU toe End
        # Sites dipping through the floor at toe-off, ours stay on it): first by the root's
        # height, then each foot near the floor is brought to its own source foot's height by
        # its leg (_place_feet), then the root's height once more for what the legs could not
        # reach.  Elsewhere the joint angles are the source's.
        qpos[:, 2] += np.maximum(source_height, 0.0) - kin.sole_points(qpos)[:, :, 2].min(axis=1)
        near = np.clip((_FOOT_IK_FULL + _FOOT_IK_BLEND - source_feet / kin.standing_height_m) / _FOOT_IK_BLEND, 0.0, 1.0)
        sole_feet = kin.sole_points(qpos)[:, :, 2].reshape(-1, 2, 4).min(axis=2)
        wanted = sole_feet + near * near * (3.0 - 2.0 * near) * (np.maximum(source_feet, 0.0) - sole_feet)
        qpos = _place_feet(kin, qpos, targets, directions, wanted)
        sole = kin.sole_points(qpos)[:, :, 2].min(axis=1)
        lift = qpos[:, 2] - raw_z + np.maximum(source_height, 0.0) - sole
    else:
        sole = kin.sole_points(qpos)[:, :, 2].min(axis=1)  # (K,) lowest sole point
        # One offset for the clip: the lowest sole of each frame, at its 25th percentile
        # over the clip (robust to jumps, where both feet leave the floor), on the floor.
        lift = np.full(len(qpos), -float(np.percentile(sole, 25.0)))
    qpos[:, 2] = raw_z + lift
    return _Floor(qpos, translation, lift, source_height)


def _foot_points(clip: BvhClip, pose: BvhPose, foot: int) -> np.ndarray:
    """The source's points of one foot ``(F, P, 3)``, file units and axes: the foot joint,
    every joint below it (toes) and their End Sites."""
    joints = [j for j in range(clip.n_joints) if j == foot or is_descendant(clip.parents, j, foot)]
    sites = [e for e, parent in enumerate(clip.end_site_parents) if parent in joints]
    return np.concatenate([pose.positions[:, joints], pose.end_positions[:, sites]], axis=1)


def _place_feet(kin: HumanoidKinematics, qpos: np.ndarray, targets: dict[str, np.ndarray],
                directions: dict[str, np.ndarray], wanted: np.ndarray) -> np.ndarray:
    """Bend or stretch each leg so that its foot's lowest sole point goes to ``wanted``.

    Two-bone inverse kinematics on our own segment lengths: the ankle moves vertically by the
    height error (the foot keeps its orientation target), the knee stays on its side of the
    hip-ankle line, and the leg is solved again from the new thigh and shank directions by
    :func:`simbench.scenes.bvh_hinges.solve_hinges` (joint ranges included), twice, since the ankle's range can change
    the foot's tilt once the shank moves.  Used where the source's foot is on or near the
    floor: without it, a foot our joint ranges leave on its toe corner holds the root up and
    the other foot hovers above the floor where the source's stands on it.

    Parameters
    ----------
    qpos : (K, 40)
        Poses; only the hinges change.
    targets, directions : dict
        As for :func:`simbench.scenes.bvh_hinges.solve_hinges`; the legs' directions are replaced.
    wanted : (K, 2) float
        Height of the lowest sole point of the left and right foot, metres; NaN leaves it.
    """
    qpos = qpos.copy()
    dirs = dict(directions)
    for _ in range(2):
        pos, rot = kin.forward(qpos)
        sole = kin.sole_points(qpos)[:, :, 2].reshape(-1, 2, 4).min(axis=2)
        for s, side in enumerate("lr"):
            dz = np.nan_to_num(wanted[:, s] - sole[:, s])
            hip, knee, ankle = (pos[:, _BODY_INDEX[f"{b}_{side}"]] for b in ("thigh", "shank", "foot"))
            l1 = np.linalg.norm(knee - hip, axis=1)
            l2 = np.linalg.norm(ankle - knee, axis=1)
            axis = np.einsum("kij,j->ki", rot[:, _BODY_INDEX[f"shank_{side}"]], kin.model.jnt_axis[kin.model.joint(f"knee_{side}").id])
            reach = ankle + dz[:, None] * np.array([0.0, 0.0, 1.0]) - hip
            d = np.clip(np.linalg.norm(reach, axis=1), np.abs(l1 - l2) + 1e-4 * (l1 + l2), (1.0 - 1e-6) * (l1 + l2))
            u = unit(reach)
            w = unit(np.cross(u, axis))  # the side a flexed knee lies on
            cos_a = np.clip((l1 * l1 + d * d - l2 * l2) / (2.0 * l1 * d), -1.0, 1.0)
            new_knee = l1[:, None] * (cos_a[:, None] * u + np.sqrt(1.0 - cos_a * cos_a)[:, None] * w)
            moved = dz != 0.0  # feet away from the floor (no height wanted) keep the source's directions
            dirs[f"thigh_{side}"] = np.where(moved[:, None], unit(new_knee), dirs[f"thigh_{side}"])
            dirs[f"shank_{side}"] = np.where(moved[:, None], unit(d[:, None] * u - new_knee), dirs[f"shank_{side}"])
        qpos[:, 7:] = solve_hinges(kin, targets, dirs)
    return qpos


def _level_foot(target: np.ndarray, toe_dir: np.ndarray, ref_pitch_sin: float) -> np.ndarray:
    """Foot orientations ``(F, 3, 3)`` that follow the source's ankle -> toe bone, level across.

    A foot's roll about its long axis cannot be seen in a BVH's foot points (ankle, toes and
    End Site lie on one line), and the joint rotations that carry it are unreliable: the Daz
    conversions stand on feet rolled by up to 40 deg while ankle and toe sit at their floor
    heights, which put our soles on one corner and lifted the other foot off the floor.  So
    our foot takes the direction and pitch of the source's ankle -> toe bone (its pitch in the
    reference pose counting as a flat foot, as in :func:`simbench.scenes.bvh_hinges.alignments`) with its lateral axis
    horizontal; only where that bone is near vertical (no level direction across it) does the
    lateral axis blend back to the source joint's rotation ``target``.

    Parameters
    ----------
    target : (F, 3, 3)
        Foot rotation from the source joint's rotation (world from foot).
    toe_dir : (F, 3)
        Unit ankle -> toe direction of the source, bench world.
    ref_pitch_sin : float
        Sine of that bone's elevation in the reference pose (negative: toe below the ankle).
    """
    sin_b = float(np.clip(ref_pitch_sin, -0.95, 0.95))
    ball = np.array([np.sqrt(1.0 - sin_b * sin_b), 0.0, sin_b])  # the flat reference foot's bone, foot frame
    across_rot = target[:, :, 1] - np.sum(target[:, :, 1] * toe_dir, axis=1, keepdims=True) * toe_dir
    # The foot's left (+y) side: up x toe for a sole facing down (feet are never upside down);
    # the source joint's lateral axis is turned to the same side before any blending.
    across_level = np.cross([0.0, 0.0, 1.0], toe_dir)  # norm = cosine of the bone's elevation
    across_rot *= np.where(np.sum(across_level * across_rot, axis=1, keepdims=True) < 0.0, -1.0, 1.0)
    w = np.clip((np.linalg.norm(across_level, axis=1, keepdims=True) - 0.25) / 0.25, 0.0, 1.0)
    w = w * w * (3.0 - 2.0 * w)  # level below 60 deg of elevation, the source's roll above 75 deg
    across = w * unit(across_level) + (1.0 - w) * unit(across_rot)
    across = unit(across - np.sum(across * toe_dir, axis=1, keepdims=True) * toe_dir)
    frame = np.stack([toe_dir, across, np.cross(toe_dir, across)], axis=2)  # columns: images of x, y, z
    return frame @ min_rotation(unit(ball), np.array([1.0, 0.0, 0.0]))


def retarget_bvh(clip: BvhClip, params: BodyParams, **options: Any) -> Motion:
    """Retarget a BVH clip onto the humanoid of ``params``: :func:`retarget_bvh_keys` as a :class:`Motion`.

    Each humanoid body follows one BVH joint (:func:`simbench.scenes.bvh_mapping.map_bvh_joints`; both CMU naming
    schemes and common aliases are known).  A body's world rotation is the BVH joint's
    rotation since the reference pose, applied to our T-pose after aligning the bone
    directions of the two reference poses; the trunk and neck then take their XYZ hinges
    relative to the realised parent.  Limbs are solved so that the upper and lower
    segments point along the BVH bones (the elbow/knee hinge is one DoF, so the upper
    segment's twist is chosen to put the bend in the BVH's plane), and the hand/foot take
    the two wrist/ankle hinges that keep their long axis.  Every hinge is clamped to the
    model's ranges.

    Parameters
    ----------
    clip : BvhClip
        From :func:`simbench.scenes.bvh_file.load_bvh`.
    params : BodyParams
        Target subject; the BVH is scaled by the ratio of limb lengths (so any units work).
    skip_frames : int, optional
        Leading frames to drop.  Default: :func:`simbench.scenes.bvh_file.converter_lead_in`, i.e. the T-pose that the
        CMU conversions insert as frame 0 and, in the Daz/Poser-friendly ones, the few
        transition frames after it, when they are detected.
    reference : {"rest", "first_frame"}
        Pose that corresponds to our T-pose: all channels zero (the OFFSETs), or frame 0.
    up_axis : {"y", "z"}
        The file's up axis (BVH files are normally Y-up).
    face_plus_x : bool
        Turn the clip about the vertical so that the subject faces +X during its first 0.25 s.
    center_xy : bool
        Centre the root's horizontal path (bounding box) on the origin.
    foot_contact : bool
        Keep the floor contact of the source, frame by frame: our lowest sole point is put at
        the height of the source's lowest foot point above the floor
        (:attr:`RetargetedBvh.source_foot_height_m`), or on the floor where the source's
        feet go below their contact height (the root's height moves), each foot near the
        floor is put at its own source foot's height by its leg (:func:`_place_feet`), and
        our feet follow the source's ankle -> toe bones kept level across (:func:`_level_foot`).
        ``False``: the feet take the source joints' rotations as they are and the clip gets
        one height offset (the lowest sole's 25th percentile on the floor), which reproduces
        a BVH of our own humanoid exactly.
    name_map : mapping, optional
        Humanoid body -> BVH joint overrides for files with unusual names (the scenario
        field ``motion.name_map``).
    name : str, optional
        Motion name; default the file stem.

    Returns
    -------
    Motion
        Key poses at the BVH frame times, interpolated (C1) in between; the floor is at
        z = 0.
    """
    return retarget_bvh_keys(clip, params, **options).motion()
