"""Marker sets as data: which body each marker rides on and where, in that body's frame.

Each marker is described anatomically (a body, an anchor point inside it and an
outward direction, from the subject's dimensions) and then placed on the rendered
skin of :mod:`simbench.scenes.surface`: the marker centre is the skin point nearest
to ``anchor + 15 cm * direction`` pushed out by :data:`MARKER_RADIUS_M` along the
same line, so the 14 mm sphere touches the skin.

Sets
----
``plugin_gait_full``
    The 39 markers of Vicon's Plug-in Gait full-body model (head 4, torso 5, arms
    2 x 7, pelvis 4, legs 2 x 6), with the usual left/right asymmetry of the upper
    arm, forearm, thigh and tibia markers and the single ``RBAK``.
``sparse_joints``
    15 markers near joint centres: head, neck (sternal notch), sacrum, and lateral
    shoulders, elbows, wrists, hips (greater trochanter), knees and ankles.
``upper_body``
    The 23 head, torso and arm markers of Plug-in Gait.
"""

from __future__ import annotations

import functools

import numpy as np
import trimesh

from mocap.subject import MarkerPlacement
from simbench.scenes.anthropometry import BodyDims, BodyParams, body_dimensions
from simbench.scenes.surface import BodyPart, body_surface

__all__ = [
    "MARKER_RADIUS_M",
    "MARKER_SETS",
    "MarkerSpec",
    "marker_set",
    "marker_names",
    "PLUGIN_GAIT_FULL",
    "UPPER_BODY",
    "SPARSE_JOINTS",
]

MARKER_RADIUS_M = 0.007  # 14 mm spheres
_PROBE_DISTANCE_M = 0.15  # probe point outside the skin (anchors are inside the body), projected onto it

PLUGIN_GAIT_FULL: tuple[str, ...] = tuple(
    "LFHD RFHD LBHD RBHD C7 T10 CLAV STRN RBAK LSHO LUPA LELB LFRM LWRA LWRB LFIN "
    "RSHO RUPA RELB RFRM RWRA RWRB RFIN LASI RASI LPSI RPSI LTHI LKNE LTIB LANK LHEE LTOE "
    "RTHI RKNE RTIB RANK RHEE RTOE".split()
)
UPPER_BODY: tuple[str, ...] = PLUGIN_GAIT_FULL[:23]
SPARSE_JOINTS: tuple[str, ...] = tuple(
    "HEAD NECK SACR LSHO RSHO LELB RELB LWRI RWRI LHIP RHIP LKNE RKNE LANK RANK".split()
)
MARKER_SETS: dict[str, tuple[str, ...]] = {
    "plugin_gait_full": PLUGIN_GAIT_FULL,
    "sparse_joints": SPARSE_JOINTS,
    "upper_body": UPPER_BODY,
}


#: One marker on one body (name, body, ``offset_m`` in the body's frame): the capture product's
#: type, so that the simulated subject and the pipeline's subject model place markers alike.
MarkerSpec = MarkerPlacement


def _unit(*v: float) -> np.ndarray:
    a = np.asarray(v, dtype=np.float64)
    return a / np.linalg.norm(a)


def _anatomy(d: BodyDims) -> dict[str, tuple[str, np.ndarray, np.ndarray]]:
    """Anatomical description of every known marker: ``name -> (body, anchor (3,), direction (3,))``.

    Left-side markers are listed; right-side ones are mirrored (y -> -y) except where
    Plug-in Gait is deliberately asymmetric.
    """
    r = d.radius
    H = d.height
    head_c = np.array([0.008 * H, 0.0, d.head - r["head_half_height"]])
    hand_c = np.array([0.0, 0.45 * d.hand, 0.0])
    heel_r = 0.5 * d.ankle_height
    toe_r = 0.012 * H
    a: dict[str, tuple[str, np.ndarray, np.ndarray]] = {
        # head: temples and back of the head
        "LFHD": ("head", head_c, _unit(1.0, 0.55, 0.35)),
        "LBHD": ("head", head_c, _unit(-1.0, 0.55, 0.35)),
        # torso
        "C7": ("thorax", np.array([0.0, 0.0, 0.95 * d.thorax]), _unit(-1.0, 0.0, 0.35)),
        "T10": ("thorax", np.array([0.0, 0.0, 0.25 * d.thorax]), _unit(-1.0, 0.0, 0.0)),
        "CLAV": ("thorax", np.array([0.0, 0.0, 0.90 * d.thorax]), _unit(1.0, 0.0, 0.25)),
        "STRN": ("thorax", np.array([0.0, 0.0, 0.35 * d.thorax]), _unit(1.0, 0.0, 0.0)),
        "RBAK": ("thorax", np.array([0.0, -0.45 * r["thorax_half_width"], 0.60 * d.thorax]), _unit(-1.0, 0.0, 0.0)),
        # arm (T-pose, palm down: lateral = +Z, thumb = +X)
        "LSHO": ("thorax", np.array([0.0, 0.95 * d.shoulder_half_width, d.shoulder_height]), _unit(0.0, 0.2, 1.0)),
        "LUPA": ("upperarm_l", np.array([0.0, 0.50 * d.upper_arm, 0.0]), _unit(-0.6, 0.0, 1.0)),
        "RUPA": ("upperarm_r", np.array([0.0, -0.65 * d.upper_arm, 0.0]), _unit(-0.6, 0.0, 1.0)),
        "LELB": ("upperarm_l", np.array([0.0, d.upper_arm, 0.0]), _unit(0.0, 0.0, 1.0)),
        "LFRM": ("forearm_l", np.array([0.0, 0.50 * d.forearm, 0.0]), _unit(-0.3, 0.0, 1.0)),
        "RFRM": ("forearm_r", np.array([0.0, -0.62 * d.forearm, 0.0]), _unit(-0.3, 0.0, 1.0)),
        "LWRA": ("forearm_l", np.array([0.0, d.forearm, 0.0]), _unit(1.0, 0.0, 0.0)),
        "LWRB": ("forearm_l", np.array([0.0, d.forearm, 0.0]), _unit(-1.0, 0.0, 0.0)),
        "LFIN": ("hand_l", hand_c + [0.3 * r["hand_half_width"], 0.0, 0.0], _unit(0.0, 0.0, 1.0)),
        # pelvis
        "LASI": ("pelvis", np.array([0.0, 0.068 * H, 0.028 * H]), _unit(1.0, 0.25, 0.0)),
        "LPSI": ("pelvis", np.array([0.0, 0.025 * H, 0.030 * H]), _unit(-1.0, 0.0, 0.0)),
        # leg (lateral = +Y on the left)
        "LTHI": ("thigh_l", np.array([0.0, 0.0, -0.55 * d.thigh]), _unit(0.0, 1.0, 0.0)),
        "RTHI": ("thigh_r", np.array([0.0, 0.0, -0.40 * d.thigh]), _unit(0.0, -1.0, 0.0)),
        "LKNE": ("thigh_l", np.array([0.0, 0.0, -d.thigh]), _unit(0.0, 1.0, 0.0)),
        "LTIB": ("shank_l", np.array([0.0, 0.0, -0.55 * d.shank]), _unit(0.0, 1.0, 0.0)),
        "RTIB": ("shank_r", np.array([0.0, 0.0, -0.40 * d.shank]), _unit(0.0, -1.0, 0.0)),
        "LANK": ("shank_l", np.array([0.0, 0.0, -d.shank]), _unit(0.0, 1.0, 0.0)),
        "LHEE": ("foot_l", np.array([-d.heel + heel_r, 0.0, -d.ankle_height + heel_r]), _unit(-1.0, 0.0, 0.1)),
        "LTOE": ("foot_l", np.array([d.foot_length - d.heel - 3.0 * toe_r, 0.0, -d.ankle_height + toe_r]), _unit(0.2, 0.0, 1.0)),
        # sparse joint set
        "HEAD": ("head", head_c, _unit(0.0, 0.0, 1.0)),
        "NECK": ("thorax", np.array([0.0, 0.0, 0.90 * d.thorax]), _unit(1.0, 0.0, 0.25)),
        "SACR": ("pelvis", np.array([0.0, 0.0, 0.030 * H]), _unit(-1.0, 0.0, 0.0)),
        "LWRI": ("forearm_l", np.array([0.0, d.forearm, 0.0]), _unit(0.0, 0.0, 1.0)),
        "LHIP": ("thigh_l", np.array([0.0, 0.0, -0.06 * H]), _unit(0.0, 1.0, 0.0)),
    }
    # right-side mirrors of the symmetric left markers
    for name, (body, anchor, direction) in list(a.items()):
        if not name.startswith("L"):
            continue
        rname = "R" + name[1:]
        if rname in a:
            continue
        rbody = body[:-2] + "_r" if body.endswith("_l") else body
        a[rname] = (rbody, anchor * [1.0, -1.0, 1.0], direction * [1.0, -1.0, 1.0])
    return a


def _place_on_skin(part: BodyPart, anchor: np.ndarray, direction: np.ndarray) -> np.ndarray:
    """Marker centre touching the skin of ``part`` near ``anchor + direction`` (body frame, metres).

    The probe point lies outside the surface, so its nearest surface point q is on
    the outer skin, and the ball of radius ``MARKER_RADIUS_M`` centred on the segment
    from q towards the probe touches the skin at q only.
    """
    probe = anchor + _PROBE_DISTANCE_M * direction
    tris = part.mesh.triangles
    closest = trimesh.triangles.closest_point(tris, np.repeat(probe[None, :], len(tris), axis=0))
    dist = np.linalg.norm(closest - probe, axis=1)
    q = closest[int(np.argmin(dist))]
    out = probe - q
    n = np.linalg.norm(out)
    if n < MARKER_RADIUS_M:
        raise RuntimeError(
            f"marker probe of body {part.body!r} is inside or too near the skin ({n * 1000:.1f} mm); "
            f"anchor {anchor}, direction {direction}: move the anchor inwards"
        )
    return q + MARKER_RADIUS_M * out / n


def marker_names(name: str) -> tuple[str, ...]:
    """Marker names of a set, in the set's order."""
    if name not in MARKER_SETS:
        raise ValueError(f"unknown marker set {name!r}; choose one of {sorted(MARKER_SETS)}")
    return MARKER_SETS[name]


def marker_set(name: str, params: BodyParams = BodyParams()) -> list[MarkerSpec]:
    """The markers of a set for a subject, on its skin.

    Parameters
    ----------
    name : str
        ``"plugin_gait_full"`` (39), ``"sparse_joints"`` (15) or ``"upper_body"`` (23).
    params : BodyParams
        The subject (markers are placed on its rendered surface).

    Returns
    -------
    list[MarkerSpec]
        In the set's order (:data:`MARKER_SETS`).
    """
    names = marker_names(name)
    return list(_placed_markers(names, params))


@functools.lru_cache(maxsize=16)
def _placed_markers(names: tuple[str, ...], params: BodyParams) -> tuple[MarkerSpec, ...]:
    """:func:`marker_set`'s markers, computed once per set and subject in a process: a run asks
    for them several times (the scene, its MJCF, the subject model, the label template), and
    each time meshed the whole body surface. A :class:`MarkerSpec` is immutable (its offset is
    a read-only copy), so the cached markers can be shared."""
    d = body_dimensions(params)
    anatomy = _anatomy(d)
    parts = {p.body: p for p in body_surface(params, shirt=False)}
    out = []
    for n in names:
        body, anchor, direction = anatomy[n]
        out.append(MarkerSpec(n, body, _place_on_skin(parts[body], anchor, direction)))
    return tuple(out)
