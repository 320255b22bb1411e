"""The shirt as the pipeline sees it: body-frame triangle meshes with patch ids, posed by Pinocchio, rasterised.

The colour-shirt pipeline (seed 001) renders id maps of candidate poses many times a
frame (the blended pose in every camera, the final pose for the white balance) and
once per entry when the pose database is built.  Everything it needs is here, and
nothing comes from the simulator: the geometry is a :class:`ShirtGeometry` (arrays
the bench exports into the database file, or that a user makes from their own body
model) and the kinematics a Pinocchio model built from the humanoid's MJCF text
(``docs/humanoid_spec.md``).

Upper-body configuration
------------------------
Only the shirt is seen, so the pipeline estimates the shirt's bodies: the abdomen's
world pose, the thorax relative to it, both shoulders (3 hinges each) and elbows.  The
kinematics is Pinocchio's model of the humanoid *reduced* (``pinocchio.buildReducedModel``)
by locking every other hinge at zero: lumbar (its rotation is folded into the root,
which then carries the abdomen's orientation), neck, wrists and legs.  Its
configuration ``q`` (:data:`UPPER_NQ` = 18, tangent size :data:`UPPER_NV` = 17) is
``x y z qx qy qz qw`` of that root (Pinocchio's quaternion order) then the hinges of
:data:`UPPER_HINGES`.  :meth:`ShirtKinematics.from_full_qpos` maps a full MuJoCo
``qpos (40,)`` (ground truth) to it exactly for every body of the shirt.

Rasteriser
----------
:func:`rasterise_faces` is a small z-buffer: triangles are back-face culled and set up
(edge functions, depth planes, boxes) with numpy, then a compiled (numba) loop tests
the pixel centres of every box and keeps the nearest triangle per pixel.  It is
hand-written rather than borrowed from OpenGL because the pipeline must run without a
GL context (the ``mocap`` side never imports the renderer), and at the tiny
resolutions used here (40-128 px) a pass over a few thousand triangles costs about a
millisecond, less than a GL round trip; ``cv2.fillPoly`` has no depth test.
"""

from __future__ import annotations

import os
import tempfile
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import cv2
import numba
import numpy as np
import pinocchio as pin

from mocap.calibration import Camera
from mocap.errors import MocapInputError

__all__ = [
    "UPPER_HINGES",
    "UPPER_NQ",
    "UPPER_NV",
    "UPPER_BODY_JOINTS",
    "SHIRT_BODIES",
    "ShirtGeometry",
    "ShirtKinematics",
    "ShirtModel",
    "CropView",
    "Rendered",
    "rasterise_faces",
    "look_at_view",
]

UPPER_HINGES: tuple[str, ...] = (
    "thorax_x", "thorax_y", "thorax_z",
    "shoulder_l_x", "shoulder_l_y", "shoulder_l_z", "elbow_l",
    "shoulder_r_x", "shoulder_r_y", "shoulder_r_z", "elbow_r",
)
"""Hinges the pipeline estimates (in the reduced configuration's order)."""
UPPER_NQ = 7 + len(UPPER_HINGES)
UPPER_NV = 6 + len(UPPER_HINGES)

UPPER_BODY_JOINTS: tuple[str, ...] = (
    "abdomen", "thorax", "head", "upperarm_l", "forearm_l", "hand_l", "upperarm_r", "forearm_r", "hand_r",
)
"""Bodies whose origins (joint centres: lumbar, thorax, neck, shoulders, elbows, wrists) the shirt determines."""

SHIRT_BODIES: tuple[str, ...] = ("abdomen", "thorax", "upperarm_l", "forearm_l", "upperarm_r", "forearm_r")
"""Bodies that carry shirt patches."""

_NEAR_M = 0.05
_MAX_BOX_PIXELS = 4096  # triangles covering more pixel centres than this are dropped (only ever when absurdly close)


# --------------------------------------------------------------------------- geometry
@dataclass(frozen=True, eq=False)
class ShirtGeometry:
    """Triangle meshes of the shirt's bodies (and the few bodies that can hide it), in body frames.

    Attributes
    ----------
    body_names : tuple[str, ...]
        Bodies carrying geometry (names of the humanoid MJCF).
    vertices_m : (V, 3) float32
        Vertex positions in their body's frame, metres; the vertices of one body are
        contiguous, bodies in ``body_names`` order.
    vertex_body : (V,) int16
        Index into ``body_names`` of each vertex.
    faces : (T, 3) int32
        Vertex indices, counter-clockwise seen from outside (outward normals).
    face_patch : (T,) int16
        Shirt patch ``0..P-1`` of every face, ``-1`` for faces that only occlude (head, hands).
    patch_colour : (P,) int16
        Colour index ``0..K-1`` of every patch (two patches share each colour).
    colour_names : tuple[str, ...]
        Names of the K colours.
    """

    body_names: tuple[str, ...]
    vertices_m: np.ndarray
    vertex_body: np.ndarray
    faces: np.ndarray
    face_patch: np.ndarray
    patch_colour: np.ndarray
    colour_names: tuple[str, ...]

    def __post_init__(self) -> None:
        V = len(self.vertices_m)
        if np.asarray(self.vertices_m).shape != (V, 3) or np.asarray(self.vertex_body).shape != (V,):
            raise MocapInputError(f"ShirtGeometry: vertices_m must be (V, 3) and vertex_body (V,), got {np.shape(self.vertices_m)} and {np.shape(self.vertex_body)}")
        faces = np.asarray(self.faces)
        if faces.ndim != 2 or faces.shape[1] != 3 or (faces.size and (faces.min() < 0 or faces.max() >= V)):
            raise MocapInputError(f"ShirtGeometry: faces must be (T, 3) indices into {V} vertices")
        if np.asarray(self.face_patch).shape != (len(faces),):
            raise MocapInputError(f"ShirtGeometry: face_patch must have one entry per face ({len(faces)}), got {np.shape(self.face_patch)}")
        if np.any(np.asarray(self.face_patch) >= len(self.patch_colour)):
            raise MocapInputError("ShirtGeometry: a face_patch value has no entry in patch_colour")
        if np.any(np.asarray(self.patch_colour) >= len(self.colour_names)):
            raise MocapInputError("ShirtGeometry: a patch_colour value has no entry in colour_names")
        vb = np.asarray(self.vertex_body)
        if np.any(vb[faces[:, 0]] != vb[faces[:, 1]]) or np.any(vb[faces[:, 0]] != vb[faces[:, 2]]):
            raise MocapInputError("ShirtGeometry: every face must lie on one body")

    @property
    def n_patches(self) -> int:
        return len(self.patch_colour)

    @property
    def n_colours(self) -> int:
        return len(self.colour_names)

    @property
    def face_body(self) -> np.ndarray:
        """``(T,)`` body index of every face."""
        return np.asarray(self.vertex_body)[np.asarray(self.faces)[:, 0]]

    def to_arrays(self, prefix: str = "geometry_") -> dict[str, np.ndarray]:
        """Arrays for ``numpy.savez`` (strings as unicode arrays)."""
        return {
            f"{prefix}body_names": np.array(self.body_names),
            f"{prefix}vertices_m": np.asarray(self.vertices_m, np.float32),
            f"{prefix}vertex_body": np.asarray(self.vertex_body, np.int16),
            f"{prefix}faces": np.asarray(self.faces, np.int32),
            f"{prefix}face_patch": np.asarray(self.face_patch, np.int16),
            f"{prefix}patch_colour": np.asarray(self.patch_colour, np.int16),
            f"{prefix}colour_names": np.array(self.colour_names),
        }

    @classmethod
    def from_arrays(cls, arrays, prefix: str = "geometry_", source: str = "<arrays>") -> "ShirtGeometry":
        try:
            return cls(
                body_names=tuple(str(s) for s in arrays[f"{prefix}body_names"]),
                vertices_m=np.asarray(arrays[f"{prefix}vertices_m"], np.float32),
                vertex_body=np.asarray(arrays[f"{prefix}vertex_body"], np.int16),
                faces=np.asarray(arrays[f"{prefix}faces"], np.int32),
                face_patch=np.asarray(arrays[f"{prefix}face_patch"], np.int16),
                patch_colour=np.asarray(arrays[f"{prefix}patch_colour"], np.int16),
                colour_names=tuple(str(s) for s in arrays[f"{prefix}colour_names"]),
            )
        except KeyError as exc:
            raise MocapInputError(f"{source}: missing array {exc.args[0]!r}; rebuild the database with `simbench shirt build-db`") from None


# --------------------------------------------------------------------------- kinematics
def _model_from_mjcf_text(mjcf_text: str) -> pin.Model:
    """Pinocchio model of the humanoid MJCF text (Pinocchio parses MJCF from files only)."""
    fd, path = tempfile.mkstemp(suffix=".xml", prefix="shirt_humanoid_")
    try:
        with os.fdopen(fd, "w") as fh:
            fh.write(mjcf_text)
        return pin.buildModelFromMJCF(path)
    except Exception as exc:  # Pinocchio raises plain RuntimeError/ValueError on bad MJCF
        raise MocapInputError(f"humanoid MJCF: Pinocchio cannot build a model from it ({exc}); give the standalone humanoid of docs/humanoid_spec.md") from None
    finally:
        Path(path).unlink(missing_ok=True)


class ShirtKinematics:
    """Forward kinematics of the upper-body configuration (Pinocchio reduced model).

    Parameters
    ----------
    mjcf_text : str
        The standalone humanoid MJCF (free root ``root`` on ``pelvis``; hinges as in
        ``docs/humanoid_spec.md``).
    """

    def __init__(self, mjcf_text: str) -> None:
        full = _model_from_mjcf_text(mjcf_text)
        if full.joints[1].shortname() != "JointModelFreeFlyer":
            raise MocapInputError("humanoid MJCF: the root body must carry a free joint (see docs/humanoid_spec.md)")
        # Pinocchio merges the hinges of one body into a composite joint and keeps the
        # MJCF order in q: read the hinge names from the XML in document order.
        names = [j.get("name", "") for j in ET.fromstring(mjcf_text).iter("joint") if j.get("type", "hinge") == "hinge"]
        if len(names) != full.nq - 7:
            raise MocapInputError(f"humanoid MJCF: {len(names)} hinges in the XML but Pinocchio built {full.nq - 7}; use only hinges below the free root")
        missing = [h for h in UPPER_HINGES + ("lumbar_x",) if h not in names]
        if missing:
            raise MocapInputError(f"humanoid MJCF: hinges {missing} are missing; the shirt pipeline needs the humanoid of docs/humanoid_spec.md")
        self.full_model = full
        self.full_data = full.createData()
        self.full_hinge_names = names
        lock = []
        for j in range(2, full.njoints):
            jm = full.joints[j]
            covered = names[jm.idx_q - 7: jm.idx_q - 7 + jm.nq]
            inside = [h in UPPER_HINGES for h in covered]
            if not any(inside):
                lock.append(j)
            elif not all(inside):
                raise MocapInputError(f"humanoid MJCF: joint {full.names[j]} mixes estimated and fixed hinges {covered}")
        self.model = pin.buildReducedModel(full, lock, pin.neutral(full))
        self.data = self.model.createData()
        kept = [h for h in names if h in UPPER_HINGES]
        if tuple(kept) != UPPER_HINGES or self.model.nq != UPPER_NQ:
            raise MocapInputError(f"humanoid MJCF: estimated hinges in the order {kept}, expected {list(UPPER_HINGES)}; keep the body order of docs/humanoid_spec.md")
        self.lower = np.asarray(self.model.lowerPositionLimit[7:], float).copy()
        self.upper = np.asarray(self.model.upperPositionLimit[7:], float).copy()
        self._frame = {}
        for f in range(self.model.nframes):
            fr = self.model.frames[f]
            if fr.type == pin.FrameType.BODY:
                self._frame[fr.name] = f
        self._abdomen_full = full.getFrameId("abdomen", pin.FrameType.BODY)
        # abdomen origin in the pelvis frame at zero lumbar angles (lumbar joint placement)
        pin.framesForwardKinematics(full, self.full_data, pin.neutral(full))
        self._abdomen_in_pelvis = self.full_data.oMf[self._abdomen_full].copy()
        self._full_hinge_index = {n: 7 + i for i, n in enumerate(names)}

    # ------------------------------------------------------------------ configurations
    @property
    def nq(self) -> int:
        return int(self.model.nq)

    @property
    def nv(self) -> int:
        return int(self.model.nv)

    def frame_id(self, body: str) -> int:
        if body not in self._frame:
            raise MocapInputError(f"humanoid MJCF: no body {body!r}")
        return self._frame[body]

    def neutral(self) -> np.ndarray:
        return np.asarray(pin.neutral(self.model), float)

    def from_full_qpos(self, qpos: np.ndarray) -> np.ndarray:
        """MuJoCo humanoid ``qpos (..., 40)`` (quaternion ``w x y z``) -> upper-body ``q (..., 18)``.

        The root takes the abdomen's world pose (lumbar rotation folded in), so every
        shirt body has exactly the same world placement in both.
        """
        qpos = np.asarray(qpos, float)
        flat = qpos.reshape(-1, qpos.shape[-1])
        if flat.shape[1] != self.full_model.nq:
            raise MocapInputError(f"qpos must have {self.full_model.nq} values (MuJoCo humanoid qpos), got {flat.shape[1]}")
        out = np.empty((len(flat), self.nq))
        for i, qm in enumerate(flat):
            qp = qm.copy()
            qp[3:7] = qm[[4, 5, 6, 3]]
            pin.framesForwardKinematics(self.full_model, self.full_data, qp)
            abd = self.full_data.oMf[self._abdomen_full]
            root = abd * self._abdomen_in_pelvis.inverse()
            out[i, :7] = pin.SE3ToXYZQUAT(root)
            out[i, 7:] = [qm[self._full_hinge_index[h]] for h in UPPER_HINGES]
        return out.reshape(*qpos.shape[:-1], self.nq)

    def to_full_qpos(self, q: np.ndarray) -> np.ndarray:
        """Upper-body ``q (..., 18)`` -> MuJoCo ``qpos (..., 40)`` with every other hinge at zero."""
        q = np.asarray(q, float)
        flat = q.reshape(-1, self.nq)
        out = np.zeros((len(flat), self.full_model.nq))
        out[:, :3] = flat[:, :3]
        out[:, 3] = flat[:, 6]
        out[:, 4:7] = flat[:, 3:6]
        for i, h in enumerate(UPPER_HINGES):
            out[:, self._full_hinge_index[h]] = flat[:, 7 + i]
        return out.reshape(*q.shape[:-1], self.full_model.nq)

    def make_q(self, rotation: np.ndarray, translation_m: np.ndarray, hinges: np.ndarray) -> np.ndarray:
        """``q (18,)`` from a root rotation ``(3, 3)``, translation ``(3,)`` m and hinges ``(11,)`` rad."""
        q = np.empty(self.nq)
        q[:7] = pin.SE3ToXYZQUAT(pin.SE3(np.asarray(rotation, float), np.asarray(translation_m, float)))
        q[7:] = hinges
        return q

    def clamp(self, q: np.ndarray) -> np.ndarray:
        """Hinges clipped to the joint limits; quaternion normalised."""
        q = np.array(q, float)
        q[7:] = np.clip(q[7:], self.lower, self.upper)
        q[3:7] /= np.linalg.norm(q[3:7])
        return q

    # ------------------------------------------------------------------ kinematics
    def placements(self, q: np.ndarray, bodies: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray]:
        """World rotation ``(B, 3, 3)`` and origin ``(B, 3)`` m of ``bodies`` at ``q``."""
        pin.framesForwardKinematics(self.model, self.data, np.asarray(q, float))
        R = np.empty((len(bodies), 3, 3))
        p = np.empty((len(bodies), 3))
        for i, b in enumerate(bodies):
            M = self.data.oMf[self.frame_id(b)]
            R[i] = M.rotation
            p[i] = M.translation
        return R, p

    def joint_centres(self, q: np.ndarray) -> np.ndarray:
        """``(..., J, 3)`` origins of :data:`UPPER_BODY_JOINTS` (metres) for ``q (..., 18)``."""
        q = np.asarray(q, float)
        flat = q.reshape(-1, self.nq)
        out = np.full((len(flat), len(UPPER_BODY_JOINTS), 3), np.nan)
        for i, qi in enumerate(flat):
            if np.all(np.isfinite(qi)):
                out[i] = self.placements(qi, UPPER_BODY_JOINTS)[1]
        return out.reshape(*q.shape[:-1], len(UPPER_BODY_JOINTS), 3)


# --------------------------------------------------------------------------- rasteriser
def rasterise_faces(uv: np.ndarray, depth: np.ndarray, faces: np.ndarray, width: int, height: int,
                    cull_back: bool = True, face_layer: np.ndarray | None = None, n_layers: int = 1) -> np.ndarray:
    """Index of the nearest triangle covering every pixel centre (a z-buffer).

    Parameters
    ----------
    uv : (V, 2) float
        Vertex image positions, pixels, OpenCV convention (x right, y down, pixel
        centres at integers).
    depth : (V,) float
        Vertex depth along the viewing direction (metres; larger is farther).  Vertices
        with depth below 5 cm drop their triangles.
    faces : (T, 3) int
        Counter-clockwise seen from outside; with ``cull_back`` triangles seen from
        behind are skipped (closed meshes: they are hidden anyway).
    width, height : int
        Image size in pixels.
    face_layer : (T,) int, optional
        Image (of ``n_layers``) each triangle is drawn into: many small renders in one call.

    Returns
    -------
    (height, width) int32, or (n_layers, height, width) with ``face_layer``
        Triangle index per pixel, ``-1`` where none covers the pixel centre.

    Notes
    -----
    Triangles are grouped by the pixel centres their bounding boxes span: up to 2x2
    and up to 4x4 (nearly all of them at the pipeline's resolutions; edge functions in
    float32), larger ones (float64); the set-up and the z-buffer (:func:`_rasterise`,
    :func:`_zbuffer`) are compiled, the groups drawn in that order.
    Each triangle carries its three edge functions and its depth plane as
    ``a x + b y + c``.
    """
    npix = height * width
    shape = (height, width) if face_layer is None else (n_layers, height, width)
    out = np.full(npix * (1 if face_layer is None else n_layers), -1, np.int32)
    if len(faces) == 0:
        return out.reshape(shape)
    base = np.zeros(len(faces), np.int64) if face_layer is None else np.asarray(face_layer, np.int64) * npix
    _rasterise(np.ascontiguousarray(uv, np.float64), np.ascontiguousarray(depth, np.float64), np.ascontiguousarray(faces, np.int64),
               int(width), int(height), bool(cull_back), base, out)
    return out.reshape(shape)


@numba.njit(cache=True, nogil=True)
def _rasterise(uv, depth, faces, width, height, cull_back, base, out):  # pragma: no cover
    """Set-up of every triangle (as the vectorised form had it, operation for operation) and :func:`_zbuffer`."""
    n = len(faces)
    keep = np.zeros(n, np.bool_)
    xmin = np.empty(n, np.int64)
    ymin = np.empty(n, np.int64)
    nx = np.empty(n, np.int64)
    ny = np.empty(n, np.int64)
    tier = np.empty(n, np.int64)
    ec = np.empty((n, 3))
    ea = np.empty((n, 3))
    eb = np.empty((n, 3))
    zc = np.empty(n)
    za = np.empty(n)
    zb = np.empty(n)
    X = np.empty(3)
    Y = np.empty(3)
    Z = np.empty(3)
    for f in range(n):
        for j in range(3):
            v = faces[f, j]
            X[j] = uv[v, 0]
            Y[j] = uv[v, 1]
            Z[j] = depth[v]
        area = (X[1] - X[0]) * (Y[2] - Y[0]) - (Y[1] - Y[0]) * (X[2] - X[0])
        # seen from the front, an outward-facing counter-clockwise triangle has negative
        # signed area in image coordinates (y points down)
        if cull_back:
            if not area < -1e-9:
                continue
        elif not abs(area) > 1e-9:
            continue
        if not min(min(Z[0], Z[1]), Z[2]) > _NEAR_M:
            continue
        fxmin = np.ceil(min(min(X[0], X[1]), X[2]))
        fxmax = np.floor(max(max(X[0], X[1]), X[2]))
        fymin = np.ceil(min(min(Y[0], Y[1]), Y[2]))
        fymax = np.floor(max(max(Y[0], Y[1]), Y[2]))
        if not (fxmax >= 0 and fymax >= 0 and fxmin <= width - 1 and fymin <= height - 1 and fxmax >= fxmin and fymax >= fymin):
            continue
        fxmin, fxmax = max(fxmin, 0.0), min(fxmax, width - 1.0)
        fymin, fymax = max(fymin, 0.0), min(fymax, height - 1.0)
        fnx = fxmax - fxmin + 1
        fny = fymax - fymin + 1
        if not fnx * fny <= _MAX_BOX_PIXELS:
            continue
        keep[f] = True
        xmin[f], ymin[f], nx[f], ny[f] = int(fxmin), int(fymin), int(fnx), int(fny)
        tier[f] = 2 if (fnx <= 2 and fny <= 2) else (4 if (fnx <= 4 and fny <= 4) else 0)
        # edge function of edge (i -> j), positive inside: sign(area) * ((xj - xi)(y - yi) - (yj - yi)(x - xi)),
        # and the depth plane, both at the box corner (xmin, ymin)
        sg = np.sign(area)
        for e in range(3):
            i0 = (e + 1) % 3
            i1 = (e + 2) % 3
            ea[f, e] = -(Y[i1] - Y[i0]) * sg
            eb[f, e] = (X[i1] - X[i0]) * sg
            ec[f, e] = ea[f, e] * (fxmin - X[i0]) + eb[f, e] * (fymin - Y[i0])
        w = 1.0 / area
        za[f] = ((Z[1] - Z[0]) * (Y[2] - Y[0]) - (Z[2] - Z[0]) * (Y[1] - Y[0])) * w
        zb[f] = ((X[1] - X[0]) * (Z[2] - Z[0]) - (X[2] - X[0]) * (Z[1] - Z[0])) * w
        zc[f] = Z[0] + za[f] * (fxmin - X[0]) + zb[f] * (fymin - Y[0])
    sel = np.flatnonzero(keep)
    _zbuffer(tier[sel], nx[sel], ny[sel], xmin[sel], ymin[sel], base[sel], sel.astype(np.int32), ec[sel].astype(np.float32),
             ea[sel].astype(np.float32), eb[sel].astype(np.float32), ec[sel], ea[sel], eb[sel], zc[sel], za[sel], zb[sel], width, out)


@numba.njit(cache=True, nogil=True)
def _zbuffer(tier, nx, ny, xmin, ymin, base_pix, face, ec32, ea32, eb32, ec, ea, eb, zc, za, zb, width, out):  # pragma: no cover
    """The z-buffer of :func:`rasterise_faces`, compiled: a loop over triangles and the pixel centres of their boxes.

    Why compiled: the vectorised form spends most of its time building and filtering
    candidate (triangle, pixel) arrays, a few thousand tiny triangles per render, many
    renders per frame.  The same arithmetic as that form (edge functions of boxes up to
    4 x 4 in float32, larger ones in float64; depth planes in float64) and the same order
    (boxes up to 2 x 2, then up to 4 x 4, then larger; each row by row), so the same
    triangle wins every pixel, ties included (the last one drawn at the least depth).
    """
    zbuf = np.full(out.size, np.inf)
    tol32 = np.float32(-1e-6)
    for g in (2, 4, 0):
        for f in range(len(tier)):
            if tier[f] != g:
                continue
            w = nx[f]
            h = ny[f]
            for cy in range(h):
                for cx in range(w):
                    if g:
                        fx = np.float32(cx)
                        fy = np.float32(cy)
                        if not (ec32[f, 0] + ea32[f, 0] * fx + eb32[f, 0] * fy >= tol32 and ec32[f, 1] + ea32[f, 1] * fx + eb32[f, 1] * fy >= tol32
                                and ec32[f, 2] + ea32[f, 2] * fx + eb32[f, 2] * fy >= tol32):
                            continue
                    else:
                        dx = np.float64(cx)
                        dy = np.float64(cy)
                        if not (ec[f, 0] + ea[f, 0] * dx + eb[f, 0] * dy >= -1e-6 and ec[f, 1] + ea[f, 1] * dx + eb[f, 1] * dy >= -1e-6
                                and ec[f, 2] + ea[f, 2] * dx + eb[f, 2] * dy >= -1e-6):
                            continue
                    z = zc[f] + za[f] * np.float64(cx) + zb[f] * np.float64(cy)
                    pix = base_pix[f] + (ymin[f] + cy) * width + xmin[f] + cx
                    if z <= zbuf[pix]:
                        zbuf[pix] = z
                        out[pix] = face[f]


def look_at_view(forward: np.ndarray, up: np.ndarray = np.array([0.0, -1.0, 0.0])) -> np.ndarray:
    """Rotation whose rows are view axes (x right, y down, z along ``forward``), in the input frame.

    ``up`` is the direction (same frame) that should appear upwards in the view; the
    default is a camera frame's own up (-y), so the view of a camera ray is that
    camera turned to look along the ray.
    """
    z = np.asarray(forward, float)
    z = z / np.linalg.norm(z)
    x = np.cross(z, np.asarray(up, float))
    if np.linalg.norm(x) < 1e-9:
        x = np.cross(z, np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 0.0, 1.0]))
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return np.vstack([x, y, z])


# --------------------------------------------------------------------------- the model
@dataclass(frozen=True)
class CropView:
    """A square region of a camera image rendered (or classified) at a working resolution.

    Attributes
    ----------
    x0, y0 : float
        Image position (px) of the crop's top-left pixel centre.
    scale : float
        Image pixels per working pixel (``crop side / resolution``).
    size : int
        Working resolution (pixels per side).
    """

    x0: float
    y0: float
    scale: float
    size: int

    def to_image(self, xy: np.ndarray) -> np.ndarray:
        """Working-pixel coordinates ``(..., 2)`` -> image pixels."""
        return np.asarray(xy, float) * self.scale + np.array([self.x0, self.y0])

    def from_image(self, uv: np.ndarray) -> np.ndarray:
        """Image pixels ``(..., 2)`` -> working-pixel coordinates."""
        return (np.asarray(uv, float) - np.array([self.x0, self.y0])) / self.scale


@dataclass
class Rendered:
    """An id map of a pose and what the pipeline derives from it.

    Attributes
    ----------
    face : (H, W) int32
        Triangle index per pixel, -1 for none.
    patch : (H, W) int16
        Shirt patch per pixel, -1 where no shirt is seen (background or an occluder).
    colour : (H, W) int16
        Colour id per pixel, -1 where no shirt is seen.
    """

    face: np.ndarray
    patch: np.ndarray
    colour: np.ndarray


class ShirtModel:
    """Shirt geometry + upper-body kinematics: pose, project and rasterise.

    Parameters
    ----------
    mjcf_text : str
        Humanoid MJCF (see :class:`ShirtKinematics`).
    geometry : ShirtGeometry
    """

    def __init__(self, mjcf_text: str, geometry: ShirtGeometry) -> None:
        self.kin = ShirtKinematics(mjcf_text)
        self.geometry = geometry
        for b in geometry.body_names:
            self.kin.frame_id(b)
        self.mjcf_text = mjcf_text
        g = geometry
        self._verts = np.asarray(g.vertices_m, np.float64)
        vb = np.asarray(g.vertex_body, np.int64)
        self._body_slices = []
        for i in range(len(g.body_names)):
            idx = np.flatnonzero(vb == i)
            if idx.size == 0:
                raise MocapInputError(f"ShirtGeometry: body {g.body_names[i]!r} has no vertices")
            if idx[-1] - idx[0] + 1 != idx.size:
                raise MocapInputError("ShirtGeometry: the vertices of each body must be contiguous")
            self._body_slices.append(slice(int(idx[0]), int(idx[-1]) + 1))
        self.faces = np.asarray(g.faces, np.int64)
        self.face_patch = np.asarray(g.face_patch, np.int16)
        self.face_colour = np.where(self.face_patch >= 0, np.asarray(g.patch_colour)[np.maximum(self.face_patch, 0)], -1).astype(np.int16)
        self.face_body = g.face_body.astype(np.int64)
        self.face_centre_body = self._verts[self.faces].mean(axis=1)  # (T, 3) in the face's body frame
        self.patch_colour = np.asarray(g.patch_colour, np.int64)
        self.n_patches = g.n_patches
        self.n_colours = g.n_colours
        shirt = self.face_patch >= 0
        self._shirt_vertex = np.zeros(len(self._verts), bool)
        self._shirt_vertex[np.unique(self.faces[shirt])] = True

    # ------------------------------------------------------------------ posing
    def world_vertices(self, q: np.ndarray) -> np.ndarray:
        """``(V, 3)`` vertex positions in the world (metres) at upper-body configuration ``q``."""
        R, p = self.kin.placements(q, self.geometry.body_names)
        out = np.empty_like(self._verts)
        for i, sl in enumerate(self._body_slices):
            out[sl] = self._verts[sl] @ R[i].T + p[i]
        return out

    def shirt_vertices(self, q: np.ndarray) -> np.ndarray:
        """``(..., Vs, 3)`` world positions of the shirt's vertices (faces with a patch) for ``q (..., 18)``."""
        q = np.asarray(q, float)
        flat = q.reshape(-1, self.kin.nq)
        n = int(self._shirt_vertex.sum())
        out = np.full((len(flat), n, 3), np.nan)
        for i, qi in enumerate(flat):
            if np.all(np.isfinite(qi)):
                out[i] = self.world_vertices(qi)[self._shirt_vertex]
        return out.reshape(*q.shape[:-1], n, 3)

    # ------------------------------------------------------------------ rendering
    def _finish(self, face: np.ndarray) -> Rendered:
        ok = face >= 0
        f = np.where(ok, face, 0)
        patch = np.where(ok, self.face_patch[f], -1).astype(np.int16)
        colour = np.where(ok, self.face_colour[f], -1).astype(np.int16)
        return Rendered(face, patch, colour)

    def render_camera(self, q: np.ndarray, camera: Camera, view: CropView, world: np.ndarray | None = None) -> Rendered:
        """Rasterise pose ``q`` as seen by ``camera`` in the crop ``view`` (working pixels).

        ``world`` : (V, 3) float, optional — :meth:`world_vertices` of ``q`` when the caller
        already has them (one pose rendered in several cameras).
        """
        P = self.world_vertices(q) if world is None else world
        uv, z = self._project(P, camera, view)
        return self._finish(rasterise_faces(uv, z, self.faces, view.size, view.size))

    def _project(self, P: np.ndarray, camera: Camera, view: CropView) -> tuple[np.ndarray, np.ndarray]:
        """Crop-view pixel positions ``(V, 2)`` and depths ``(V,)`` of world points ``P``."""
        Xc = P @ camera.R.T + camera.t
        z = Xc[:, 2]
        if np.any(camera.dist != 0):
            uv, _ = cv2.projectPoints(P, camera.rvec, camera.t, camera.K, camera.dist)
            uv = uv.reshape(-1, 2)
        else:
            zs = np.where(z > _NEAR_M, z, 1.0)
            uv = (Xc[:, :2] / zs[:, None]) @ camera.K[:2, :2].T + camera.K[:2, 2]
        return view.from_image(uv), z

    def render_cameras(self, q: np.ndarray, shots: list[tuple[Camera, CropView]], world: np.ndarray | None = None) -> list[Rendered]:
        """:meth:`render_camera` of one pose in several (camera, crop view) pairs of one size, one rasteriser call.

        The same pixels as separate calls (each camera's triangles go to their own layer).
        """
        if not shots:
            return []
        size = shots[0][1].size
        if any(v.size != size for _, v in shots):
            return [self.render_camera(q, c, v, world) for c, v in shots]
        P = self.world_vertices(q) if world is None else world
        V, T, n = len(P), len(self.faces), len(shots)
        proj = [self._project(P, c, v) for c, v in shots]
        uv = np.concatenate([u for u, _ in proj])
        z = np.concatenate([d for _, d in proj])
        faces = (self.faces[None] + (np.arange(n) * V)[:, None, None]).reshape(-1, 3)
        layer = np.repeat(np.arange(n), T)
        face = rasterise_faces(uv, z, faces, size, size, face_layer=layer, n_layers=n)
        return [self._finish(np.where(face[i] >= 0, face[i] - i * T, -1).astype(np.int32)) for i in range(n)]

    def view_vertices(self, hinges: np.ndarray, view_rotation: np.ndarray) -> np.ndarray:
        """``(V, 3)`` vertices in a view frame for a root at the origin with orientation ``view_rotation``.

        ``view_rotation`` maps root-frame vectors to view coordinates (x right, y down,
        z away from the viewer).
        """
        q = self.kin.make_q(np.eye(3), np.zeros(3), hinges)
        return self.world_vertices(q) @ np.asarray(view_rotation, float).T

    def render_orthographic(self, view_vertices: np.ndarray, centre_m: np.ndarray, side_m: float, size: int) -> Rendered:
        """Orthographic id map of view-frame vertices over the square ``centre_m +- side_m / 2``.

        Pixel ``(i, j)`` centre sits at view ``centre + ((j + 0.5) / size - 0.5) * side``
        (and likewise for rows); depth is the view z plus a large offset.
        """
        s = size / float(side_m)
        uv = (view_vertices[:, :2] - np.asarray(centre_m, float)) * s + size / 2.0 - 0.5
        z = view_vertices[:, 2] + 100.0
        return self._finish(rasterise_faces(uv, z, self.faces, size, size))

    def render_orthographic_views(self, view_vertices: list[np.ndarray], centres_m: list[np.ndarray], sides_m: list[float],
                                  size: int) -> list[Rendered]:
        """:meth:`render_orthographic` of several views, one rasteriser call (the same pixels)."""
        n = len(view_vertices)
        if n == 0:
            return []
        V, T = len(view_vertices[0]), len(self.faces)
        uv = np.concatenate([(vv[:, :2] - np.asarray(c, float)) * (size / float(sd)) + size / 2.0 - 0.5
                             for vv, c, sd in zip(view_vertices, centres_m, sides_m)])
        z = np.concatenate([vv[:, 2] + 100.0 for vv in view_vertices])
        faces = (self.faces[None] + (np.arange(n) * V)[:, None, None]).reshape(-1, 3)
        face = rasterise_faces(uv, z, faces, size, size, face_layer=np.repeat(np.arange(n), T), n_layers=n)
        return [self._finish(np.where(face[i] >= 0, face[i] - i * T, -1).astype(np.int32)) for i in range(n)]

    def view_vertices_batch(self, hinges: np.ndarray, view_rotation: np.ndarray) -> np.ndarray:
        """``(B, V, 3)`` view-frame vertices of ``B`` poses (see :meth:`view_vertices`)."""
        hinges = np.asarray(hinges, float)
        B = len(hinges)
        nb = len(self.geometry.body_names)
        R = np.empty((B, nb, 3, 3))
        p = np.empty((B, nb, 3))
        for i in range(B):
            R[i], p[i] = self.kin.placements(self.kin.make_q(np.eye(3), np.zeros(3), hinges[i]), self.geometry.body_names)
        V = np.asarray(view_rotation, float)
        R = np.einsum("bij,bkjl->bkil", V, R)
        p = np.einsum("bij,bkj->bki", V, p)
        out = np.empty((B, len(self._verts), 3))
        for k, sl in enumerate(self._body_slices):
            out[:, sl] = np.einsum("bij,vj->bvi", R[:, k], self._verts[sl]) + p[:, k, None, :]
        return out

    def render_orthographic_batch(self, view_vertices: np.ndarray, centre_m: np.ndarray, side_m: np.ndarray, size: int) -> np.ndarray:
        """Colour id maps ``(B, size, size)`` of ``B`` poses (see :meth:`render_orthographic`), one rasteriser call."""
        vv = np.asarray(view_vertices, float)
        B, V, _ = vv.shape
        s = size / np.asarray(side_m, float)
        uv = (vv[..., :2] - np.asarray(centre_m, float)[:, None, :]) * s[:, None, None] + size / 2.0 - 0.5
        z = vv[..., 2] + 100.0
        faces = (self.faces[None, :, :] + (np.arange(B) * V)[:, None, None]).reshape(-1, 3)
        layer = np.repeat(np.arange(B), len(self.faces))
        face = rasterise_faces(uv.reshape(-1, 2), z.ravel(), faces, size, size, face_layer=layer, n_layers=B)
        T = len(self.faces)
        ok = face >= 0
        return np.where(ok, self.face_colour[np.where(ok, face % T, 0)], -1).astype(np.int16)

    def shirt_extent_batch(self, view_vertices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Centres ``(B, 2)`` and sides ``(B,)`` of the squares bounding the shirt in each view."""
        xy = np.asarray(view_vertices)[:, self._shirt_vertex, :2]
        lo, hi = xy.min(axis=1), xy.max(axis=1)
        return 0.5 * (lo + hi), np.max(hi - lo, axis=1)

    def shirt_extent(self, view_vertices: np.ndarray) -> tuple[np.ndarray, float]:
        """Centre ``(2,)`` and side (m) of the square bounding the shirt's vertices in a view."""
        xy = view_vertices[self._shirt_vertex, :2]
        lo, hi = xy.min(axis=0), xy.max(axis=0)
        return 0.5 * (lo + hi), float(np.max(hi - lo))

    def patch_anchors(self, rendered: Rendered) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Where each visible patch lies on the bodies, from a rendered id map.

        The centroid of a patch's pixels is modelled as the pixel-weighted mean of the
        projections of one point per (patch, body): the mean body-frame position of the
        faces seen in those pixels.

        Returns
        -------
        patch : (A,) int
            Patch of each anchor.
        body : (A,) int
            Body index (``geometry.body_names``) of each anchor.
        point_m : (A, 3) float
            Anchor in its body's frame, metres.
        weight : (A,) float
            Fraction of the patch's pixels that belong to this body (sums to 1 per patch).
        """
        f = rendered.face.ravel()
        f = f[f >= 0]
        p = self.face_patch[f].astype(np.int64)
        on = p >= 0
        f, p = f[on], p[on]
        if f.size == 0:
            return (np.zeros(0, int), np.zeros(0, int), np.zeros((0, 3)), np.zeros(0))
        B = len(self.geometry.body_names)
        key = p * B + self.face_body[f]
        n = np.bincount(key, minlength=self.n_patches * B).astype(float)
        c = self.face_centre_body[f]
        sums = np.stack([np.bincount(key, weights=c[:, k], minlength=self.n_patches * B) for k in range(3)], axis=1)
        used = np.flatnonzero(n > 0)
        per_patch = np.bincount(used // B, weights=n[used], minlength=self.n_patches)
        patch = used // B
        return patch, used % B, sums[used] / n[used, None], n[used] / per_patch[patch]
