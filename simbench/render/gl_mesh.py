"""Triangle geometry on the GPU: the vertex arrays a scene hands the rasteriser
(:class:`GeometryBuffers`) and their GL buffers (:class:`Mesh`), with the back faces of
closed meshes culled (:func:`closed_outward_faces`). See :mod:`simbench.render.rasterizer`.
"""

from __future__ import annotations

import ctypes
from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

import simbench.render.gl_context  # noqa: F401  (configures the GL platform before PyOpenGL loads)

from OpenGL import GL as gl  # noqa: E402  (after the platform is configured)


@dataclass
class GeometryBuffers:
    """Indexed vertex arrays for one draw call.

    positions, normals : (V, 3) float32, world frame (static) or updated per frame
    albedo : (V, 3) float32 linear RGB in 0..1
    ids : (V,) int32 (0 is background; see :mod:`simbench.render.ids`)
    retro : (V,) float32 retro-reflective gain (0 for ordinary surfaces)
    faces : (T, 3) uint32 vertex indices
    uv : (V, 2) float32 texture coordinates in 0..1 for textured vertices, -1 elsewhere
        (None: untextured); the texture is set with :meth:`simbench.render.rasterizer.Rasterizer.set_texture`
    """

    positions: np.ndarray
    normals: np.ndarray
    albedo: np.ndarray
    ids: np.ndarray
    retro: np.ndarray
    faces: np.ndarray
    uv: np.ndarray | None = None


def closed_outward_faces(faces: np.ndarray, positions: np.ndarray) -> np.ndarray:
    """Which faces ``(T,)`` bool belong to a closed, consistently oriented, outward-wound component.

    A component is closed and consistently oriented when each of its directed edges
    ``(a, b)`` occurs once and its reverse ``(b, a)`` occurs too; outward when its signed
    volume (counter-clockwise faces seen from outside) is positive. The back faces of
    such a component are always hidden behind its front faces (for a camera outside it),
    so culling them changes no pixel.
    """
    F = np.asarray(faces, np.int64).reshape(-1, 3)
    P = np.asarray(positions, np.float64)
    nv = len(P)
    if len(F) == 0:
        return np.zeros(0, bool)
    e = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    n_comp, label = connected_components(coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(nv, nv)),
                                         directed=False)
    key = e[:, 0] * nv + e[:, 1]
    uniq, count = np.unique(key, return_counts=True)
    bad_edge = ~np.isin(e[:, 1] * nv + e[:, 0], key) | (count[np.searchsorted(uniq, key)] > 1)
    open_comp = np.zeros(n_comp, bool)
    open_comp[label[e[bad_edge, 0]]] = True
    a, b, c = P[F[:, 0]], P[F[:, 1]], P[F[:, 2]]
    volume = np.bincount(label[F[:, 0]], weights=np.einsum("ij,ij->i", a, np.cross(b, c)), minlength=n_comp)
    good = ~open_comp & (volume > 0)
    return good[label[F[:, 0]]]


class Mesh:
    """One :class:`GeometryBuffers` in GL buffers: static, or with positions and normals updated per frame."""

    def __init__(self, buf: GeometryBuffers, dynamic: bool) -> None:
        self.n = len(buf.positions)
        self.n_idx = int(np.asarray(buf.faces).size)
        # Closed outward meshes (the body, markers, props) first, drawn with back faces
        # culled: llvmpipe's cost for the moving body is per triangle (setup and binning),
        # and half of a closed mesh's triangles face away. Open surfaces stay two-sided.
        faces = np.asarray(buf.faces, np.uint32).reshape(-1, 3)
        closed = closed_outward_faces(faces, buf.positions)
        # Within each group, faces in order of their lowest vertex index: llvmpipe reuses a
        # shaded vertex only while it is in a small cache, and this keeps neighbours close
        # (~15 % less vertex work on the body).
        faces = np.concatenate([g[np.argsort(g.min(axis=1), kind="stable")] for g in (faces[closed], faces[~closed])])
        self.n_cull_idx = 3 * int(closed.sum())
        self.vao = gl.glGenVertexArrays(1)
        gl.glBindVertexArray(self.vao)
        self.ebo = gl.glGenBuffers(1)
        gl.glBindBuffer(gl.GL_ELEMENT_ARRAY_BUFFER, self.ebo)
        gl.glBufferData(gl.GL_ELEMENT_ARRAY_BUFFER, np.ascontiguousarray(faces).ravel(), gl.GL_STATIC_DRAW)
        usage = gl.GL_DYNAMIC_DRAW if dynamic else gl.GL_STATIC_DRAW
        self.vbo_pos = gl.glGenBuffers(1)
        self.vbo_nrm = gl.glGenBuffers(1)
        for loc, vbo, arr in ((0, self.vbo_pos, buf.positions), (1, self.vbo_nrm, buf.normals)):
            gl.glBindBuffer(gl.GL_ARRAY_BUFFER, vbo)
            gl.glBufferData(gl.GL_ARRAY_BUFFER, np.ascontiguousarray(arr, np.float32), usage)
            gl.glEnableVertexAttribArray(loc)
            gl.glVertexAttribPointer(loc, 3, gl.GL_FLOAT, gl.GL_FALSE, 0, None)
        self._static = []
        uv = np.full((self.n, 2), -1.0, np.float32) if buf.uv is None else np.ascontiguousarray(buf.uv, np.float32)
        self.textured = bool(np.any(uv[:, 0] >= 0))  # drawn with the texturing program
        for loc, arr, comps, ityp in (
            (2, np.ascontiguousarray(buf.albedo, np.float32), 3, None),
            (3, np.ascontiguousarray(buf.ids, np.int32), 1, gl.GL_INT),
            (4, np.ascontiguousarray(buf.retro, np.float32), 1, None),
            (5, uv, 2, None),
        ):
            vbo = gl.glGenBuffers(1)
            self._static.append(vbo)
            gl.glBindBuffer(gl.GL_ARRAY_BUFFER, vbo)
            gl.glBufferData(gl.GL_ARRAY_BUFFER, arr, gl.GL_STATIC_DRAW)
            gl.glEnableVertexAttribArray(loc)
            if ityp is None:
                gl.glVertexAttribPointer(loc, comps, gl.GL_FLOAT, gl.GL_FALSE, 0, None)
            else:
                gl.glVertexAttribIPointer(loc, comps, ityp, 0, None)
        gl.glBindVertexArray(0)

    def free(self) -> None:
        """Delete the vertex array and every buffer of this mesh (the context must be current)."""
        gl.glDeleteVertexArrays(1, [self.vao])
        gl.glDeleteBuffers(3 + len(self._static), [self.ebo, self.vbo_pos, self.vbo_nrm, *self._static])
        self._static = []

    def update(self, positions: np.ndarray, normals: np.ndarray) -> None:
        if len(positions) != self.n:
            raise ValueError(f"dynamic geometry has {self.n} vertices, got {len(positions)}")
        gl.glBindBuffer(gl.GL_ARRAY_BUFFER, self.vbo_pos)
        gl.glBufferSubData(gl.GL_ARRAY_BUFFER, 0, np.ascontiguousarray(positions, np.float32))
        gl.glBindBuffer(gl.GL_ARRAY_BUFFER, self.vbo_nrm)
        gl.glBufferSubData(gl.GL_ARRAY_BUFFER, 0, np.ascontiguousarray(normals, np.float32))

    def draw(self) -> None:
        gl.glBindVertexArray(self.vao)
        if self.n_cull_idx:
            # Counter-clockwise seen from outside in the world becomes clockwise in GL
            # window coordinates: the projection keeps OpenCV's y-down rows (see projection_from_K).
            gl.glEnable(gl.GL_CULL_FACE)
            gl.glFrontFace(gl.GL_CW)
            gl.glCullFace(gl.GL_BACK)
            gl.glDrawElements(gl.GL_TRIANGLES, self.n_cull_idx, gl.GL_UNSIGNED_INT, None)
            gl.glDisable(gl.GL_CULL_FACE)
        if self.n_idx > self.n_cull_idx:
            gl.glDrawElements(gl.GL_TRIANGLES, self.n_idx - self.n_cull_idx, gl.GL_UNSIGNED_INT,
                              ctypes.c_void_p(4 * self.n_cull_idx))
