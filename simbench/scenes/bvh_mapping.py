"""Which BVH joint each humanoid body follows (:func:`map_bvh_joints`), by name.

Both CMU naming schemes, our own body names, MotionBuilder- and 3dsMax-style names and
``mixamorig:``-style prefixes are known (:data:`ROLE_ALIASES`); a scenario's
``motion.name_map`` overrides them. The chains the retargeting follows (trunk, limbs, where
each bone ends) are defined here with the names.
"""

from __future__ import annotations

from types import MappingProxyType
from typing import Mapping

from mocap.errors import InputFileError
from simbench.scenes.bvh_file import BvhClip, is_descendant

__all__ = ["ROLE_ALIASES", "ROLES", "LIMBS", "TRUNK", "BONE_END", "map_bvh_joints"]

# Candidate BVH joint names for each humanoid role, tried in order (compared after
# _normalise_name: case, separators and namespace prefixes like "mixamorig:" ignored).
# Our own body names come first, so files written by mocap.exports.write_bvh map 1:1.
# Order matters where schemes disagree: MotionBuilder-style files call the clavicle
# "LeftShoulder" and the upper arm "LeftArm"; 3dsMax-style files call the upper arm
# "LeftShoulder" (clavicle "LeftCollar") - so "LeftArm" is tried first.
_LEFT_ALIASES: dict[str, tuple[str, ...]] = {
    "upperarm": ("upperarm_l", "LeftArm", "LeftUpArm", "LeftUpperArm", "lShldr", "L_UpperArm", "UpperArm_L", "LeftShoulder"),
    "forearm": ("forearm_l", "LeftForeArm", "LeftLowArm", "LeftLowerArm", "lForeArm", "L_Forearm", "ForeArm_L", "LeftElbow"),
    "hand": ("hand_l", "LeftHand", "LeftWrist", "lHand", "L_Hand", "Hand_L"),
    "thigh": ("thigh_l", "LeftUpLeg", "LeftUpperLeg", "LeftThigh", "lThigh", "L_Thigh", "Thigh_L", "LeftHip"),
    "shank": ("shank_l", "LeftLeg", "LeftLowLeg", "LeftLowerLeg", "LeftShin", "lShin", "L_Calf", "Shin_L", "LeftKnee"),
    "foot": ("foot_l", "LeftFoot", "LeftAnkle", "lFoot", "L_Foot", "Foot_L"),
}
_TRUNK_ALIASES: dict[str, tuple[str, ...]] = {
    "abdomen": ("abdomen", "Spine", "Abdomen", "Chest", "Spine0", "LowerBack"),
    "thorax": ("thorax", "Spine2", "Spine1", "Chest2", "UpperChest", "Chest"),
    "head": ("head",),
}


def _right_name(name: str) -> str:
    for left, right in (("Left", "Right"), ("L_", "R_"), ("_L", "_R"), ("_l", "_r"), ("l", "r")):
        if name.startswith(left) or (left.startswith("_") and name.endswith(left)):
            return name.replace(left, right, 1) if name.startswith(left) else name[: -len(left)] + right
    return name


ROLE_ALIASES: Mapping[str, tuple[str, ...]] = MappingProxyType(
    {
        **_TRUNK_ALIASES,
        **{f"{seg}_l": names for seg, names in _LEFT_ALIASES.items()},
        **{f"{seg}_r": tuple(_right_name(n) for n in names) for seg, names in _LEFT_ALIASES.items()},
    }
)
"""BVH joint names accepted for each humanoid body (first match wins); ``pelvis`` is the ROOT."""

ROLES = ("pelvis", "abdomen", "thorax", "head", "upperarm_l", "forearm_l", "hand_l", "upperarm_r", "forearm_r", "hand_r",
          "thigh_l", "shank_l", "foot_l", "thigh_r", "shank_r", "foot_r")

#: (upper, middle, end, middle hinge, end hinges, parent) of each limb, as in docs/humanoid_spec.md
LIMBS = (
    ("upperarm_l", "forearm_l", "hand_l", "elbow_l", ("wrist_l_x", "wrist_l_z"), "thorax"),
    ("upperarm_r", "forearm_r", "hand_r", "elbow_r", ("wrist_r_x", "wrist_r_z"), "thorax"),
    ("thigh_l", "shank_l", "foot_l", "knee_l", ("ankle_l_y", "ankle_l_x"), "pelvis"),
    ("thigh_r", "shank_r", "foot_r", "knee_r", ("ankle_r_y", "ankle_r_x"), "pelvis"),
)
TRUNK = (("abdomen", "pelvis", "lumbar"), ("thorax", "abdomen", "thorax"), ("head", "thorax", "neck"))
# Where each body's bone ends: the next body of its chain, or None at a chain's end (then the
# BVH's next non-zero child or End Site marks it).
BONE_END: Mapping[str, str | None] = MappingProxyType(
    {"abdomen": "thorax", "thorax": "head", "head": None}
    | {a: b for upper, middle, end, *_ in LIMBS for a, b in ((upper, middle), (middle, end), (end, None))}
)


def _normalise_name(name: str) -> str:
    base = name.rsplit(":", 1)[-1]
    return "".join(ch for ch in base.lower() if ch.isalnum())


def map_bvh_joints(clip: BvhClip, name_map: Mapping[str, str] | None = None) -> dict[str, str]:
    """Which BVH joint each humanoid body follows.

    Parameters
    ----------
    clip : BvhClip
    name_map : mapping, optional
        Overrides: humanoid body name (e.g. ``"upperarm_l"``) -> BVH joint name.  ``pelvis``
        follows the ROOT unless overridden (files whose ROOT is a reference node above the hips).
        In a scenario this is ``motion.name_map``.

    Raises
    ------
    InputFileError
        If a body has no matching joint or the matches do not form the expected chains.
    """
    by_norm: dict[str, str] = {}
    for name in clip.joint_names:
        by_norm.setdefault(_normalise_name(name), name)
    overrides = dict(name_map or {})
    unknown = sorted(set(overrides) - set(ROLES))
    if unknown:
        raise InputFileError(clip.path, f"name_map has unknown humanoid bodies {unknown}", f"use keys among: {', '.join(ROLES)}")
    for role, joint in overrides.items():
        if joint not in clip.joint_names:
            raise InputFileError(clip.path, f"name_map['{role}'] = '{joint}' is not a joint of the file",
                                 f"use one of: {', '.join(clip.joint_names)}")
    mapping = {"pelvis": overrides.get("pelvis", clip.joint_names[0])}
    missing = []
    for role in ROLES[1:]:
        if role in overrides:
            mapping[role] = overrides[role]
            continue
        taken = set(mapping.values())
        found = next((by_norm[_normalise_name(c)] for c in ROLE_ALIASES[role]
                      if _normalise_name(c) in by_norm and by_norm[_normalise_name(c)] not in taken), None)
        if found is None:
            missing.append(role)
        else:
            mapping[role] = found
    if missing:
        raise InputFileError(
            clip.path,
            f"no joint found for humanoid bodies {missing} (file joints: {', '.join(clip.joint_names)})",
            f"map them with name_map (in a scenario: [motion.name_map] {missing[0]} = \"<joint>\"); "
            "the names tried are in simbench.scenes.bvh_mapping.ROLE_ALIASES",
        )
    index = {role: clip.joint_index(name) for role, name in mapping.items()}
    for role, parent_role in [(r, p) for r, p, _ in TRUNK] + [(m, u) for u, m, *_ in LIMBS] + [(e, m) for _, m, e, *_ in LIMBS] \
            + [(u, p) for u, _, _, _, _, p in LIMBS]:
        if not is_descendant(clip.parents, index[role], index[parent_role]):
            raise InputFileError(
                clip.path,
                f"joint '{mapping[role]}' (for {role}) is not below '{mapping[parent_role]}' (for {parent_role})",
                f"map the bodies with name_map (in a scenario: [motion.name_map] {role} = \"<joint>\")",
            )
    return mapping
