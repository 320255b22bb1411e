"""The bench's humanoid as MJCF, generated from body parameters.

Implements the contract of ``docs/humanoid_spec.md``: 16 bodies, a free root and 33
hinges (nq = 40), T-pose at zero, body frames aligned with the world in the T-pose,
body origins at joint centres, 3-DoF joints as three hinges ``_x, _y, _z`` (so
``R = Rx @ Ry @ Rz``).  Every joint carries its ``pos`` inline and every attribute
is written explicitly (no default classes), because Pinocchio's MJCF parser ignores
values inherited from defaults; the same text therefore loads in MuJoCo and in
``pinocchio.buildModelFromMJCF`` with identical kinematics.

Collision geoms are one capsule (feet: a box) per segment.  They are in contact group
``contype=2, conaffinity=0``: the humanoid never collides with itself or with the
floor (it is driven kinematically), but props (which have bit 2 in ``conaffinity``)
hit it.  The pelvis body sits at the world origin in the MJCF, so the free joint's
position in ``qpos`` is the pelvis position itself in both libraries; the standing
T-pose has the pelvis at ``BodyDims.hip_height`` (see :func:`tpose_qpos`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING
from xml.sax.saxutils import quoteattr

import numpy as np

from simbench.scenes.anthropometry import BODY_NAMES, BodyParams, body_dimensions
from simbench.scenes.markers import MARKER_RADIUS_M, marker_set as _marker_set

if TYPE_CHECKING:  # pragma: no cover - typing only
    import mujoco

__all__ = [
    "BodyParams",
    "BODY_NAMES",
    "HINGE_NAMES",
    "NQ",
    "NV",
    "HUMANOID_CONTYPE",
    "HUMANOID_CONAFFINITY",
    "JointSpec",
    "BodySpec",
    "humanoid_bodies",
    "humanoid_mjcf",
    "humanoid_only_mjcf",
    "humanoid_body_xml",
    "joint_ranges",
    "tpose_qpos",
    "mujoco_to_pinocchio_q",
    "pinocchio_to_mujoco_q",
    "joint_qpos_index",
]

_PARENT = {
    "pelvis": None,
    "abdomen": "pelvis",
    "thorax": "abdomen",
    "head": "thorax",
    "upperarm_l": "thorax",
    "forearm_l": "upperarm_l",
    "hand_l": "forearm_l",
    "upperarm_r": "thorax",
    "forearm_r": "upperarm_r",
    "hand_r": "forearm_r",
    "thigh_l": "pelvis",
    "shank_l": "thigh_l",
    "foot_l": "shank_l",
    "thigh_r": "pelvis",
    "shank_r": "thigh_r",
    "foot_r": "shank_r",
}

_X, _Y, _Z = (1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)

# Hinges of the left side and the trunk: (name, axis, (lo, hi) radians).  Anatomical
# ranges of motion (AAOS / Kapandji, rounded), expressed in the T-pose frames of the
# contract: left arm along +Y, legs along -Z, feet along +X.
_LEFT_AND_TRUNK_JOINTS: dict[str, list[tuple[str, tuple[float, float, float], tuple[float, float]]]] = {
    "abdomen": [("lumbar_x", _X, (-0.5, 0.5)), ("lumbar_y", _Y, (-0.5, 1.0)), ("lumbar_z", _Z, (-0.6, 0.6))],
    "thorax": [("thorax_x", _X, (-0.35, 0.35)), ("thorax_y", _Y, (-0.35, 0.6)), ("thorax_z", _Z, (-0.5, 0.5))],
    "head": [("neck_x", _X, (-0.7, 0.7)), ("neck_y", _Y, (-0.9, 0.8)), ("neck_z", _Z, (-1.3, 1.3))],
    # left arm points +Y: x = down (-) / overhead (+), z = forward (-) / backward (+)
    "upperarm_l": [("shoulder_l_x", _X, (-1.8, 1.7)), ("shoulder_l_y", _Y, (-1.5, 1.5)), ("shoulder_l_z", _Z, (-2.2, 0.9))],
    "forearm_l": [("elbow_l", _Z, (-2.6, 0.05))],  # flexion is negative on the left
    "hand_l": [("wrist_l_x", _X, (-1.2, 1.2)), ("wrist_l_z", _Z, (-0.6, 0.5))],
    # left leg points -Z: hip_x > 0 abducts, hip_y < 0 flexes, knee > 0 flexes
    "thigh_l": [("hip_l_x", _X, (-0.5, 0.9)), ("hip_l_y", _Y, (-2.2, 0.5)), ("hip_l_z", _Z, (-0.8, 0.8))],
    "shank_l": [("knee_l", _Y, (-0.05, 2.6))],
    "foot_l": [("ankle_l_y", _Y, (-0.6, 0.9)), ("ankle_l_x", _X, (-0.45, 0.45))],
}


def _mirror_joints(joints):
    """Right-side hinges: mirroring through the XZ plane flips rotations about X and Z."""
    out = []
    for name, axis, (lo, hi) in joints:
        rname = name.replace("_l_", "_r_") if "_l_" in name else name[:-2] + "_r"
        if axis == _Y:
            out.append((rname, axis, (lo, hi)))
        else:
            out.append((rname, axis, (-hi, -lo)))
    return out


_JOINTS = dict(_LEFT_AND_TRUNK_JOINTS)
for _b in ("upperarm", "forearm", "hand", "thigh", "shank", "foot"):
    _JOINTS[f"{_b}_r"] = _mirror_joints(_LEFT_AND_TRUNK_JOINTS[f"{_b}_l"])
_JOINTS["pelvis"] = []

HINGE_NAMES: tuple[str, ...] = tuple(j[0] for b in BODY_NAMES for j in _JOINTS[b])
NQ = 7 + len(HINGE_NAMES)  # 40
NV = 6 + len(HINGE_NAMES)  # 39

HUMANOID_CONTYPE = 2
HUMANOID_CONAFFINITY = 0


@dataclass(frozen=True)
class JointSpec:
    """One hinge: name, unit axis in the body frame, range (radians)."""

    name: str
    axis: tuple[float, float, float]
    range: tuple[float, float]


@dataclass(frozen=True)
class BodySpec:
    """One body of the tree, in its parent's frame (T-pose, world-aligned).

    Attributes
    ----------
    name, parent : str, str | None
    pos : (3,) float
        Origin (joint centre) in the parent frame, metres.
    joints : tuple[JointSpec, ...]
    geom : tuple
        Collision geom ``("capsule", fromto (6,), radius)`` or ``("box", centre (3,), half sizes (3,))``.
    mass : float
        Kilograms.
    com : (3,) float
        Centre of mass in the body frame, metres.
    """

    name: str
    parent: str | None
    pos: tuple[float, float, float]
    joints: tuple[JointSpec, ...]
    geom: tuple
    mass: float
    com: tuple[float, float, float]


def _capsule(a, b, r):
    return ("capsule", tuple(float(v) for v in (*a, *b)), float(r))


def humanoid_bodies(params: BodyParams) -> list[BodySpec]:
    """The kinematic tree of a subject, in :data:`BODY_NAMES` order."""
    d = body_dimensions(params)
    r = d.radius
    pos: dict[str, tuple[float, float, float]] = {
        "pelvis": (0.0, 0.0, 0.0),
        "abdomen": (0.0, 0.0, d.lumbar),
        "thorax": (0.0, 0.0, d.abdomen),
        "head": (0.0, 0.0, d.thorax),
        "thigh_l": (0.0, d.hip_half_width, 0.0),
        "shank_l": (0.0, 0.0, -d.thigh),
        "foot_l": (0.0, 0.0, -d.shank),
        "upperarm_l": (0.0, d.shoulder_half_width, d.shoulder_height),
        "forearm_l": (0.0, d.upper_arm, 0.0),
        "hand_l": (0.0, d.forearm, 0.0),
    }
    # collision geoms, left side (+Y); mirrored below
    pw = r["pelvis_half_width"] - r["pelvis_half_depth"]
    aw = r["abdomen_half_width"] - r["abdomen_half_depth"]
    tw = r["thorax_half_width"] - r["thorax_half_depth"]
    zh = d.head - r["head_half_height"]  # head centre above the neck joint
    geom = {
        "pelvis": _capsule((0, -pw, 0.5 * d.lumbar), (0, pw, 0.5 * d.lumbar), r["pelvis_half_depth"]),
        "abdomen": _capsule((0, -aw, 0.5 * d.abdomen), (0, aw, 0.5 * d.abdomen), r["abdomen_half_depth"]),
        "thorax": _capsule((0, -tw, 0.55 * d.thorax), (0, tw, 0.55 * d.thorax), r["thorax_half_depth"]),
        "head": _capsule((0, 0, zh - 0.3 * r["head_half_height"]), (0, 0, zh + 0.3 * r["head_half_height"]), r["head_half_width"] * 1.1),
        "upperarm_l": _capsule((0, 0, 0), (0, d.upper_arm, 0), 0.5 * (r["upperarm_prox"] + r["upperarm_dist"])),
        "forearm_l": _capsule((0, 0, 0), (0, d.forearm, 0), 0.5 * (r["forearm_prox"] + r["forearm_dist"])),
        "hand_l": _capsule((0, 0.2 * d.hand, 0), (0, d.hand - r["hand_half_thickness"] * 2, 0), r["hand_half_thickness"] * 2),
        "thigh_l": _capsule((0, 0, 0), (0, 0, -d.thigh), 0.5 * (r["thigh_prox"] + r["thigh_dist"])),
        "shank_l": _capsule((0, 0, 0), (0, 0, -d.shank), 0.5 * (r["shank_prox"] + r["shank_dist"])),
        "foot_l": (
            "box",
            (0.5 * d.foot_length - d.heel, 0.0, -0.5 * d.ankle_height),
            (0.5 * d.foot_length, 0.5 * d.foot_width, 0.5 * d.ankle_height),
        ),
    }
    for seg in ("upperarm", "forearm", "hand", "thigh", "shank", "foot"):  # mirror the left limbs
        left = f"{seg}_l"
        p = pos[left]
        pos[f"{seg}_r"] = (p[0], -p[1], p[2])
        g = geom[left]
        if g[0] == "capsule":
            a = g[1]
            geom[f"{seg}_r"] = ("capsule", (a[0], -a[1], a[2], a[3], -a[4], a[5]), g[2])
        else:
            c = g[1]
            geom[f"{seg}_r"] = ("box", (c[0], -c[1], c[2]), g[2])
    out = []
    for name in BODY_NAMES:
        g = geom[name]
        if g[0] == "capsule":
            com = tuple(0.5 * (np.array(g[1][:3]) + np.array(g[1][3:])))
        else:
            com = tuple(g[1])
        seg = name.split("_")[0]
        out.append(
            BodySpec(
                name=name,
                parent=_PARENT[name],
                pos=tuple(float(v) for v in pos[name]),
                joints=tuple(JointSpec(n, ax, rg) for n, ax, rg in _JOINTS[name]),
                geom=g,
                mass=float(d.mass[seg]),
                com=tuple(float(v) for v in com),
            )
        )
    return out


def _fmt(values) -> str:
    return " ".join(f"{float(v):.9g}" for v in values)


def _diag_inertia(geom: tuple, mass: float) -> tuple[float, float, float]:
    """Principal inertia of a solid box/cylinder approximating the geom (kg m^2).

    Only used so that the model has physically sensible inertias; the humanoid is
    driven kinematically, so these values never affect its motion.
    """
    if geom[0] == "box":
        hx, hy, hz = geom[2]
    else:
        a, b = np.array(geom[1][:3]), np.array(geom[1][3:])
        rad = geom[2]
        half = np.abs(b - a) / 2 + rad
        hx, hy, hz = half
    return (
        mass * (hy**2 + hz**2) / 3.0,
        mass * (hx**2 + hz**2) / 3.0,
        mass * (hx**2 + hy**2) / 3.0,
    )


def humanoid_body_xml(
    params: BodyParams,
    marker_set: str | None = None,
    indent: str = "    ",
) -> str:
    """The ``<body name="pelvis">`` element (whole tree) as MJCF text.

    Used by :func:`humanoid_mjcf` and by :func:`simbench.scenes.scene.build_scene` to
    place the same humanoid into a scene.  Marker sites (``<site>`` named like the
    markers, ``size`` = marker radius) are added when ``marker_set`` is given.
    """
    bodies = humanoid_bodies(params)
    sites: dict[str, list] = {b.name: [] for b in bodies}
    if marker_set is not None:
        for m in _marker_set(marker_set, params):
            sites[m.body].append(m)
    children: dict[str | None, list[BodySpec]] = {}
    for b in bodies:
        children.setdefault(b.parent, []).append(b)

    lines: list[str] = []

    def emit(b: BodySpec, depth: int) -> None:
        pad = indent * depth
        lines.append(f'{pad}<body name="{b.name}" pos="{_fmt(b.pos)}">')
        inner = pad + "  "
        if b.parent is None:
            lines.append(f'{inner}<freejoint name="root"/>')
        for j in b.joints:
            lines.append(
                f'{inner}<joint name="{j.name}" type="hinge" pos="0 0 0" axis="{_fmt(j.axis)}" '
                f'limited="true" range="{_fmt(j.range)}" damping="0" armature="0"/>'
            )
        lines.append(
            f'{inner}<inertial pos="{_fmt(b.com)}" mass="{b.mass:.9g}" diaginertia="{_fmt(_diag_inertia(b.geom, b.mass))}"/>'
        )
        common = f'contype="{HUMANOID_CONTYPE}" conaffinity="{HUMANOID_CONAFFINITY}" group="3" density="0" rgba="0.6 0.5 0.45 1"'
        if b.geom[0] == "capsule":
            lines.append(f'{inner}<geom name="{b.name}_col" type="capsule" fromto="{_fmt(b.geom[1])}" size="{b.geom[2]:.9g}" {common}/>')
        else:
            lines.append(
                f'{inner}<geom name="{b.name}_col" type="box" pos="{_fmt(b.geom[1])}" size="{_fmt(b.geom[2])}" {common}/>'
            )
        for m in sites[b.name]:
            lines.append(
                f'{inner}<site name={quoteattr(m.name)} pos="{_fmt(m.offset_m)}" size="{MARKER_RADIUS_M:.9g}" '
                f'type="sphere" rgba="0.9 0.9 0.9 1" group="4"/>'
            )
        for c in children.get(b.name, []):
            emit(c, depth + 1)
        lines.append(f"{pad}</body>")

    emit(children[None][0], 0)
    return "\n".join(indent + ln for ln in lines)


def humanoid_mjcf(params: BodyParams = BodyParams(), marker_set: str | None = None) -> str:
    """Standalone MJCF of the humanoid (no floor, no props), loadable by MuJoCo and Pinocchio.

    Parameters
    ----------
    params : BodyParams
        Subject shape.
    marker_set : str, optional
        Name of a marker set (:func:`simbench.scenes.markers.marker_set`) to add as sites.

    Returns
    -------
    str
        MJCF text.  ``compiler angle="radian"``; the free joint ``root`` is the first
        joint; hinges follow in :data:`HINGE_NAMES` order.
    """
    body = humanoid_body_xml(params, marker_set, indent="    ")
    return (
        '<mujoco model="simbench_humanoid">\n'
        '  <compiler angle="radian" autolimits="true"/>\n'
        '  <option gravity="0 0 -9.81"/>\n'
        "  <worldbody>\n"
        f"{body}\n"
        "  </worldbody>\n"
        "</mujoco>\n"
    )


def humanoid_only_mjcf(params: BodyParams = BodyParams(), marker_set: str | None = None) -> str:
    """Alias of :func:`humanoid_mjcf`: the humanoid alone, e.g. for Pinocchio."""
    return humanoid_mjcf(params, marker_set)


def joint_ranges() -> dict[str, tuple[float, float]]:
    """Range (radians) of every hinge, by name, in :data:`HINGE_NAMES` order.

    The ranges do not depend on :class:`BodyParams`.
    """
    return {j[0]: j[2] for b in BODY_NAMES for j in _JOINTS[b]}


def tpose_qpos(params: BodyParams = BodyParams()) -> np.ndarray:
    """MuJoCo qpos ``(40,)`` of the standing T-pose: pelvis at hip height, feet on the floor."""
    q = np.zeros(NQ)
    q[2] = body_dimensions(params).hip_height
    q[3] = 1.0
    return q


def mujoco_to_pinocchio_q(q_mj: np.ndarray) -> np.ndarray:
    """Convert MuJoCo qpos to Pinocchio q (free-flyer quaternion ``w x y z`` -> ``x y z w``).

    Parameters
    ----------
    q_mj : (..., 40) float
        MuJoCo humanoid qpos: ``x y z qw qx qy qz`` then the hinges in
        :data:`HINGE_NAMES` order (Pinocchio's MJCF parser keeps that order; the
        tests check it by name).

    Returns
    -------
    (..., 40) float
    """
    q = np.array(q_mj, dtype=np.float64, copy=True)
    if q.shape[-1] != NQ:
        raise ValueError(f"q_mj must have {NQ} values in its last axis (humanoid qpos), got shape {q.shape}")
    q[..., 3:7] = np.asarray(q_mj, dtype=np.float64)[..., [4, 5, 6, 3]]
    return q


def pinocchio_to_mujoco_q(q_pin: np.ndarray) -> np.ndarray:
    """Inverse of :func:`mujoco_to_pinocchio_q` (quaternion ``x y z w`` -> ``w x y z``)."""
    q = np.array(q_pin, dtype=np.float64, copy=True)
    if q.shape[-1] != NQ:
        raise ValueError(f"q_pin must have {NQ} values in its last axis (humanoid q), got shape {q.shape}")
    q[..., 3:7] = np.asarray(q_pin, dtype=np.float64)[..., [6, 3, 4, 5]]
    return q


def joint_qpos_index(model: "mujoco.MjModel") -> dict[str, int]:
    """qpos address of every named joint of a MuJoCo model (``root`` -> its first of 7).

    Works for the standalone humanoid and for a scene (props' joints included).
    """
    out: dict[str, int] = {}
    for j in range(model.njnt):
        name = model.joint(j).name
        if name:
            out[name] = int(model.jnt_qposadr[j])
    return out
