"""BVH of the solved skeleton: the humanoid's hierarchy, Y up by default, centimetres, degrees."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Literal

import numpy as np
from scipy.spatial.transform import Rotation

from mocap.errors import MocapInputError
from mocap.atomic_files import atomic_target
from mocap.exports._common import _Z_UP_TO_Y_UP, _rate
from mocap.skeleton_fit import KinematicTree, SkeletonFit
from mocap.subject import SubjectModel

_AXIS_NAMES = "XYZ"


def _hinge_channel(axis: np.ndarray, P: np.ndarray, where: str) -> tuple[int, float]:
    """BVH channel (0 = X, 1 = Y, 2 = Z) and sign of a hinge axis given in body coordinates."""
    a = P @ axis
    k = int(np.argmax(np.abs(a)))
    if abs(abs(a[k]) - 1.0) > 1e-6:
        raise MocapInputError(f"{where}: hinge axis {axis.round(4).tolist()} is not a body axis; BVH channels rotate about X, Y or Z only")
    return k, float(np.sign(a[k]))


def write_bvh(
    path: str | os.PathLike,
    fit: SkeletonFit,
    subject: SubjectModel,
    *,
    up_axis: Literal["y", "z"] = "y",
    rate_hz: float | None = None,
) -> Path:
    """Write the solved skeleton as BVH: the humanoid's hierarchy and one frame per sample.

    * Hierarchy: one ``JOINT`` per MJCF body (``ROOT`` = the pelvis), ``OFFSET`` = the body's
      MJCF position in its parent (cm), the root's 0 (its position channels carry the free
      joint's position, which is the pelvis origin in the world); leaves get an ``End Site`` at their farthest marker
      (or 10 cm along the parent bone if they carry none).
    * Channels: the root has ``Xposition Yposition Zposition`` (cm) and ``Zrotation
      Yrotation Xrotation``; every other joint has three rotation channels: its hinges in
      qpos order (a hinge about body axis ``a`` becomes the rotation channel about the BVH
      axis ``a`` maps to), followed by the axes it does not have, which stay 0. A joint's
      rotation is the product of its channels in the listed order, so ``R = Rx Ry Rz`` of the
      contract is written exactly (``Xrotation Yrotation Zrotation``).
    * Axes: ``up_axis="y"`` (default, the BVH custom): ``(x, y, z)_bvh = (x, z, -y)_world``, so
      the body's Y axis becomes -Z (a hinge about Y is written as a Zrotation with its sign
      flipped) and Z becomes Y. ``up_axis="z"``: the world axes unchanged.
    * ``Frame Time`` = ``1 / rate_hz`` (default: the fit's rate, from its timestamps). Frames the fit could not solve repeat the nearest
      solved frame (BVH has no way to mark a gap).

    Parameters
    ----------
    path : path-like
    fit : SkeletonFit
        From :func:`mocap.skeleton.solve_skeleton` on ``subject``.
    subject : SubjectModel
    up_axis : {"y", "z"}
    rate_hz : float, optional
        Needed only for a single-frame fit.

    Returns
    -------
    Path
    """
    path = Path(path)
    P = _bvh_axes(path, fit, subject, up_axis)
    rate = _rate(fit.times, rate_hz, str(path))
    qpos = _nearest_solved_qpos(fit.qpos, fit.valid)
    channel_names, columns = _bvh_root_channels(qpos, P)
    for b in range(1, len(fit.tree.body_names)):
        names, cols = _bvh_joint_channels(b, fit.tree, qpos, P, path)
        channel_names.append(names)
        columns.append(cols)
    lines = ["HIERARCHY", *_bvh_hierarchy(fit.tree, channel_names, _bvh_end_sites(fit.tree, subject), P)]
    lines += ["MOTION", f"Frames: {len(fit.times)}", f"Frame Time: {1.0 / rate:.8f}"]
    motion = np.concatenate(columns, axis=1)
    import pandas as pd  # here, not at the top: see mocap/exports/trc.py

    body = pd.DataFrame(motion).to_csv(sep=" ", header=False, index=False, float_format="%.6f", lineterminator="\n")
    with atomic_target(path) as tmp:
        tmp.write_text("\n".join(lines) + "\n" + body)
    return path


def _bvh_axes(path: Path, fit: SkeletonFit, subject: SubjectModel, up_axis: str) -> np.ndarray:
    """Check that ``fit`` can be written as BVH for ``subject``; the axis change for ``up_axis``.

    Returns
    -------
    P : (3, 3) float
        ``v_bvh = P @ v_world`` (Y up: :data:`_Z_UP_TO_Y_UP`; Z up: the identity).
    """
    tree = fit.tree
    if tree.body_names != subject.body_names:
        raise MocapInputError(f"{path}: the fit's bodies {tree.body_names} are not the subject's {subject.body_names}; write the BVH with the subject the fit was solved with")
    if tree.rest_rotation:
        raise MocapInputError(f"{path}: a body of the MJCF has a rest orientation; BVH export needs body frames aligned with the world in the rest pose (docs/humanoid_spec.md)")
    if up_axis == "y":
        P = _Z_UP_TO_Y_UP
    elif up_axis == "z":
        P = np.eye(3)
    else:
        raise MocapInputError(f"{path}: up_axis must be 'y' or 'z', got {up_axis!r}")
    if not fit.valid.any():
        raise MocapInputError(f"{path}: no frame of the fit was solved, nothing to write; check the marker labels and min_markers")
    return P


def _nearest_solved_qpos(qpos: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """``qpos (F, nq)`` with each unsolved frame replaced by the nearest solved one (the earlier on a tie).

    ``valid (F,) bool`` marks the solved frames; at least one must be. Returns ``(F, nq)``.
    """
    F = len(valid)
    ok = np.flatnonzero(valid)
    nearest = ok[np.clip(np.searchsorted(ok, np.arange(F)), 0, len(ok) - 1)]
    left = ok[np.clip(np.searchsorted(ok, np.arange(F)) - 1, 0, len(ok) - 1)]
    use = np.where(np.abs(left - np.arange(F)) <= np.abs(nearest - np.arange(F)), left, nearest)
    return qpos[use]


def _bvh_root_channels(qpos: np.ndarray, P: np.ndarray) -> tuple[list[list[str]], list[np.ndarray]]:
    """The root's six channels from the free joint of ``qpos (F, nq)`` (position m, quaternion w-first).

    Returns ``([names], [values (F, 6)])``: position in cm in BVH axes (``P @ x``), then the
    ``Zrotation Yrotation Xrotation`` Euler angles (degrees) of ``P R P^T``; lists so that the
    joints' channels can be appended.
    """
    root_pos = qpos[:, :3] @ P.T * 100.0  # cm
    root_R = P @ Rotation.from_quat(qpos[:, 3:7], scalar_first=True).as_matrix() @ P.T
    root_euler = np.degrees(Rotation.from_matrix(root_R).as_euler("ZYX"))  # R = Rz Ry Rx
    names = ["Xposition", "Yposition", "Zposition", "Zrotation", "Yrotation", "Xrotation"]
    return [names], [np.concatenate([root_pos, root_euler], axis=1)]


def _bvh_joint_channels(b: int, tree: KinematicTree, qpos: np.ndarray, P: np.ndarray, path: Path) -> tuple[list[str], np.ndarray]:
    """Body ``b``'s three rotation channels: its hinges (qpos order), then its missing axes at 0.

    Parameters
    ----------
    b : int
        Body index (not the root).
    qpos : (F, nq) float
        Free joint (7) then hinge angles in radians.
    P : (3, 3) float
        World -> BVH axes.

    Returns
    -------
    names : list[str], length 3
        ``"<axis>rotation"`` channel names.
    values : (F, 3) float
        Degrees, signed for the BVH axis each hinge maps to.
    """
    angles_deg = np.degrees(qpos[:, 7:])
    names, cols, used = [], [], set()
    for h in np.flatnonzero(tree.hinge_bodies == b):
        k, sign = _hinge_channel(tree.hinge_axes[h], P, f"{path}: hinge {tree.hinge_names[h]!r}")
        if k in used:
            raise MocapInputError(f"{path}: body {tree.body_names[b]!r} has two hinges about the same axis; BVH cannot write that")
        used.add(k)
        names.append(f"{_AXIS_NAMES[k]}rotation")
        cols.append(sign * angles_deg[:, h])
    for k in range(3):
        if k not in used:
            names.append(f"{_AXIS_NAMES[k]}rotation")
            cols.append(np.zeros(len(qpos)))
    return names, np.stack(cols, axis=1)


def _bvh_end_sites(tree: KinematicTree, subject: SubjectModel) -> dict[int, np.ndarray]:
    """``body index -> (3,) end-site offset (m, body frame)`` for every leaf body.

    The leaf's marker farthest from its origin, else 10 cm along its bone from the parent
    (straight up for a zero-length bone).
    """
    marker_offsets: dict[str, list[np.ndarray]] = {}
    for m in subject.markers:
        marker_offsets.setdefault(m.body, []).append(m.offset_m)
    has_child = set(int(p) for p in tree.parents[1:])
    sites: dict[int, np.ndarray] = {}
    for b in range(len(tree.body_names)):
        if b in has_child:
            continue
        offs = marker_offsets.get(tree.body_names[b])
        if offs:
            offs_arr = np.array(offs)
            sites[b] = offs_arr[int(np.argmax(np.linalg.norm(offs_arr, axis=1)))]
        else:
            bone = tree.offsets_m[b]
            n = np.linalg.norm(bone)
            sites[b] = bone / n * 0.1 if n > 0 else np.array([0.0, 0.0, 0.1])
    return sites


def _bvh_hierarchy(tree: KinematicTree, channel_names: list[list[str]], end_sites: dict[int, np.ndarray], P: np.ndarray) -> list[str]:
    """The ``HIERARCHY`` section's lines after its keyword: ROOT/JOINT blocks, depth first.

    ``channel_names[b]`` are body ``b``'s channels; ``end_sites[b] (3,)`` metres for each leaf;
    offsets are written in cm in BVH axes (``P @ v``).
    """
    children: dict[int, list[int]] = {b: [] for b in range(len(tree.body_names))}
    for b in range(1, len(tree.body_names)):
        children[int(tree.parents[b])].append(b)
    lines: list[str] = []

    def fmt(v: np.ndarray) -> str:
        return " ".join(f"{x:.6f}" for x in (P @ v) * 100.0)

    def emit(b: int, depth: int) -> None:
        pad = "  " * depth
        kind = "ROOT" if b == 0 else "JOINT"
        lines.append(f"{pad}{kind} {tree.body_names[b]}")
        lines.append(f"{pad}{{")
        offset = np.zeros(3) if b == 0 else tree.offsets_m[b]
        lines.append(f"{pad}  OFFSET {fmt(offset)}")
        lines.append(f"{pad}  CHANNELS {len(channel_names[b])} {' '.join(channel_names[b])}")
        if children[b]:
            for c in children[b]:
                emit(c, depth + 1)
        else:
            lines.append(f"{pad}  End Site")
            lines.append(f"{pad}  {{")
            lines.append(f"{pad}    OFFSET {fmt(end_sites[b])}")
            lines.append(f"{pad}  }}")
        lines.append(f"{pad}}}")

    emit(0, 0)
    return lines
