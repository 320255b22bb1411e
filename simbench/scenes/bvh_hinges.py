"""From target rotations and bone directions of the humanoid's bodies to its hinge angles
(the solver of :mod:`simbench.scenes.bvh`'s retargeting; also its small rotation helpers).

:func:`alignments` turns each body so that its bone points along a reference pose's bone;
:func:`solve_hinges` realises target world rotations parents first: the trunk and neck by XYZ
decomposition, each limb so that both segments point along the wanted directions (the
one-DoF elbow/knee picks the upper segment's twist), hands and feet by the two hinges that
keep their long axis / sole normal; every hinge is clamped to the model's ranges.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from simbench.scenes.bvh_mapping import BONE_END, LIMBS, ROLES, TRUNK
from simbench.scenes.humanoid import HINGE_NAMES
from simbench.scenes.motions import HumanoidKinematics

__all__ = ["alignments", "solve_hinges", "bone_axis", "unit", "min_rotation", "rz", "heading_angle"]

_AXIS_LETTER = "XYZ"

# Bending weight of a limb: below sin(5 deg) of flexion the bend plane is undefined and the
# upper segment's twist follows the BVH rotation; above sin(20 deg) it follows the bend plane.
_BEND_SIN_LO, _BEND_SIN_HI = np.sin(np.deg2rad(5.0)), np.sin(np.deg2rad(20.0))


def unit(v: np.ndarray) -> np.ndarray:
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-12)


def min_rotation(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Smallest rotation matrix ``(3, 3)`` taking unit vector ``a`` to unit vector ``b``."""
    axis = np.cross(a, b)
    s, c = np.linalg.norm(axis), float(np.dot(a, b))
    if s < 1e-12:
        if c > 0:
            return np.eye(3)
        perp = unit(np.cross(a, [1.0, 0.0, 0.0] if abs(a[0]) < 0.9 else [0.0, 1.0, 0.0]))
        return Rotation.from_rotvec(np.pi * perp).as_matrix()
    return Rotation.from_rotvec(axis / s * np.arctan2(s, c)).as_matrix()


def rz(angle: float) -> np.ndarray:
    return Rotation.from_euler("z", angle).as_matrix()


def heading_angle(forward: np.ndarray) -> np.ndarray:
    """Heading angle(s) of horizontal direction(s) ``(..., 3)`` in the bench world (0 = +X)."""
    return np.arctan2(forward[..., 1], forward[..., 0])


def bone_axis(kin: HumanoidKinematics, role: str) -> np.ndarray:
    """Unit bone axis of a humanoid body in its own frame (= its T-pose world direction)."""
    end = BONE_END[role]
    if role in ("abdomen", "thorax", "head"):
        return np.array([0.0, 0.0, 1.0])
    if role.startswith("foot"):
        return unit(kin.ball_of_foot_local * (1.0, 1.0 if role.endswith("_l") else -1.0, 1.0))
    if role.startswith("hand"):
        return bone_axis(kin, role.replace("hand", "forearm"))  # the hand continues the forearm
    return unit(kin.model.body_pos[kin.model.body(end).id])


def alignments(kin: HumanoidKinematics, ref_dirs: dict[str, np.ndarray], psi_ref: float) -> dict[str, np.ndarray]:
    """Orientation ``(3, 3)`` of each humanoid body when the BVH is in its reference pose.

    The pelvis only turns to the reference heading; trunk, head and limb segments turn their
    bone axis onto the BVH's reference bone (smallest rotation after the heading turn); hands
    and feet keep their reference relation to the forearm / shank (CMU rest skeletons splay
    the legs ~20 deg with the feet rolled along, so aligning the feet on their own would leave
    them rolled by as much once the legs are straight), except for the foot's pitch: the
    reference ankle -> toe-base bone gets the pitch of our ankle -> ball-of-foot direction
    (CMU rest feet are ~10 deg dorsiflexed compared with a foot flat on the floor).
    """
    turn = rz(psi_ref)
    align: dict[str, np.ndarray] = {"pelvis": turn}
    for role in ROLES[1:]:
        if not role.startswith(("hand", "foot")):
            align[role] = min_rotation(turn @ bone_axis(kin, role), ref_dirs[role]) @ turn
    for _, middle, end, *_ in LIMBS:
        align[end] = align[middle]
    ball = kin.ball_of_foot_local
    for foot in ("foot_l", "foot_r"):
        v = align[foot].T @ ref_dirs[foot]
        pitch = np.arctan2(-v[2], v[0]) - np.arctan2(-ball[2], ball[0])
        align[foot] = align[foot] @ Rotation.from_euler("y", pitch).as_matrix()
    return align


def solve_hinges(kin: HumanoidKinematics, targets: dict[str, np.ndarray], directions: dict[str, np.ndarray]) -> np.ndarray:
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

    for role, parent, prefix in TRUNK:
        local = np.swapaxes(world[parent], 1, 2) @ targets[role]
        world[role] = world[parent] @ set_joint((f"{prefix}_x", f"{prefix}_y", f"{prefix}_z"), local)

    for upper, middle, end, mid_hinge, end_hinges, parent in LIMBS:
        side = upper[-1]
        joint = "shoulder" if upper.startswith("upperarm") else "hip"
        u = bone_axis(kin, upper)
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
        raise RuntimeError(f"hinge {hinge} is not about a positive body axis; update simbench.scenes.bvh_hinges")
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
    n_rot = unit(n_rot - np.sum(n_rot * d1, axis=1, keepdims=True) * d1)
    bend = flex * np.sum(normal * n_rot, axis=1)  # sine of the flexion seen in the BVH segment's bend plane
    w = np.clip((bend - _BEND_SIN_LO) / (_BEND_SIN_HI - _BEND_SIN_LO), 0.0, 1.0)
    w = (w * w * (3.0 - 2.0 * w))[:, None]
    n = unit(w * flex * unit(normal) + (1.0 - w) * n_rot)
    n = unit(n - np.sum(n * d1, axis=1, keepdims=True) * d1)
    u_perp = unit(u - np.dot(u, e_h) * e_h)
    local = np.stack([u_perp, e_h, np.cross(u_perp, e_h)], axis=0)  # rows: the three local vectors
    world = np.stack([d1, n, np.cross(d1, n)], axis=2)  # columns: their world images
    return world @ local
