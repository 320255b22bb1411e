"""BVH motion files: the parser (:func:`load_bvh`) and the converter's lead-in
(:func:`converter_lead_in`); retargeting onto the humanoid is :mod:`simbench.scenes.bvh`.

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
- Units are whatever the file uses (the retargeting finds the scale from the limb lengths).

The converter's lead-in (CMU conversions: a T-pose in frame 0; Daz/Poser-friendly ones: a few
transition frames after it) is detected by :func:`converter_lead_in`.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mocap.errors import InputFileError

__all__ = ["BvhClip", "BvhPose", "converter_lead_in", "is_descendant", "load_bvh"]

_ROTATION_CHANNELS = {"xrotation": 0, "yrotation": 1, "zrotation": 2}
_POSITION_CHANNELS = {"xposition": 0, "yposition": 1, "zposition": 2}

# Converter lead-in (converter_lead_in): an inserted frame 0 turns some joint by more than
# 20 deg towards frame 1; the transition after it is searched within the first 0.1 s.
_TPOSE_STEP_DEG = 20.0
_TRANSITION_STEP_DEG = 3.0
_LEAD_IN_S = 0.1


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


class _HierarchyReader:
    """The skeleton of a HIERARCHY section, read joint by joint (recursive descent over the tokens)."""

    def __init__(self, tokens: _Tokens) -> None:
        self.tokens = tokens
        self.names: list[str] = []
        self.parents: list[int] = []
        self.offsets: list[np.ndarray] = []
        self.channels: list[tuple[str, ...]] = []
        self.end_parents: list[int] = []
        self.end_offsets: list[np.ndarray] = []

    def read(self) -> None:
        """``ROOT name { ... }`` and nothing after it but the MOTION section."""
        tokens = self.tokens
        line = tokens.current_line
        root_word = tokens.next("'ROOT'")
        if root_word.upper() != "ROOT":
            raise tokens.error(f"expected 'ROOT', found '{root_word}'", line)
        self.read_joint(-1)
        if tokens.pos < len(tokens.items):
            raise tokens.error(
                f"unexpected '{tokens.items[tokens.pos][0]}' after the root joint's closing brace",
                fix="only one ROOT is supported; check that the braces balance",
            )
        if not tokens.motion_line:
            raise tokens.error("no MOTION section", tokens.last_line, "a BVH file needs a MOTION line after the HIERARCHY")

    def read_name(self) -> str:
        """A joint's name: the tokens up to ``{`` on its line (names may contain spaces)."""
        tokens = self.tokens
        line = tokens.current_line
        parts: list[str] = []
        while tokens.pos < len(tokens.items) and tokens.items[tokens.pos][0] != "{":
            if tokens.items[tokens.pos][1] != line:
                break
            parts.append(tokens.next("a joint name"))
        if not parts:
            raise tokens.error("joint without a name", line)
        return " ".join(parts)

    def read_joint(self, parent: int) -> None:
        """``name { OFFSET ... CHANNELS ... JOINT ... End Site ... }`` (the keyword ROOT/JOINT already read)."""
        tokens = self.tokens
        index = len(self.names)
        self.names.append(self.read_name())
        self.parents.append(parent)
        self.offsets.append(np.zeros(3))
        self.channels.append(())
        tokens.expect("{")
        seen_offset = False
        name = self.names[index]
        while True:
            line = tokens.current_line
            token = tokens.next(f"'}}' closing joint '{name}'")
            key = token.upper()
            if key == "}":
                break
            if key == "OFFSET":
                self.offsets[index] = tokens.floats(3, f"OFFSET of joint '{name}'")
                seen_offset = True
            elif key == "CHANNELS":
                self.channels[index] = self.read_channels(name, line)
            elif key == "JOINT":
                self.read_joint(index)
            elif key == "END":
                self.read_end_site(index)
            elif key == "ROOT":
                raise tokens.error("a second ROOT inside a joint", line)
            else:
                raise tokens.error(f"unexpected '{token}' in joint '{name}'", line)
        if not seen_offset:
            raise tokens.error(f"joint '{name}' has no OFFSET", line)

    def read_channels(self, joint: str, line: int) -> tuple[str, ...]:
        """``CHANNELS n name...`` after the keyword: the channel names as written."""
        tokens = self.tokens
        count_token = tokens.next("the channel count")
        try:
            count = int(count_token)
        except ValueError:
            raise tokens.error(f"CHANNELS count '{count_token}' is not an integer", line) from None
        found = tuple(tokens.next("a channel name") for _ in range(count))
        bad = [c for c in found if c.lower() not in _ROTATION_CHANNELS and c.lower() not in _POSITION_CHANNELS]
        if bad:
            raise tokens.error(
                f"unknown channel '{bad[0]}' in joint '{joint}'",
                line,
                "channels must be Xposition, Yposition, Zposition, Xrotation, Yrotation or Zrotation",
            )
        return found

    def read_end_site(self, joint: int) -> None:
        """``Site { OFFSET x y z }`` after the keyword End."""
        tokens = self.tokens
        tokens.expect("Site")
        tokens.expect("{")
        tokens.expect("OFFSET")
        self.end_offsets.append(tokens.floats(3, f"End Site OFFSET of joint '{self.names[joint]}'"))
        self.end_parents.append(joint)
        tokens.expect("}")


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
        # utf-8-sig: a byte-order mark first was "does not start with HIERARCHY (found 'HIERARCHY')", the mark unseen
        text = path.read_text(encoding="utf-8-sig", errors="replace")
    except OSError as exc:
        raise InputFileError(path, f"cannot read the file ({exc.strerror})", "give the path of an existing BVH file") from None
    lines = text.splitlines()  # handles \n, \r\n, lone \r and mixtures of them
    tokens = _Tokens(path, lines)
    first = tokens.next("'HIERARCHY'") if tokens.items else ""
    if first.upper() != "HIERARCHY":
        raise InputFileError(path, f"does not start with HIERARCHY (found '{first[:40]}')", "give a BVH motion file", field="line 1")
    skeleton = _HierarchyReader(tokens)
    skeleton.read()

    channel_counts = np.array([len(c) for c in skeleton.channels])
    channel_start = np.concatenate([[0], np.cumsum(channel_counts)[:-1]]).astype(int)
    n_frames, frame_time, data_start, frames_line = _read_motion_header(path, lines, tokens.motion_line)
    frames = _read_frames(path, lines, data_start, n_frames, int(channel_counts.sum()), frames_line)
    return BvhClip(
        path=path,
        joint_names=tuple(skeleton.names),
        parents=np.array(skeleton.parents, dtype=int),
        offsets=np.array(skeleton.offsets, dtype=float).reshape(-1, 3),
        channels=tuple(skeleton.channels),
        channel_start=channel_start,
        end_site_parents=np.array(skeleton.end_parents, dtype=int),
        end_site_offsets=np.array(skeleton.end_offsets, dtype=float).reshape(-1, 3),
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


def is_descendant(parents: np.ndarray, joint: int, ancestor: int) -> bool:
    """Whether ``joint`` lies below ``ancestor`` in the tree of ``parents`` (:attr:`BvhClip.parents`)."""
    j = int(parents[joint])
    while j >= 0:
        if j == ancestor:
            return True
        j = int(parents[j])
    return False
