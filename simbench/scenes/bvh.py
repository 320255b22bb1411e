"""BVH motion files: parsing (:func:`load_bvh`) and retargeting onto the humanoid (:func:`retarget_bvh`).

Parsing is tolerant of what real files contain (mixed CRLF/LF line endings, any rotation
channel order per joint, 6-channel roots, 3- or 6-channel joints, ``End Site`` blocks) and
strict about what makes a file unusable: every error names the file, the line and the fix.

Conventions of a BVH file, as read here
---------------------------------------
- A joint's local transform is ``T(offset) @ R`` where ``R`` is the product of its rotation
  channels in the order they are listed (``Zrotation Yrotation Xrotation`` ->
  ``Rz @ Ry @ Rx``), angles in degrees.
- Position channels (``Xposition`` ...) *replace* the matching component of the offset (the
  usual reading: roots have a zero offset, and exporters that give every joint 6 channels write
  the offset itself into the position channels).
- Units are whatever the file uses; :func:`retarget_bvh` finds the scale from the skeleton's
  limb lengths, so CMU units (1 unit = 1/0.45 inch = 5.644 cm), centimetres, inches or metres
  all work.

Retargeting, in short
---------------------
1. Map humanoid bodies to BVH joints by name (:data:`ROLE_ALIASES`; both CMU schemes, our own
   body names, ``mixamorig:``-style prefixes; ``name_map`` overrides).
2. Reference pose (the OFFSETs, or frame 0): each of our bodies is turned so that its bone
   points along the BVH's reference bone (:func:`_alignments`).
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

The converter's lead-in (CMU conversions: a T-pose in frame 0; Daz/Poser-friendly ones: a few
transition frames after it) is detected and dropped (:func:`converter_lead_in`).

A BVH written from our own humanoid (our body names, T-pose rest) retargets onto itself
exactly (``tests/test_motions_bvh.py``).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType
from typing import Mapping

import numpy as np
from scipy.spatial.transform import Rotation

from mocap.errors import InputFileError
from simbench.scenes.humanoid import BODY_NAMES, HINGE_NAMES, BodyParams
from simbench.scenes.motions import HumanoidKinematics, Motion

__all__ = [
    "BvhClip",
    "BvhPose",
    "RetargetedBvh",
    "ROLE_ALIASES",
    "converter_lead_in",
    "load_bvh",
    "map_bvh_joints",
    "retarget_bvh",
    "retarget_bvh_keys",
]

_ROTATION_CHANNELS = {"xrotation": 0, "yrotation": 1, "zrotation": 2}
_POSITION_CHANNELS = {"xposition": 0, "yposition": 1, "zposition": 2}


@dataclass(frozen=True)
class BvhPose:
    """World-space forward kinematics of a BVH skeleton (file units, file axes).

    Attributes
    ----------
    positions : (F, J, 3) float
        Joint origins in file units.
    rotations : (F, J, 3, 3) float
        Joint frames: world-from-joint rotation matrices.
    end_positions : (F, E, 3) float
        ``End Site`` points in file units.
    """

    positions: np.ndarray
    rotations: np.ndarray
    end_positions: np.ndarray


@dataclass(frozen=True)
class BvhClip:
    """A parsed BVH file: skeleton hierarchy plus the motion channels of every frame.

    Attributes
    ----------
    path : Path
        File it was read from (used in error messages).
    joint_names : tuple[str, ...], length J
        Joints in file order (depth first, so a parent always precedes its children).
    parents : (J,) int
        Index of each joint's parent; -1 for the root.
    offsets : (J, 3) float
        Joint origin in its parent's frame, file units.
    channels : tuple[tuple[str, ...], ...], length J
        Channel names of each joint as written (e.g. ``("Zrotation", "Yrotation", "Xrotation")``).
    channel_start : (J,) int
        Column of each joint's first channel in ``frames``.
    end_site_parents : (E,) int
        Joint that carries each ``End Site``.
    end_site_offsets : (E, 3) float
        ``End Site`` offsets in the carrying joint's frame, file units.
    frame_time_s : float
        Time between frames in seconds (1/120 for CMU).
    frames : (F, n_channels) float
        Channel values per frame: positions in file units, rotations in degrees.
    """

    path: Path
    joint_names: tuple[str, ...]
    parents: np.ndarray
    offsets: np.ndarray
    channels: tuple[tuple[str, ...], ...]
    channel_start: np.ndarray
    end_site_parents: np.ndarray
    end_site_offsets: np.ndarray
    frame_time_s: float
    frames: np.ndarray

    @property
    def n_frames(self) -> int:
        return int(self.frames.shape[0])

    @property
    def n_joints(self) -> int:
        return len(self.joint_names)

    @property
    def duration_s(self) -> float:
        """Time from the first to the last frame, seconds."""
        return (self.n_frames - 1) * self.frame_time_s

    def joint_index(self, name: str) -> int:
        """Index of the joint called ``name`` (exact match)."""
        try:
            return self.joint_names.index(name)
        except ValueError:
            raise InputFileError(
                self.path,
                f"no joint named '{name}'",
                f"use one of: {', '.join(self.joint_names)}",
            ) from None

    def children(self, joint: int) -> list[int]:
        """Indices of the direct child joints of ``joint``."""
        return [int(j) for j in np.flatnonzero(self.parents == joint)]

    def local_transforms(self, frames: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Local rotation and translation of every joint.

        Parameters
        ----------
        frames : (F, n_channels) float, optional
            Channel values; default: all frames of the clip.

        Returns
        -------
        rotations : (F, J, 3, 3) float
            Parent-from-joint rotations.
        translations : (F, J, 3) float
            Joint origins in the parent frame, file units.
        """
        values = self.frames if frames is None else np.atleast_2d(np.asarray(frames, dtype=float))
        n = values.shape[0]
        rotations = np.broadcast_to(np.eye(3), (n, self.n_joints, 3, 3)).copy()
        translations = np.broadcast_to(self.offsets, (n, self.n_joints, 3)).copy()
        for j, names in enumerate(self.channels):
            start = int(self.channel_start[j])
            for k, channel in enumerate(names):
                key = channel.lower()
                column = values[:, start + k]
                if key in _POSITION_CHANNELS:
                    translations[:, j, _POSITION_CHANNELS[key]] = column
                else:
                    # Compose in listed order: R = R_first @ R_second @ ... (intrinsic).
                    rotations[:, j] = rotations[:, j] @ _axis_rotation(_ROTATION_CHANNELS[key], np.deg2rad(column))
        return rotations, translations

    def forward_kinematics(self, frames: np.ndarray | None = None) -> BvhPose:
        """World pose of every joint and ``End Site`` (file units and axes).

        Parameters
        ----------
        frames : (F, n_channels) float, optional
            Channel values; default: all frames of the clip.
        """
        local_r, local_t = self.local_transforms(frames)
        world_r = np.empty_like(local_r)
        world_p = np.empty_like(local_t)
        for j, parent in enumerate(self.parents):
            if parent < 0:
                world_r[:, j] = local_r[:, j]
                world_p[:, j] = local_t[:, j]
            else:
                world_r[:, j] = world_r[:, parent] @ local_r[:, j]
                world_p[:, j] = world_p[:, parent] + np.einsum("fij,fj->fi", world_r[:, parent], local_t[:, j])
        ends = world_p[:, self.end_site_parents] + np.einsum(
            "feij,ej->fei", world_r[:, self.end_site_parents], self.end_site_offsets
        )
        return BvhPose(positions=world_p, rotations=world_r, end_positions=ends)


def _axis_rotation(axis: int, angle: np.ndarray) -> np.ndarray:
    """Rotation matrices ``(N, 3, 3)`` about coordinate axis 0/1/2 by ``angle`` (N,) radians."""
    c, s = np.cos(angle), np.sin(angle)
    out = np.zeros(angle.shape + (3, 3))
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    out[..., axis, axis] = 1.0
    out[..., i, i] = c
    out[..., j, j] = c
    out[..., i, j] = -s
    out[..., j, i] = s
    return out


class _Tokens:
    """Whitespace tokens of the HIERARCHY section, each with its 1-based line number."""

    def __init__(self, path: Path, lines: list[str]) -> None:
        self.path = path
        self.items: list[tuple[str, int]] = []
        for number, line in enumerate(lines, start=1):
            if line.strip().upper() == "MOTION":
                self.motion_line = number
                break
            self.items.extend((token, number) for token in line.split())
        else:
            self.motion_line = 0
        self.pos = 0
        self.last_line = len(lines)

    def error(self, problem: str, line: int | None = None, fix: str = "") -> InputFileError:
        line = self.current_line if line is None else line
        return InputFileError(
            self.path,
            problem,
            fix or "check the HIERARCHY section against the BVH format (ROOT/JOINT name { OFFSET x y z CHANNELS n ... })",
            field=f"line {line}",
        )

    @property
    def current_line(self) -> int:
        if self.pos < len(self.items):
            return self.items[self.pos][1]
        return self.motion_line or self.last_line

    def next(self, what: str) -> str:
        if self.pos >= len(self.items):
            raise self.error(f"file ends while expecting {what}")
        token = self.items[self.pos][0]
        self.pos += 1
        return token

    def expect(self, word: str) -> None:
        line = self.current_line
        token = self.next(f"'{word}'")
        if token.upper() != word.upper():
            raise self.error(f"expected '{word}', found '{token}'", line)

    def floats(self, n: int, what: str) -> np.ndarray:
        line = self.current_line
        values = [self.next(what) for _ in range(n)]
        try:
            out = np.array([float(v) for v in values])
        except ValueError:
            raise self.error(f"{what} needs {n} numbers, found {' '.join(values)}", line) from None
        if not np.all(np.isfinite(out)):
            raise self.error(f"{what} has a non-finite value: {' '.join(values)}", line)
        return out


def load_bvh(path: str | Path) -> BvhClip:
    """Read a BVH file.

    Parameters
    ----------
    path : str or Path
        BVH file (any line endings, any channel order).

    Returns
    -------
    BvhClip

    Raises
    ------
    InputFileError
        If the file is missing or malformed; the message names the file and the line.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8", errors="replace")
    except OSError as exc:
        raise InputFileError(path, f"cannot read the file ({exc.strerror})", "give the path of an existing BVH file") from None
    lines = text.splitlines()  # handles \n, \r\n, lone \r and mixtures of them
    tokens = _Tokens(path, lines)

    first = tokens.next("'HIERARCHY'") if tokens.items else ""
    if first.upper() != "HIERARCHY":
        raise InputFileError(path, f"does not start with HIERARCHY (found '{first[:40]}')", "give a BVH motion file", field="line 1")

    names: list[str] = []
    parents: list[int] = []
    offsets: list[np.ndarray] = []
    channels: list[tuple[str, ...]] = []
    end_parents: list[int] = []
    end_offsets: list[np.ndarray] = []

    def read_name() -> str:
        line = tokens.current_line
        parts: list[str] = []
        while tokens.pos < len(tokens.items) and tokens.items[tokens.pos][0] != "{":
            if tokens.items[tokens.pos][1] != line:
                break
            parts.append(tokens.next("a joint name"))
        if not parts:
            raise tokens.error("joint without a name", line)
        return " ".join(parts)

    def read_joint(parent: int) -> None:
        index = len(names)
        names.append(read_name())
        parents.append(parent)
        offsets.append(np.zeros(3))
        channels.append(())
        tokens.expect("{")
        seen_offset = False
        while True:
            line = tokens.current_line
            token = tokens.next(f"'}}' closing joint '{names[index]}'")
            key = token.upper()
            if key == "}":
                break
            if key == "OFFSET":
                offsets[index] = tokens.floats(3, f"OFFSET of joint '{names[index]}'")
                seen_offset = True
            elif key == "CHANNELS":
                count_token = tokens.next("the channel count")
                try:
                    count = int(count_token)
                except ValueError:
                    raise tokens.error(f"CHANNELS count '{count_token}' is not an integer", line) from None
                found = tuple(tokens.next("a channel name") for _ in range(count))
                bad = [c for c in found if c.lower() not in _ROTATION_CHANNELS and c.lower() not in _POSITION_CHANNELS]
                if bad:
                    raise tokens.error(
                        f"unknown channel '{bad[0]}' in joint '{names[index]}'",
                        line,
                        "channels must be Xposition, Yposition, Zposition, Xrotation, Yrotation or Zrotation",
                    )
                channels[index] = found
            elif key == "JOINT":
                read_joint(index)
            elif key == "END":
                tokens.expect("Site")
                tokens.expect("{")
                tokens.expect("OFFSET")
                end_offsets.append(tokens.floats(3, f"End Site OFFSET of joint '{names[index]}'"))
                end_parents.append(index)
                tokens.expect("}")
            elif key == "ROOT":
                raise tokens.error("a second ROOT inside a joint", line)
            else:
                raise tokens.error(f"unexpected '{token}' in joint '{names[index]}'", line)
        if not seen_offset:
            raise tokens.error(f"joint '{names[index]}' has no OFFSET", line)

    line = tokens.current_line
    root_word = tokens.next("'ROOT'")
    if root_word.upper() != "ROOT":
        raise tokens.error(f"expected 'ROOT', found '{root_word}'", line)
    read_joint(-1)
    if tokens.pos < len(tokens.items):
        raise tokens.error(
            f"unexpected '{tokens.items[tokens.pos][0]}' after the root joint's closing brace",
            fix="only one ROOT is supported; check that the braces balance",
        )
    if not tokens.motion_line:
        raise tokens.error("no MOTION section", tokens.last_line, "a BVH file needs a MOTION line after the HIERARCHY")

    channel_counts = np.array([len(c) for c in channels])
    channel_start = np.concatenate([[0], np.cumsum(channel_counts)[:-1]]).astype(int)
    n_channels = int(channel_counts.sum())

    n_frames, frame_time, data_start, frames_line = _read_motion_header(path, lines, tokens.motion_line)
    frames = _read_frames(path, lines, data_start, n_frames, n_channels, frames_line)

    return BvhClip(
        path=path,
        joint_names=tuple(names),
        parents=np.array(parents, dtype=int),
        offsets=np.array(offsets, dtype=float).reshape(-1, 3),
        channels=tuple(channels),
        channel_start=channel_start,
        end_site_parents=np.array(end_parents, dtype=int),
        end_site_offsets=np.array(end_offsets, dtype=float).reshape(-1, 3),
        frame_time_s=frame_time,
        frames=frames,
    )


def _read_motion_header(path: Path, lines: list[str], motion_line: int) -> tuple[int, float, int, int]:
    """Parse ``Frames: N`` and ``Frame Time: dt``.

    Returns N, dt, the 0-based index of the first data line and the 1-based line of ``Frames:``.
    """
    index = motion_line  # 0-based index of the line after MOTION
    header: dict[str, tuple[str, int]] = {}
    while index < len(lines) and len(header) < 2:
        stripped = lines[index].strip()
        index += 1
        if not stripped:
            continue
        label, _, value = stripped.partition(":")
        key = "".join(label.lower().split())
        if key not in ("frames", "frametime"):
            raise InputFileError(
                path, f"expected 'Frames:' or 'Frame Time:', found '{stripped[:40]}'",
                "write 'Frames: N' and 'Frame Time: seconds' after MOTION", field=f"line {index}",
            )
        header[key] = (value.strip(), index)
    for key, label in (("frames", "Frames:"), ("frametime", "Frame Time:")):
        if key not in header:
            raise InputFileError(path, f"no '{label}' line after MOTION", f"add '{label}' after MOTION", field=f"line {motion_line}")
    value, line = header["frames"]
    try:
        n_frames = int(value)
    except ValueError:
        n_frames = -1
    if n_frames < 1:
        raise InputFileError(path, f"Frames: '{value}' is not a positive integer", "give the number of frames", field=f"line {line}")
    value, line = header["frametime"]
    try:
        frame_time = float(value)
    except ValueError:
        frame_time = float("nan")
    if not (np.isfinite(frame_time) and frame_time > 0):
        raise InputFileError(path, f"Frame Time: '{value}' is not a positive number of seconds", "e.g. 'Frame Time: 0.0083333' for 120 Hz", field=f"line {line}")
    return n_frames, frame_time, index, header["frames"][1]


def _read_frames(path: Path, lines: list[str], start: int, n_frames: int, n_channels: int, frames_line: int) -> np.ndarray:
    """Motion rows ``(n_frames, n_channels)``; errors name the first bad line."""
    rows = [(number, line) for number, line in enumerate(lines[start:], start=start + 1) if line.strip()]
    if len(rows) < n_frames:
        raise InputFileError(
            path, f"'Frames: {n_frames}' but only {len(rows)} data lines",
            "correct the Frames: line or restore the missing frames", field=f"line {frames_line}",
        )
    if len(rows) > n_frames:
        number = rows[n_frames][0]
        raise InputFileError(
            path, f"'Frames: {n_frames}' but {len(rows)} data lines",
            "correct the Frames: line or remove the extra lines", field=f"line {number}",
        )
    split = [line.split() for _, line in rows]
    counts = np.fromiter((len(s) for s in split), dtype=int, count=len(split))
    bad = np.flatnonzero(counts != n_channels)
    if bad.size:
        number = rows[int(bad[0])][0]
        raise InputFileError(
            path, f"frame has {counts[bad[0]]} values but the HIERARCHY declares {n_channels} channels",
            "every frame line needs one value per channel", field=f"line {number}",
        )
    try:
        frames = np.array([v for s in split for v in s], dtype=float).reshape(n_frames, n_channels)
    except ValueError:
        frames = None
    if frames is None or not np.all(np.isfinite(frames)):
        for (number, _), values in zip(rows, split):
            try:
                ok = np.all(np.isfinite(np.array(values, dtype=float)))
            except ValueError:
                ok = False
            if not ok:
                raise InputFileError(path, "frame has a value that is not a finite number", "fix or remove that frame", field=f"line {number}")
    return frames


# ======================================================================================
# retargeting onto the simbench humanoid
# ======================================================================================

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

_ROLES = ("pelvis", "abdomen", "thorax", "head", "upperarm_l", "forearm_l", "hand_l", "upperarm_r", "forearm_r", "hand_r",
          "thigh_l", "shank_l", "foot_l", "thigh_r", "shank_r", "foot_r")

# (upper, middle, end, middle hinge, end hinges) of each limb, as in docs/humanoid_spec.md
_LIMBS = (
    ("upperarm_l", "forearm_l", "hand_l", "elbow_l", ("wrist_l_x", "wrist_l_z"), "thorax"),
    ("upperarm_r", "forearm_r", "hand_r", "elbow_r", ("wrist_r_x", "wrist_r_z"), "thorax"),
    ("thigh_l", "shank_l", "foot_l", "knee_l", ("ankle_l_y", "ankle_l_x"), "pelvis"),
    ("thigh_r", "shank_r", "foot_r", "knee_r", ("ankle_r_y", "ankle_r_x"), "pelvis"),
)
_TRUNK = (("abdomen", "pelvis", "lumbar"), ("thorax", "abdomen", "thorax"), ("head", "thorax", "neck"))
# Where each body's bone ends: the next body of its chain, or None at a chain's end (then the
# BVH's next non-zero child or End Site marks it).
_BONE_END: Mapping[str, str | None] = MappingProxyType(
    {"abdomen": "thorax", "thorax": "head", "head": None}
    | {a: b for upper, middle, end, *_ in _LIMBS for a, b in ((upper, middle), (middle, end), (end, None))}
)
_AXIS_LETTER = "XYZ"
_BODY_INDEX = {name: i for i, name in enumerate(BODY_NAMES)}

# Bending weight of a limb: below sin(5 deg) of flexion the bend plane is undefined and the
# upper segment's twist follows the BVH rotation; above sin(20 deg) it follows the bend plane.
_BEND_SIN_LO, _BEND_SIN_HI = np.sin(np.deg2rad(5.0)), np.sin(np.deg2rad(20.0))

# Converter lead-in (converter_lead_in): an inserted frame 0 turns some joint by more than
# 20 deg towards frame 1; the transition after it is searched within the first 0.1 s.
_TPOSE_STEP_DEG = 20.0
_TRANSITION_STEP_DEG = 3.0
_LEAD_IN_S = 0.1

# Floor contact: a foot point's height when its foot is on the floor is its 5th percentile
# over the clip (every clip has its feet on the floor for far more than 5 % of its frames).
_CONTACT_PERCENTILE = 5.0
# Legs are bent or stretched to put a foot at its source foot's height (_place_feet) where
# that foot is within 2 cm of the floor, blending out up to 6 cm (feet in the air keep the
# source's limb directions); for a 1.75 m subject, i.e. as fractions of the standing hip height
# (0.93 m), so that every body size gets the same joint angles.
_FOOT_IK_FULL = 0.02 / 0.93
_FOOT_IK_BLEND = 0.04 / 0.93


def _normalise_name(name: str) -> str:
    base = name.rsplit(":", 1)[-1]
    return "".join(ch for ch in base.lower() if ch.isalnum())


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
    unknown = sorted(set(overrides) - set(_ROLES))
    if unknown:
        raise InputFileError(clip.path, f"name_map has unknown humanoid bodies {unknown}", f"use keys among: {', '.join(_ROLES)}")
    for role, joint in overrides.items():
        if joint not in clip.joint_names:
            raise InputFileError(clip.path, f"name_map['{role}'] = '{joint}' is not a joint of the file",
                                 f"use one of: {', '.join(clip.joint_names)}")
    mapping = {"pelvis": overrides.get("pelvis", clip.joint_names[0])}
    missing = []
    for role in _ROLES[1:]:
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
            "the names tried are in simbench.scenes.bvh.ROLE_ALIASES",
        )
    index = {role: clip.joint_index(name) for role, name in mapping.items()}
    for role, parent_role in [(r, p) for r, p, _ in _TRUNK] + [(m, u) for u, m, *_ in _LIMBS] + [(e, m) for _, m, e, *_ in _LIMBS] \
            + [(u, p) for u, _, _, _, _, p in _LIMBS]:
        if not _is_descendant(clip.parents, index[role], index[parent_role]):
            raise InputFileError(
                clip.path,
                f"joint '{mapping[role]}' (for {role}) is not below '{mapping[parent_role]}' (for {parent_role})",
                f"map the bodies with name_map (in a scenario: [motion.name_map] {role} = \"<joint>\")",
            )
    return mapping


def _is_descendant(parents: np.ndarray, joint: int, ancestor: int) -> bool:
    j = int(parents[joint])
    while j >= 0:
        if j == ancestor:
            return True
        j = int(parents[j])
    return False


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


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-12)


def _min_rotation(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Smallest rotation matrix ``(3, 3)`` taking unit vector ``a`` to unit vector ``b``."""
    axis = np.cross(a, b)
    s, c = np.linalg.norm(axis), float(np.dot(a, b))
    if s < 1e-12:
        if c > 0:
            return np.eye(3)
        perp = _unit(np.cross(a, [1.0, 0.0, 0.0] if abs(a[0]) < 0.9 else [0.0, 1.0, 0.0]))
        return Rotation.from_rotvec(np.pi * perp).as_matrix()
    return Rotation.from_rotvec(axis / s * np.arctan2(s, c)).as_matrix()


def _rz(angle: float) -> np.ndarray:
    return Rotation.from_euler("z", angle).as_matrix()


def _heading(forward: np.ndarray) -> np.ndarray:
    """Heading angle(s) of horizontal direction(s) ``(..., 3)`` in the bench world (0 = +X)."""
    return np.arctan2(forward[..., 1], forward[..., 0])


def converter_lead_in(clip: BvhClip) -> int:
    """Number of leading frames a BVH converter added before the capture (0 if none).

    cgspeed's CMU conversions insert a T-pose as frame 0; its Daz/Poser-friendly ones then
    blend into the capture over a few frames (joints turning 20-40 deg per frame where the
    capture itself turns a few).  Both are found from the largest joint rotation between
    consecutive frames (geodesic angle of the local rotations, so Euler wraps do not count):

    - frame 0 is inserted if its step to frame 1 exceeds :data:`_TPOSE_STEP_DEG` and five
      times the ordinary step (the median over the second after the lead-in window);
    - the transition then ends after the last step within :data:`_LEAD_IN_S` of the start
      that exceeds ``max(_TRANSITION_STEP_DEG, 4 x ordinary)``.

    Returns
    -------
    int
        Frames to drop: 0 (no inserted pose), 1 (T-pose only) or more (T-pose + transition).
    """
    scan = max(2, int(round(_LEAD_IN_S / clip.frame_time_s)))
    n = min(clip.n_frames, scan + 2 + int(round(1.0 / clip.frame_time_s)))
    if clip.n_frames < 4:
        return 0
    local, _ = clip.local_transforms(clip.frames[:n])
    cos = (np.einsum("fjab,fjab->fj", local[:-1], local[1:]) - 1.0) / 2.0
    steps = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))).max(axis=1)  # (n-1,) largest joint turn per frame
    after = steps[scan + 1:] if len(steps) > scan + 1 else steps[1:]
    ordinary = float(np.median(after))
    if not (steps[0] > _TPOSE_STEP_DEG and steps[0] > 5.0 * ordinary):
        return 0
    threshold = max(_TRANSITION_STEP_DEG, 4.0 * ordinary)
    jumps = np.flatnonzero(steps[1:scan + 1] > threshold)
    return 1 + (int(jumps[-1]) + 1 if jumps.size else 0)


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
    idx = {role: clip.joint_index(j) for role, j in joint_map.items()}

    first = converter_lead_in(clip) if skip_frames is None else int(skip_frames)
    if first < 0:
        raise ValueError(f"skip_frames must be >= 0, got {skip_frames!r}")
    if clip.n_frames - first < 2:
        raise InputFileError(clip.path, f"only {clip.n_frames} frame(s), {first} of them skipped",
                             "a motion needs at least two frames after the converter's T-pose and transition")
    keep = np.arange(first, clip.n_frames)
    # BVH axes -> bench axes: Y-up files have the subject's up on +Y; the bench is Z-up.
    axes = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]) if up_axis == "y" else np.eye(3)
    ref = clip.forward_kinematics(np.zeros((1, clip.frames.shape[1])) if reference == "rest" else clip.frames[:1])
    pose = clip.forward_kinematics(clip.frames[keep])

    def bone(p: BvhPose, role: str) -> np.ndarray:
        """BVH bone vector ``(F, 3)`` of a humanoid body, file units, bench axes."""
        start = p.positions[:, idx[role]]
        end_role = _BONE_END[role]
        end = p.positions[:, idx[end_role]] if end_role else _chain_end(clip, p.positions, p.end_positions, idx[role])
        return (end - start) @ axes.T

    # Scale: limb lengths of the model over those of the skeleton (any units).  Limbs rather
    # than stature: where a BVH's head end site sits varies between skeletons (CMU's is ~10 cm
    # below the vertex), while joint-centre distances are what the retargeted motion must fit.
    limbs = [r for u, m, *_ in _LIMBS for r in (u, m)]
    bvh_total = sum(np.linalg.norm(bone(ref, r)[0]) for r in limbs)
    if not bvh_total > 0:
        raise InputFileError(clip.path, "the limbs of the skeleton have zero length", "check the OFFSETs of the arm and leg joints")
    body_pos = kin.model.body_pos
    scale = sum(np.linalg.norm(body_pos[kin.model.body(_BONE_END[r]).id]) for r in limbs) / bvh_total

    left = (ref.positions[0, idx["thigh_l"]] - ref.positions[0, idx["thigh_r"]]) @ axes.T
    psi_ref = float(_heading(left)) - 0.5 * np.pi  # left side towards +Y means facing +X
    ref_dirs = {r: _unit(bone(ref, r)[0]) for r in _BONE_END}
    align = _alignments(kin, ref_dirs, psi_ref)

    # Target world rotation of every body: the BVH joint's rotation since the reference pose,
    # applied to our body as it sits in that reference pose.
    targets = {}
    for role in _ROLES:
        relative = pose.rotations[:, idx[role]] @ ref.rotations[0, idx[role]].T
        targets[role] = axes @ relative @ axes.T @ align[role]
    heading = np.eye(3)
    if face_plus_x:
        n0 = max(1, min(len(keep), int(round(0.25 / clip.frame_time_s))))
        psi = _heading(targets["pelvis"][:n0, :, 0])
        heading = _rz(-float(np.arctan2(np.mean(np.sin(psi)), np.mean(np.cos(psi)))))
    targets = {r: heading @ t for r, t in targets.items()}
    directions = {r: _unit(bone(pose, r) @ heading.T) for r in _BONE_END}
    if foot_contact:
        for foot in ("foot_l", "foot_r"):
            targets[foot] = _level_foot(targets[foot], directions[foot], float(ref_dirs[foot][2]))

    hinges = _solve_hinges(kin, targets, directions)
    world_from_file = heading @ axes
    hip_mid = 0.5 * (pose.positions[:, idx["thigh_l"]] + pose.positions[:, idx["thigh_r"]])
    qpos = np.zeros((len(keep), len(HINGE_NAMES) + 7))
    qpos[:, :3] = scale * hip_mid @ world_from_file.T
    qpos[:, 3:7] = Rotation.from_matrix(targets["pelvis"]).as_quat(scalar_first=True)
    qpos[:, 7:] = hinges

    # Floor.  The source's feet: each foot point (ankle, toes, End Sites) measured from its own
    # floor-contact height, the lowest of them per frame is how high the source's feet are
    # above the floor.  The file's own floor (y = 0) is not trusted: the Daz conversions stand
    # 6-9 cm above or below it.  to_world() puts the lowest contact height at z = 0.
    per_foot = []  # (K,) per foot: its lowest point above its contact height, metres
    lowest_contact = np.inf
    for foot in ("foot_l", "foot_r"):
        heights = scale * (_foot_points(clip, pose, idx[foot]) @ world_from_file.T)[..., 2]  # (K, P) m
        contact = np.percentile(heights, _CONTACT_PERCENTILE, axis=0)  # (P,) m
        per_foot.append((heights - contact).min(axis=1))
        lowest_contact = min(lowest_contact, float(contact.min()))
    source_feet = np.stack(per_foot, axis=1)  # (K, 2)
    source_height = source_feet.min(axis=1)  # (K,)
    translation = np.zeros(3)
    translation[2] = -lowest_contact
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
        lift = np.full(len(keep), -float(np.percentile(sole, 25.0)))
    qpos[:, 2] = raw_z + lift

    return RetargetedBvh(
        name=name or clip.path.stem,
        times_s=(keep - keep[0]) * clip.frame_time_s,
        qpos=qpos,
        joint_map=joint_map,
        frames=keep,
        scale_m_per_unit=float(scale),
        world_from_file=world_from_file,
        translation_m=translation,
        root_lift_m=lift,
        source_foot_height_m=source_height,
        kinematics=kin,
    )


def _foot_points(clip: BvhClip, pose: BvhPose, foot: int) -> np.ndarray:
    """The source's points of one foot ``(F, P, 3)``, file units and axes: the foot joint,
    every joint below it (toes) and their End Sites."""
    joints = [j for j in range(clip.n_joints) if j == foot or _is_descendant(clip.parents, j, foot)]
    sites = [e for e, parent in enumerate(clip.end_site_parents) if parent in joints]
    return np.concatenate([pose.positions[:, joints], pose.end_positions[:, sites]], axis=1)


def _place_feet(kin: HumanoidKinematics, qpos: np.ndarray, targets: dict[str, np.ndarray],
                directions: dict[str, np.ndarray], wanted: np.ndarray) -> np.ndarray:
    """Bend or stretch each leg so that its foot's lowest sole point goes to ``wanted``.

    Two-bone inverse kinematics on our own segment lengths: the ankle moves vertically by the
    height error (the foot keeps its orientation target), the knee stays on its side of the
    hip-ankle line, and the leg is solved again from the new thigh and shank directions by
    :func:`_solve_hinges` (joint ranges included), twice, since the ankle's range can change
    the foot's tilt once the shank moves.  Used where the source's foot is on or near the
    floor: without it, a foot our joint ranges leave on its toe corner holds the root up and
    the other foot hovers above the floor where the source's stands on it.

    Parameters
    ----------
    qpos : (K, 40)
        Poses; only the hinges change.
    targets, directions : dict
        As for :func:`_solve_hinges`; the legs' directions are replaced.
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
            u = _unit(reach)
            w = _unit(np.cross(u, axis))  # the side a flexed knee lies on
            cos_a = np.clip((l1 * l1 + d * d - l2 * l2) / (2.0 * l1 * d), -1.0, 1.0)
            new_knee = l1[:, None] * (cos_a[:, None] * u + np.sqrt(1.0 - cos_a * cos_a)[:, None] * w)
            moved = dz != 0.0  # feet away from the floor (no height wanted) keep the source's directions
            dirs[f"thigh_{side}"] = np.where(moved[:, None], _unit(new_knee), dirs[f"thigh_{side}"])
            dirs[f"shank_{side}"] = np.where(moved[:, None], _unit(d[:, None] * u - new_knee), dirs[f"shank_{side}"])
        qpos[:, 7:] = _solve_hinges(kin, targets, dirs)
    return qpos


def _level_foot(target: np.ndarray, toe_dir: np.ndarray, ref_pitch_sin: float) -> np.ndarray:
    """Foot orientations ``(F, 3, 3)`` that follow the source's ankle -> toe bone, level across.

    A foot's roll about its long axis cannot be seen in a BVH's foot points (ankle, toes and
    End Site lie on one line), and the joint rotations that carry it are unreliable: the Daz
    conversions stand on feet rolled by up to 40 deg while ankle and toe sit at their floor
    heights, which put our soles on one corner and lifted the other foot off the floor.  So
    our foot takes the direction and pitch of the source's ankle -> toe bone (its pitch in the
    reference pose counting as a flat foot, as in :func:`_alignments`) with its lateral axis
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
    across = w * _unit(across_level) + (1.0 - w) * _unit(across_rot)
    across = _unit(across - np.sum(across * toe_dir, axis=1, keepdims=True) * toe_dir)
    frame = np.stack([toe_dir, across, np.cross(toe_dir, across)], axis=2)  # columns: images of x, y, z
    return frame @ _min_rotation(_unit(ball), np.array([1.0, 0.0, 0.0]))


def _our_bone_axis(kin: HumanoidKinematics, role: str) -> np.ndarray:
    """Unit bone axis of a humanoid body in its own frame (= its T-pose world direction)."""
    end = _BONE_END[role]
    if role in ("abdomen", "thorax", "head"):
        return np.array([0.0, 0.0, 1.0])
    if role.startswith("foot"):
        return _unit(kin.ball_of_foot_local * (1.0, 1.0 if role.endswith("_l") else -1.0, 1.0))
    if role.startswith("hand"):
        return _our_bone_axis(kin, role.replace("hand", "forearm"))  # the hand continues the forearm
    return _unit(kin.model.body_pos[kin.model.body(end).id])


def _alignments(kin: HumanoidKinematics, ref_dirs: dict[str, np.ndarray], psi_ref: float) -> dict[str, np.ndarray]:
    """Orientation ``(3, 3)`` of each humanoid body when the BVH is in its reference pose.

    The pelvis only turns to the reference heading; trunk, head and limb segments turn their
    bone axis onto the BVH's reference bone (smallest rotation after the heading turn); hands
    and feet keep their reference relation to the forearm / shank (CMU rest skeletons splay
    the legs ~20 deg with the feet rolled along, so aligning the feet on their own would leave
    them rolled by as much once the legs are straight), except for the foot's pitch: the
    reference ankle -> toe-base bone gets the pitch of our ankle -> ball-of-foot direction
    (CMU rest feet are ~10 deg dorsiflexed compared with a foot flat on the floor).
    """
    turn = _rz(psi_ref)
    align: dict[str, np.ndarray] = {"pelvis": turn}
    for role in _ROLES[1:]:
        if not role.startswith(("hand", "foot")):
            align[role] = _min_rotation(turn @ _our_bone_axis(kin, role), ref_dirs[role]) @ turn
    for _, middle, end, *_ in _LIMBS:
        align[end] = align[middle]
    ball = kin.ball_of_foot_local
    for foot in ("foot_l", "foot_r"):
        v = align[foot].T @ ref_dirs[foot]
        pitch = np.arctan2(-v[2], v[0]) - np.arctan2(-ball[2], ball[0])
        align[foot] = align[foot] @ Rotation.from_euler("y", pitch).as_matrix()
    return align


def _solve_hinges(kin: HumanoidKinematics, targets: dict[str, np.ndarray], directions: dict[str, np.ndarray]) -> np.ndarray:
    """Hinge angles ``(F, 33)`` that realise the target body rotations, parents first.

    Parameters
    ----------
    targets : dict body -> (F, 3, 3)
        Wanted world rotation of each body.
    directions : dict body -> (F, 3)
        Wanted world direction of each bone (unit).
    """
    n = len(targets["pelvis"])
    hinges = np.zeros((n, len(HINGE_NAMES)))
    column = {name: i for i, name in enumerate(HINGE_NAMES)}
    world = {"pelvis": targets["pelvis"]}

    def set_joint(names: tuple[str, ...], local: np.ndarray) -> np.ndarray:
        """Decompose ``local`` (F, 3, 3) into the hinges ``names`` (intrinsic, in hinge order; a
        missing axis goes last and is dropped), unwrap over time, clamp to the ranges; return
        the rotation the clamped hinges make."""
        axes_seq = [_joint_axis(kin, h) for h in names]
        free = [a for a in "XYZ" if a not in axes_seq]
        euler = Rotation.from_matrix(local).as_euler("".join(axes_seq + free))
        cols = [column[h] for h in names]
        unwrapped = np.unwrap(euler[:, : len(names)], axis=0)
        values = np.clip(unwrapped, kin.hinge_lo[cols], kin.hinge_hi[cols])
        if len(names) == 2:
            # Wrist and ankle: the dropped axis (the hand's long axis, the sole's normal) is what
            # the two hinges keep.  Where the first hinge hit its range, the second takes the
            # angle that brings that axis closest to its target (the decomposition's own second
            # angle where nothing is clamped), e.g. an ankle at its dorsiflexion limit still
            # levels the foot across.
            kept = np.eye(3)[_AXIS_LETTER.index(free[0])]
            second_axis = np.eye(3)[_AXIS_LETTER.index(axes_seq[1])]
            first = Rotation.from_euler(axes_seq[0], values[:, :1]).as_matrix()
            m = np.einsum("fji,fj->fi", first, local @ kept)  # the kept axis's target, in the first hinge's frame
            second = np.arctan2(m @ np.cross(second_axis, kept), m @ kept)
            second += 2.0 * np.pi * np.round((unwrapped[:, 1] - second) / (2.0 * np.pi))  # the same branch
            values[:, 1] = np.clip(second, kin.hinge_lo[cols[1]], kin.hinge_hi[cols[1]])
        hinges[:, cols] = values
        return Rotation.from_euler("".join(axes_seq), values).as_matrix()

    for role, parent, prefix in _TRUNK:
        local = np.swapaxes(world[parent], 1, 2) @ targets[role]
        world[role] = world[parent] @ set_joint((f"{prefix}_x", f"{prefix}_y", f"{prefix}_z"), local)

    for upper, middle, end, mid_hinge, end_hinges, parent in _LIMBS:
        side = upper[-1]
        joint = "shoulder" if upper.startswith("upperarm") else "hip"
        u = _our_bone_axis(kin, upper)
        e_h = kin.model.jnt_axis[kin.model.joint(mid_hinge).id].copy()
        lo, hi = kin.hinge_range(mid_hinge)
        flex = 1.0 if abs(hi) > abs(lo) else -1.0
        d2 = directions[middle]
        q1 = _limb_upper_rotation(directions[upper], d2, targets[upper], u, e_h, flex)
        local = np.swapaxes(world[parent], 1, 2) @ q1
        q1 = world[parent] @ set_joint((f"{joint}_{side}_x", f"{joint}_{side}_y", f"{joint}_{side}_z"), local)
        # the hinge angle that best reaches the lower bone's direction from the realised upper segment
        axis_w, u_w = q1 @ e_h, q1 @ u
        d2p = d2 - np.sum(d2 * axis_w, axis=1, keepdims=True) * axis_w
        theta = np.arctan2(np.sum(np.cross(u_w, d2p) * axis_w, axis=1), np.sum(u_w * d2p, axis=1))
        theta = np.clip(theta, lo, hi)
        hinges[:, column[mid_hinge]] = theta
        q2 = q1 @ Rotation.from_rotvec(theta[:, None] * e_h).as_matrix()
        set_joint(end_hinges, np.swapaxes(q2, 1, 2) @ targets[end])
    return hinges


def _joint_axis(kin: HumanoidKinematics, hinge: str) -> str:
    axis = kin.model.jnt_axis[kin.model.joint(hinge).id]
    k = int(np.argmax(np.abs(axis)))
    if not np.isclose(axis[k], 1.0):  # the spec: hinges about +x, +y or +z of the body frame
        raise RuntimeError(f"hinge {hinge} is not about a positive body axis; update simbench.scenes.bvh")
    return _AXIS_LETTER[k]


def _limb_upper_rotation(d1, d2, target, u, e_h, flex):
    """World rotation ``(F, 3, 3)`` of a limb's upper segment.

    The bone axis ``u`` goes to the BVH direction ``d1``; the twist about it puts the hinge
    axis ``e_h`` normal to the plane of ``d1`` and ``d2`` (so the one-DoF elbow/knee can
    reach ``d2``) when the limb is bent, and follows the BVH segment's own rotation
    (``target``) when it is nearly straight, with a smooth blend in between.
    """
    normal = np.cross(d1, d2)
    n_rot = target @ e_h
    n_rot = _unit(n_rot - np.sum(n_rot * d1, axis=1, keepdims=True) * d1)
    bend = flex * np.sum(normal * n_rot, axis=1)  # sine of the flexion seen in the BVH segment's bend plane
    w = np.clip((bend - _BEND_SIN_LO) / (_BEND_SIN_HI - _BEND_SIN_LO), 0.0, 1.0)
    w = (w * w * (3.0 - 2.0 * w))[:, None]
    n = _unit(w * flex * _unit(normal) + (1.0 - w) * n_rot)
    n = _unit(n - np.sum(n * d1, axis=1, keepdims=True) * d1)
    u_perp = _unit(u - np.dot(u, e_h) * e_h)
    local = np.stack([u_perp, e_h, np.cross(u_perp, e_h)], axis=0)  # rows: the three local vectors
    world = np.stack([d1, n, np.cross(d1, n)], axis=2)  # columns: their world images
    return world @ local


def retarget_bvh(
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
) -> Motion:
    """Retarget a BVH clip onto the humanoid of ``params``.

    Each humanoid body follows one BVH joint (:func:`map_bvh_joints`; both CMU naming
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
        From :func:`load_bvh`.
    params : BodyParams
        Target subject; the BVH is scaled by the ratio of limb lengths (so any units work).
    skip_frames : int, optional
        Leading frames to drop.  Default: :func:`converter_lead_in`, i.e. the T-pose that the
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
    return retarget_bvh_keys(
        clip, params, skip_frames=skip_frames, reference=reference, up_axis=up_axis,
        face_plus_x=face_plus_x, center_xy=center_xy, foot_contact=foot_contact, name_map=name_map, name=name,
    ).motion()
