"""The rendered body surface: one rigid triangle mesh per body, in that body's frame.

Each segment is made of a few closed primitives (a lofted torso of
superelliptic cross-sections, tapered capsules, ellipsoids, convex hulls of spheres) sized from :func:`simbench.scenes.anthropometry.body_dimensions`.
Every joint centre is the centre of a sphere of the same radius on both sides of the
joint (e.g. the upper arm ends with the elbow sphere the forearm starts with), so the
surface stays closed at the joints whatever the joint angles.  Primitives overlap and
are concatenated, not merged: hidden inner faces cost a little fill but keep the
meshes simple.

The renderer poses each part with MuJoCo's ``data.xpos`` / ``data.xmat`` of its
body: ``world = xmat @ vertex + xpos`` (see :meth:`BodyPart.world_vertices`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import trimesh

from simbench.scenes.anthropometry import BODY_NAMES, TORSO_SECTION_EXPONENT, TORSO_SECTIONS, BodyDims, BodyParams, body_dimensions
from simbench.scenes.shirt import PATCH_COLOUR, SHIRT_COLOURS_RGB, shirt_face_patch, shirt_row_borders_m

__all__ = [
    "BodyPart",
    "body_surface",
    "DEFAULT_SKIN_RGB",
    "DEFAULT_CLOTHES_RGB",
    "SKIN_BODIES",
]

# Linear-RGB albedo.  Skin: a light skin tone; clothes: a dark grey suit (markers
# stand out on it; kept well away from the shirt's black and light grey).
DEFAULT_SKIN_RGB: tuple[float, float, float] = (0.55, 0.36, 0.27)
DEFAULT_CLOTHES_RGB: tuple[float, float, float] = (0.10, 0.10, 0.11)
SKIN_BODIES: tuple[str, ...] = ("head", "hand_l", "hand_r")

# Tessellation: enough to keep the faceting error of every primitive under ~1.5 mm
# while the whole body stays well under 15k faces.
_RING_SECTIONS = 16
_ICO_OTHER = 2
_OVERLAP_INSET = 0.04  # torso pieces shrink by 4 % where they reach into a neighbour


@dataclass(frozen=True, eq=False)
class BodyPart:
    """The surface of one rigid body.

    Attributes
    ----------
    body : str
        Body name (:data:`simbench.scenes.anthropometry.BODY_NAMES`).
    mesh : trimesh.Trimesh
        Closed triangle mesh in the body frame, metres (a concatenation of closed
        pieces; outward normals).
    face_patch : (n_faces,) int16
        Shirt patch id ``0..19`` of every face, ``-1`` where it is not shirt.
    albedo : (n_faces, 3) float
        Linear-RGB albedo ``0..1`` of every face.
    pieces : tuple[trimesh.Trimesh, ...]
        The closed pieces ``mesh`` is made of, in face order (all convex except the
        torso lofts, which follow the waist).
    """

    body: str
    mesh: trimesh.Trimesh
    face_patch: np.ndarray
    albedo: np.ndarray
    pieces: tuple = field(default=(), repr=False)

    def world_vertices(self, xpos: np.ndarray, xmat: np.ndarray) -> np.ndarray:
        """Mesh vertices in the world for one or many body poses.

        Parameters
        ----------
        xpos : (..., 3) float
            Body origin in the world, metres (MuJoCo ``data.xpos[body]``).
        xmat : (..., 3, 3) or (..., 9) float
            Body orientation (MuJoCo ``data.xmat[body]``).

        Returns
        -------
        (..., n_vertices, 3) float
            World positions, metres.
        """
        xpos = np.asarray(xpos, dtype=np.float64)
        R = np.asarray(xmat, dtype=np.float64).reshape(*xpos.shape[:-1], 3, 3)
        v = np.asarray(self.mesh.vertices)
        return np.einsum("...ij,nj->...ni", R, v) + xpos[..., None, :]


# --- primitives --------------------------------------------------------------------


def _align_z_to(direction: np.ndarray) -> np.ndarray:
    """4x4 rotation taking +Z to ``direction``."""
    return trimesh.geometry.align_vectors([0.0, 0.0, 1.0], np.asarray(direction, dtype=np.float64))


def tapered_capsule(a, b, ra: float, rb: float, sections: int = _RING_SECTIONS) -> trimesh.Trimesh:
    """Closed surface swept by a sphere going from centre ``a`` (radius ``ra``) to ``b`` (``rb``).

    Built as a surface of revolution (trimesh.creation.revolve) of the exact
    profile: two spherical caps joined by the common tangent cone, with rings along
    the cone so that faces stay compact (shirt patches are assigned per face).
    """
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    axis = b - a
    length = float(np.linalg.norm(axis))
    if length < 1e-9:
        raise ValueError("tapered_capsule: the two sphere centres coincide")
    if abs(ra - rb) >= length:
        raise ValueError(f"tapered_capsule: |ra - rb| = {abs(ra - rb):.4f} m must be below the length {length:.4f} m")
    phi = np.arcsin((ra - rb) / length)  # tilt of the cone's outward normal towards +z
    n_cap = 5
    th_a = np.linspace(-np.pi / 2, phi, n_cap + 1)
    th_b = np.linspace(phi, np.pi / 2, n_cap + 1)
    cap_a = np.c_[ra * np.cos(th_a), ra * np.sin(th_a)]
    cap_b = np.c_[rb * np.cos(th_b), length + rb * np.sin(th_b)]
    # rings on the cone about every 2.5 cm
    n_cone = max(2, int(np.ceil((cap_b[0, 1] - cap_a[-1, 1]) / 0.025)))
    s = np.linspace(0.0, 1.0, n_cone + 1)[1:-1, None]
    cone = (1 - s) * cap_a[-1] + s * cap_b[0]
    profile = np.vstack([cap_a, cone, cap_b])
    profile[0, 0] = profile[-1, 0] = 0.0  # exact poles on the axis
    mesh = trimesh.creation.revolve(profile, sections=sections)
    T = _align_z_to(axis / length)
    T[:3, 3] = a
    mesh.apply_transform(T)
    return mesh


def ellipsoid(centre, half_axes, subdivisions: int = _ICO_OTHER) -> trimesh.Trimesh:
    """Axis-aligned ellipsoid (a scaled icosphere) with the given half axes, metres."""
    mesh = trimesh.creation.icosphere(subdivisions=subdivisions)
    mesh.apply_transform(np.diag([*half_axes, 1.0]))
    mesh.apply_translation(centre)
    return mesh


def hull_of_spheres(centres, radii, subdivisions: int = 2) -> trimesh.Trimesh:
    """Convex hull of a few spheres (feet, hands)."""
    unit = trimesh.creation.icosphere(subdivisions=subdivisions).vertices
    pts = np.concatenate([np.asarray(c, dtype=np.float64) + r * unit for c, r in zip(centres, radii)])
    return trimesh.convex.convex_hull(pts)


def hull_of_points(points) -> trimesh.Trimesh:
    return trimesh.convex.convex_hull(np.asarray(points, dtype=np.float64))


# --- the body ----------------------------------------------------------------------


def _torso_piece(
    lo: float, hi: float, own_lo: float, own_hi: float, origin: float, d: BodyDims
) -> trimesh.Trimesh:
    """Closed loft of torso cross-sections between heights ``lo`` and ``hi`` above the hips.

    Heights in metres above the hip-centre midpoint (pelvis origin); the piece is
    returned in the frame of a body whose origin is ``origin`` metres above it.
    ``[own_lo, own_hi]`` is the body's own span (between its joints); beyond it the
    piece overlaps its neighbour and is inset by a few millimetres, so that the two
    surfaces never coincide (no z-fighting) yet close the joint when it bends.  The
    mesh is a structured grid (rings x meridians, flat caps), so faces line up with
    the shirt's patch borders: meridians at the front/back/side axes and rings at
    the row heights.  It follows the waist, so it is not convex.
    """
    table = np.asarray(TORSO_SECTIONS, dtype=np.float64)
    neck = d.lumbar + d.abdomen + d.thorax
    u_table = table[:, 0] * neck
    # rings about every 2 cm, plus one at each shirt row border inside the range
    n_rings = max(3, int(np.ceil((hi - lo) / 0.02)) + 1)
    borders = [b for b in shirt_row_borders_m(d) if lo < b < hi]
    u = np.unique(np.concatenate([np.linspace(lo, hi, n_rings), borders]))
    scale = d.height * d.radius_scale
    beyond = np.maximum(own_lo - u, 0.0) + np.maximum(u - own_hi, 0.0)
    inset = 1.0 - _OVERLAP_INSET * np.minimum(beyond / 0.01, 1.0)
    half_depth = np.interp(u, u_table, table[:, 1]) * scale * inset
    half_width = np.interp(u, u_table, table[:, 2]) * scale * inset
    # superellipse |x/a|^p + |y/b|^p = 1, parametrised by angle (0 = front, +90 deg = left)
    n_ang = 32
    t = np.linspace(0.0, 2.0 * np.pi, n_ang, endpoint=False)
    e = 2.0 / TORSO_SECTION_EXPONENT
    cx = np.sign(np.cos(t)) * np.abs(np.cos(t)) ** e
    cy = np.sign(np.sin(t)) * np.abs(np.sin(t)) ** e
    n_r = len(u)
    ring = np.stack(
        [half_depth[:, None] * cx, half_width[:, None] * cy, np.broadcast_to((u - origin)[:, None], (n_r, n_ang))],
        axis=-1,
    ).reshape(-1, 3)
    bottom = n_r * n_ang
    top = bottom + 1
    vertices = np.vstack([ring, [[0.0, 0.0, u[0] - origin], [0.0, 0.0, u[-1] - origin]]])
    i = np.arange(n_r - 1)[:, None] * n_ang
    j = np.arange(n_ang)[None, :]
    j1 = (j + 1) % n_ang
    a, b, c, e_ = i + j, i + j1, i + n_ang + j1, i + n_ang + j
    side = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, e_], -1).reshape(-1, 3)])
    jj = np.arange(n_ang)
    cap_lo = np.stack([np.full(n_ang, bottom), (jj + 1) % n_ang, jj], -1)
    last = (n_r - 1) * n_ang
    cap_hi = np.stack([np.full(n_ang, top), last + jj, last + (jj + 1) % n_ang], -1)
    mesh = trimesh.Trimesh(vertices, np.vstack([side, cap_lo, cap_hi]), process=False)
    if mesh.volume < 0:  # keep normals outward whatever the orientation conventions above
        mesh.invert()
    return mesh


def _pieces(body: str, d: BodyDims) -> list[trimesh.Trimesh]:
    """Convex pieces of one body's surface in its frame (left side; right is mirrored)."""
    r = d.radius
    H = d.height
    if body in ("pelvis", "abdomen", "thorax"):
        # the torso is one lofted shape cut into three overlapping convex pieces
        lumbar, thorax_joint, neck = d.lumbar, d.lumbar + d.abdomen, d.lumbar + d.abdomen + d.thorax
        crotch = TORSO_SECTIONS[0][0] * neck
        lo, hi, own_lo, own_hi, origin = {
            "pelvis": (crotch, lumbar + 0.03 * H, crotch, lumbar, 0.0),
            "abdomen": (lumbar - 0.015 * H, thorax_joint + 0.03 * H, lumbar, thorax_joint, lumbar),
            "thorax": (thorax_joint - 0.03 * H, neck, thorax_joint, neck, thorax_joint),
        }[body]
        main = _torso_piece(lo, hi, own_lo, own_hi, origin, d)
        if body != "thorax":
            return [main]
        pieces = [main]
        # shoulder bridges (trapezius / deltoid): from the root of the neck to the
        # shoulder joint sphere, which the upper arm shares
        for s in (1.0, -1.0):
            pieces.append(
                tapered_capsule(
                    (0.0, s * 0.35 * d.shoulder_half_width, d.shoulder_height),
                    (0.0, s * d.shoulder_half_width, d.shoulder_height),
                    0.040 * H * d.radius_scale,
                    r["upperarm_prox"],
                )
            )
        return pieces
    if body == "head":
        neck = tapered_capsule((0.0, 0.0, -0.02 * H), (0.0, 0.0, 0.06 * H), r["neck"], 0.95 * r["neck"])
        head = ellipsoid(
            (0.008 * H, 0.0, d.head - r["head_half_height"]),
            (r["head_half_depth"], r["head_half_width"], r["head_half_height"]),
            _ICO_OTHER,
        )
        return [neck, head]
    if body == "upperarm_l":
        return [tapered_capsule((0.0, 0.0, 0.0), (0.0, d.upper_arm, 0.0), r["upperarm_prox"], r["upperarm_dist"])]
    if body == "forearm_l":
        return [tapered_capsule((0.0, 0.0, 0.0), (0.0, d.forearm, 0.0), r["forearm_prox"], r["forearm_dist"])]
    if body == "hand_l":
        palm = ellipsoid((0.0, 0.5 * d.hand, 0.0), (r["hand_half_width"], 0.5 * d.hand, r["hand_half_thickness"]), 2)
        wrist = trimesh.creation.icosphere(subdivisions=2).vertices * r["forearm_dist"]
        return [hull_of_points(np.vstack([palm.vertices, wrist]))]
    if body == "thigh_l":
        return [tapered_capsule((0.0, 0.0, 0.0), (0.0, 0.0, -d.thigh), r["thigh_prox"], r["thigh_dist"])]
    if body == "shank_l":
        return [tapered_capsule((0.0, 0.0, 0.0), (0.0, 0.0, -d.shank), r["shank_prox"], r["shank_dist"])]
    if body == "foot_l":
        ah = d.ankle_height
        rh = 0.5 * ah  # heel
        rt = 0.012 * H  # toes
        toe_x = d.foot_length - d.heel - rt
        half_w = 0.5 * d.foot_width - rt
        ball_x = 0.7 * d.foot_length - d.heel
        return [
            hull_of_spheres(
                [
                    (0.0, 0.0, 0.0),  # ankle: the sphere the shank ends with
                    (-d.heel + rh, 0.0, -ah + rh),
                    (toe_x, 0.3 * half_w, -ah + rt),
                    (toe_x - 0.02 * H, -0.8 * half_w, -ah + rt),
                    (ball_x, half_w, -ah + rt),
                    (ball_x, -half_w, -ah + rt),
                    (0.3 * ball_x, 0.0, -ah + r["foot_half_height"]),
                ],
                [r["shank_dist"], rh, rt, rt, rt, rt, r["foot_half_height"]],
            )
        ]
    raise KeyError(body)


def _mirror_y(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    m = mesh.copy()
    m.apply_transform(np.diag([1.0, -1.0, 1.0, 1.0]))  # trimesh flips the winding of reflections
    return m


def body_surface(
    params: BodyParams = BodyParams(),
    shirt: bool = False,
    skin_rgb: tuple[float, float, float] = DEFAULT_SKIN_RGB,
    clothes_rgb: tuple[float, float, float] = DEFAULT_CLOTHES_RGB,
) -> list[BodyPart]:
    """The humanoid's rendered surface, one :class:`BodyPart` per body in ``BODY_NAMES`` order.

    Parameters
    ----------
    params : BodyParams
    shirt : bool
        Dress the torso and arms in the 20-patch colour shirt (seed 001); otherwise
        they wear ``clothes_rgb`` like the legs.
    skin_rgb, clothes_rgb : (3,) float
        Linear-RGB albedo in ``0..1`` of the head and hands, and of the clothes.

    Returns
    -------
    list[BodyPart]
    """
    for what, rgb in (("skin_rgb", skin_rgb), ("clothes_rgb", clothes_rgb)):
        arr = np.asarray(rgb, dtype=np.float64)
        if arr.shape != (3,) or not np.all((arr >= 0.0) & (arr <= 1.0)):
            raise ValueError(f"body_surface: {what} must be 3 linear-RGB values in 0..1, got {rgb!r}")
    d = body_dimensions(params)
    parts = []
    for body in BODY_NAMES:
        if body.endswith("_r"):
            pieces = [_mirror_y(p) for p in _pieces(body[:-2] + "_l", d)]
        else:
            pieces = _pieces(body, d)
        mesh = trimesh.util.concatenate(pieces)
        centres = mesh.triangles_center
        patch = shirt_face_patch(body, centres, d) if shirt else np.full(len(mesh.faces), -1, dtype=np.int16)
        base = np.asarray(skin_rgb if body in SKIN_BODIES else clothes_rgb, dtype=np.float64)
        albedo = np.repeat(base[None, :], len(mesh.faces), axis=0)
        on_shirt = patch >= 0
        albedo[on_shirt] = SHIRT_COLOURS_RGB[PATCH_COLOUR[patch[on_shirt]]]
        parts.append(BodyPart(body=body, mesh=mesh, face_patch=patch, albedo=albedo, pieces=tuple(pieces)))
    return parts
