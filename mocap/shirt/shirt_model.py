"""The shirt as the pipeline sees it: its geometry (:mod:`mocap.shirt.geometry`) posed by the
upper-body kinematics (:mod:`mocap.shirt.kinematics`) and rasterised into id maps
(:mod:`mocap.shirt.zbuffer`) through a camera's crop or orthographically (:class:`ShirtModel`).

The colour-shirt pipeline (seed 001) renders id maps of candidate poses many times a
frame (the blended pose in every camera, the final pose for the white balance) and
once per entry when the pose database is built.  Everything it needs is here, and
nothing comes from the simulator: the geometry is a :class:`~mocap.shirt.geometry.ShirtGeometry`
and the kinematics a Pinocchio model built from the humanoid's MJCF text
(``docs/humanoid_spec.md``).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numba
import numpy as np

from mocap.calibration import Camera
from mocap.errors import MocapInputError
from mocap.shirt.geometry import ShirtGeometry
from mocap.shirt.kinematics import ShirtKinematics
from mocap.shirt.zbuffer import NEAR_M, rasterise_faces, rasterise_faces_over

__all__ = ["ShirtModel", "CropView", "Rendered", "look_at_view"]


def look_at_view(forward: np.ndarray, up: np.ndarray = np.array([0.0, -1.0, 0.0])) -> np.ndarray:
    """Rotation whose rows are view axes (x right, y down, z along ``forward``), in the input frame.

    ``up`` is the direction (same frame) that should appear upwards in the view; the
    default is a camera frame's own up (-y), so the view of a camera ray is that
    camera turned to look along the ray.
    """
    z = np.asarray(forward, float)
    z = z / np.linalg.norm(z)
    x = _cross3(z, np.asarray(up, float))
    if np.linalg.norm(x) < 1e-9:
        x = _cross3(z, np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 0.0, 1.0]))
    x /= np.linalg.norm(x)
    y = _cross3(z, x)
    return np.array([x, y, z])


def _cross3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``np.cross`` of two 3-vectors, the same products and differences in the same order (its
    generic path cost 0.1 ms a call, three calls for every camera's ray rotation a frame)."""
    a0, a1, a2 = (float(v) for v in a)
    b0, b1, b2 = (float(v) for v in b)
    return np.array([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0])


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


@dataclass(frozen=True)
class _MeshSplit:
    """The mesh's bodies that some hinges move (``body_names``, their vertex ``body_slices``, the vertices
    ``vertex_index`` in that order, their faces ``moved_faces`` indexing those, with mesh ids ``moved_ids``) and the
    faces of the others (``still_faces`` into the whole mesh's vertices, mesh ids ``still_ids``)."""

    body_names: tuple[str, ...]
    body_slices: tuple[slice, ...]
    vertex_index: np.ndarray
    still_faces: np.ndarray
    still_ids: np.ndarray
    moved_faces: np.ndarray
    moved_ids: np.ndarray


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
        self.shirt_vertex_index = np.flatnonzero(self._shirt_vertex)  # the shirt's vertices (:meth:`shirt_vertices`)
        self._patch_of = np.concatenate([[-1], self.face_patch]).astype(np.int16)
        self._colour_of = np.concatenate([[-1], self.face_colour]).astype(np.int16)
        self._layers: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}  # (_layered)
        self._parts: dict[tuple[int, int], _MeshSplit] = {}  # (_split)
        self._split_layers: dict[tuple, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}  # (_layered_part)

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
        # look-up tables with -1 (no face) in front: patch and colour of ``face + 1``
        return Rendered(face, self._patch_of[face + 1], self._colour_of[face + 1])

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
        elif camera.K[0, 1] == 0 and camera.K[1, 0] == 0 and Xc.dtype == np.float64:
            # the rest in one compiled pass (numpy's took five over the vertices, 4 renders of 2 cameras
            # and the arm search a frame); without skew each pixel coordinate of the K product is one
            # product plus an exact zero, the same value whatever order BLAS sums in
            K = camera.K
            return _pinhole_to_view(Xc, NEAR_M, K[0, 0], K[0, 1], K[1, 0], K[1, 1], K[0, 2], K[1, 2],
                                    float(view.x0), float(view.y0), float(view.scale)), z
        else:
            zs = np.where(z > NEAR_M, z, 1.0)
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
        faces, layer = self._layered(n, V)
        face = rasterise_faces(uv, z, faces, size, size, face_layer=layer, n_layers=n)
        return [self._finish_layer(face[i], i * T) for i in range(n)]

    def _layered(self, n: int, V: int) -> tuple[np.ndarray, np.ndarray]:
        """The mesh's faces repeated for ``n`` renders of ``V`` vertices each in one rasteriser call (vertex
        indices offset by ``V`` per layer) and each face's layer; kept (a few renders a frame, 8144 faces each)."""
        got = self._layers.get((n, V))
        if got is None:
            got = self._layers[(n, V)] = _repeat_faces(self.faces, n, V)
        return got

    def _finish_layer(self, face: np.ndarray, offset: int) -> Rendered:
        """``self._finish(self._layer_faces(face, offset))`` in one compiled pass over the map (integers: the same ids)."""
        f, patch, colour = _layer_maps(np.ascontiguousarray(face), int(offset), self._patch_of, self._colour_of)
        return Rendered(f, patch, colour)

    # ------------------------------------------------------------------ one part of the pose varied
    def render_variants(self, q: np.ndarray, hinges: slice, values: np.ndarray,
                        shots: list[tuple[Camera, CropView]]) -> list[list[Rendered]]:
        """:meth:`render_cameras` of pose ``q (18,)`` with ``q[hinges]`` set to each row of ``values (k, m)``.

        Why not ``k`` calls of :meth:`render_cameras`: the bodies that ``q[hinges]`` does not
        move (for an arm, 80 % of the mesh) look the same in every variant, so they are
        posed, projected and drawn once, and each variant draws only the moved bodies over
        a copy of that (:func:`mocap.shirt.zbuffer.rasterise_faces_over`; the same pixels
        where no two bodies tie in depth to the last bit).  The arm hypotheses of every
        frame render three arms per side this way (issue 18: 10 ms a frame as full renders).
        """
        values = np.atleast_2d(np.asarray(values, float))
        if not shots:
            return [[] for _ in values]
        size = shots[0][1].size
        if any(v.size != size for _, v in shots):
            out = []
            for row in values:
                qv = np.array(q, float)
                qv[hinges] = row
                out.append([self.render_camera(qv, c, v) for c, v in shots])
            return out
        part = self._split(hinges)
        n, k = len(shots), len(values)
        P = self.world_vertices(q)
        proj = [self._project(P, c, v) for c, v in shots]
        faces, ids, layer = self._layered_part(hinges, "still", n, len(P))
        face_map = np.full((n, size, size), -1, np.int32)
        depth_map = np.full((n, size, size), np.inf)
        rasterise_faces_over(np.concatenate([u for u, _ in proj]), np.concatenate([d for _, d in proj]),
                             faces, ids, layer, face_map, depth_map)
        qv = np.array(q, float)
        Vm = len(part.vertex_index)
        Pm = np.empty((k, Vm, 3))
        for j, row in enumerate(values):
            qv[hinges] = row
            R, p = self.kin.placements(qv, part.body_names)
            Pm[j] = np.concatenate([self._verts[sl] @ R[i].T + p[i] for i, sl in enumerate(part.body_slices)])
        # every variant projected in one call per camera, then ordered (variant, camera) as the layers
        proj = [self._project(Pm.reshape(-1, 3), c, v) for c, v in shots]
        uv = np.stack([u.reshape(k, Vm, 2) for u, _ in proj], axis=1).reshape(-1, 2)
        z = np.stack([d.reshape(k, Vm) for _, d in proj], axis=1).reshape(-1)
        face_maps = np.repeat(face_map[None], k, axis=0).reshape(k * n, size, size)
        depth_maps = np.repeat(depth_map[None], k, axis=0).reshape(k * n, size, size)
        faces, ids, layer = self._layered_part(hinges, "moved", k * n, Vm)
        rasterise_faces_over(uv, z, faces, ids, layer, face_maps, depth_maps)
        return [[self._finish_layer(face_maps[i * n + c], 0) for c in range(n)] for i in range(k)]

    def _split(self, hinges: slice) -> _MeshSplit:
        """The mesh split into the bodies that ``q[hinges]`` moves and the rest (kept per slice).

        Found by moving those hinges (bodies outside their subtree keep their placement to
        the bit: forward kinematics takes the same steps for them)."""
        key = (hinges.start, hinges.stop)
        got = self._parts.get(key)
        if got is not None:
            return got
        names = self.geometry.body_names
        q0 = self.kin.neutral()
        q1 = q0.copy()
        q1[hinges] += 0.3
        R0, p0 = self.kin.placements(q0, names)
        R1, p1 = self.kin.placements(q1, names)
        moved = [i for i in range(len(names)) if not (np.array_equal(R0[i], R1[i]) and np.array_equal(p0[i], p1[i]))]
        vertex_index = np.concatenate([np.arange(self._body_slices[i].start, self._body_slices[i].stop) for i in moved]) \
            if moved else np.zeros(0, np.int64)
        local = np.full(len(self._verts), -1, np.int64)
        local[vertex_index] = np.arange(len(vertex_index))
        is_moved = np.isin(self.face_body, moved)
        got = self._parts[key] = _MeshSplit(
            body_names=tuple(names[i] for i in moved), body_slices=tuple(self._body_slices[i] for i in moved),
            vertex_index=vertex_index, still_faces=self.faces[~is_moved], still_ids=np.flatnonzero(~is_moved).astype(np.int32),
            moved_faces=local[self.faces[is_moved]], moved_ids=np.flatnonzero(is_moved).astype(np.int32))
        return got

    def _layered_part(self, hinges: slice, which: str, n: int, V: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The faces of :meth:`_split`'s ``which`` part (``"still"`` or ``"moved"``) repeated for ``n`` layers of ``V``
        vertices each (as :meth:`_layered`), their mesh ids and layers; kept."""
        key = (hinges.start, hinges.stop, which, n, V)
        got = self._split_layers.get(key)
        if got is None:
            part = self._split(hinges)
            f, i = (part.still_faces, part.still_ids) if which == "still" else (part.moved_faces, part.moved_ids)
            faces, layer = _repeat_faces(f, n, V)
            got = self._split_layers[key] = (faces, np.tile(i, n), layer)
        return got

    @staticmethod
    def _layer_faces(face: np.ndarray, offset: int) -> np.ndarray:
        """``np.where(face >= 0, face - offset, -1)`` as int32: a layer's face ids back to the mesh's."""
        out = np.full(face.shape, -1, np.int32)
        np.subtract(face, offset, out=out, where=face >= 0, casting="unsafe")
        return out

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
        faces, layer = self._layered(n, V)
        face = rasterise_faces(uv, z, faces, size, size, face_layer=layer, n_layers=n)
        return [self._finish_layer(face[i], i * T) for i in range(n)]

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

    def shirt_image_box(self, shirt_world: np.ndarray, camera: Camera) -> tuple[np.ndarray, np.ndarray] | None:
        """The image box ``(lo (2,), hi (2,))`` px of the shirt's vertices ``shirt_world (Vs, 3)`` (world metres) in
        ``camera``, by the pinhole of its focal lengths and principal point (no skew, no lens: a box for the
        next crop); None when fewer than 3 vertices are more than 5 cm in front of it."""
        Xc = shirt_world @ camera.R.T + camera.t
        # (the division, scaling and extremes in one compiled pass: numpy's masked copies took 0.25 ms a camera)
        n, lo, hi = _pinhole_box(Xc, 0.05, camera.K[0, 0], camera.K[1, 1], camera.K[0, 2], camera.K[1, 2])
        return None if n < 3 else (lo, hi)

    def shirt_extent(self, view_vertices: np.ndarray) -> tuple[np.ndarray, float]:
        """Centre ``(2,)`` and side (m) of the square bounding the shirt's vertices in a view."""
        xy = view_vertices[self.shirt_vertex_index, :2]
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
        B = len(self.geometry.body_names)
        n, sums = _anchor_sums(rendered.face.ravel(), self.face_patch, self.face_body, self.face_centre_body, B, self.n_patches * B)
        used = np.flatnonzero(n > 0)
        if used.size == 0:
            return (np.zeros(0, int), np.zeros(0, int), np.zeros((0, 3)), np.zeros(0))
        per_patch = np.bincount(used // B, weights=n[used], minlength=self.n_patches)
        patch = used // B
        return patch, used % B, sums[used] / n[used, None], n[used] / per_patch[patch]



@numba.njit(cache=True, nogil=True)
def _anchor_sums(face, face_patch, face_body, centre, B, size):  # pragma: no cover
    """:meth:`ShirtModel.patch_anchors`' pixel counts ``(size,)`` and sums of face centres ``(size, 3)`` per
    (patch, body) key ``patch * B + body``, over the pixels in order: the sums of ``np.bincount`` with weights,
    compiled (its gathers and four counts over the map's pixels were most of the call)."""
    n = np.zeros(size)
    sums = np.zeros((size, 3))
    for i in range(face.shape[0]):
        f = face[i]
        if f < 0 or face_patch[f] < 0:
            continue
        key = face_patch[f] * B + face_body[f]
        n[key] += 1.0
        for k in range(3):
            sums[key, k] += centre[f, k]
    return n, sums


def _repeat_faces(faces: np.ndarray, n: int, V: int) -> tuple[np.ndarray, np.ndarray]:
    """``faces (T, 3)`` repeated for ``n`` layers of ``V`` vertices each in one rasteriser call (vertex indices
    offset by ``V`` per layer), and each face's layer ``(n T,)``."""
    return (faces[None] + (np.arange(n) * V)[:, None, None]).reshape(-1, 3), np.repeat(np.arange(n), len(faces))


@numba.njit(cache=True, nogil=True)
def _pinhole_to_view(Xc, near, k00, k01, k10, k11, cx, cy, x0, y0, scale):  # pragma: no cover
    """:meth:`ShirtModel._project`'s pinhole path after ``Xc``: ``zs = where(z > near, z, 1)``,
    ``uv = (Xc[:, :2] / zs) @ K[:2, :2].T + K[:2, 2]`` (with ``k01 = k10 = 0``), then ``view.from_image``:
    ``(uv - (x0, y0)) / scale``."""
    n = Xc.shape[0]
    out = np.empty((n, 2))
    for i in range(n):
        z = Xc[i, 2]
        zs = z if z > near else 1.0
        x = Xc[i, 0] / zs
        y = Xc[i, 1] / zs
        out[i, 0] = ((x * k00 + y * k01) + cx - x0) / scale
        out[i, 1] = ((x * k10 + y * k11) + cy - y0) / scale
    return out


@numba.njit(cache=True, nogil=True)
def _pinhole_box(Xc, near, fx, fy, cx, cy):  # pragma: no cover
    """Of the points ``Xc (n, 3)`` (camera metres) with ``z > near``: how many, and the least and greatest
    ``(x / z * fx + cx, y / z * fy + cy)`` (the same operations as numpy's ``Xc[:, :2] / Xc[:, 2:] * f + c``)."""
    lo = np.full(2, np.inf)
    hi = np.full(2, -np.inf)
    n = 0
    for i in range(Xc.shape[0]):
        z = Xc[i, 2]
        if not z > near:
            continue
        n += 1
        u = Xc[i, 0] / z * fx + cx
        v = Xc[i, 1] / z * fy + cy
        lo[0], hi[0] = min(lo[0], u), max(hi[0], u)
        lo[1], hi[1] = min(lo[1], v), max(hi[1], v)
    return n, lo, hi


@numba.njit(cache=True, nogil=True)
def _layer_maps(face, offset, patch_of, colour_of):  # pragma: no cover
    """Face ids of one layer (``face - offset`` where ``face >= 0``, else -1; int32) and their patch and colour by the
    look-up tables (entry ``id + 1``)."""
    f = np.empty(face.shape, np.int32)
    patch = np.empty(face.shape, patch_of.dtype)
    colour = np.empty(face.shape, colour_of.dtype)
    fr, pr, cr = face.reshape(-1), f.reshape(-1), patch.reshape(-1)
    for i in range(fr.size):
        g = fr[i] - offset if fr[i] >= 0 else -1
        pr[i] = g
        cr[i] = patch_of[g + 1]
    colour_r = colour.reshape(-1)
    for i in range(fr.size):
        colour_r[i] = colour_of[pr[i] + 1]
    return f, patch, colour
