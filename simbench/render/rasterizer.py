"""One-pass OpenGL rasteriser: linear radiance, integer ids and camera depth together.

Why hand-written rather than pyrender's renderer (whose EGL/OSMesa platform we do
reuse, see :mod:`simbench.render.gl_context`): for every frame of every camera the
bench needs three images of the same view — linear float radiance (so that the
sensor model adds shot noise, white balance and gamma itself), an exact integer id
map (marker id, shirt patch id, background) and metric depth. pyrender draws these in
separate passes, hard-codes 4x MSAA, reads back 8-bit colour only, and sets every
uniform by name lookup per primitive per frame; measured here that caps it at about
12-17 fps for one 640x480 camera. This class keeps all scene geometry in two vertex
buffers (static set, and the moving body re-posed on the CPU with numpy, a few
thousand vertices), draws them in two calls into three colour attachments (multiple
render targets), draws and reads back only what was asked for, and culls the back
faces of closed meshes (see :func:`closed_outward_faces`).

Conventions
-----------
* Cameras follow OpenCV: x right, y down, z forward; pixel centres at integers.
  ``render`` takes the world-to-camera ``R, t`` and a pinhole ``K`` (no distortion:
  distortion is applied afterwards by remapping, see :mod:`simbench.render.camera`).
* Row 0 of every returned image is the top row (v = 0), as OpenCV.
* Radiance is linear, in arbitrary radiometric units (irradiance x albedo / pi);
  the sensor model scales it to electrons.
"""

from __future__ import annotations

import ctypes
from dataclasses import dataclass, field

import numba
import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from simbench.render.gl_context import GLContext

from OpenGL import GL as gl  # noqa: E402  (after the platform is configured)
from OpenGL.raw.GL.VERSION.GL_1_0 import glReadPixels as _raw_read_pixels  # noqa: E402  (a plain pointer)

MAX_LIGHTS = 8
_SCRATCH_UNIT = 7  # texture unit for creating textures without disturbing unit 0 (the board texture)
_ALL_COLOR = (gl.GL_COLOR_ATTACHMENT0, gl.GL_COLOR_ATTACHMENT1, gl.GL_COLOR_ATTACHMENT2)
_ZEROS_F = np.zeros(4, np.float32)
_ZEROS_I = np.zeros(4, np.int32)

# Lighting is evaluated per vertex (Gouraud): on llvmpipe the fragment stage dominates,
# and per-fragment lighting of a 640x480 view costs ~4x the whole rest of the frame.
# Meshes are tessellated finely enough (floor and walls are grids) that the
# interpolation error is far below the sensor noise.
_VERT = """
#version 330 core
layout(location = 0) in vec3 a_pos;
layout(location = 1) in vec3 a_nrm;
layout(location = 2) in vec3 a_alb;
layout(location = 3) in int a_id;
layout(location = 4) in float a_retro;
layout(location = 5) in vec2 a_uv;      // texture coordinates; negative = untextured
uniform mat4 u_world_to_cam;   // OpenCV camera frame
uniform mat4 u_proj;           // OpenCV camera frame -> clip
uniform int u_n_lights;
uniform int u_light_kind[%(n)d];      // 0 directional, 1 point
uniform vec3 u_light_vec[%(n)d];      // direction the light travels (dir) or position (point)
uniform vec3 u_light_rgb[%(n)d];      // irradiance at normal incidence (dir) or at 1 m (point)
uniform vec3 u_ambient;
uniform vec3 u_cam_pos;
uniform vec3 u_ring_rgb;              // coaxial ring light irradiance at 1 m (IR mode)
uniform float u_specular;
out vec3 v_rad;
out vec3 v_irr;
out vec2 v_uv;
flat out int v_id;
out float v_z;
void main() {
    vec4 pc = u_world_to_cam * vec4(a_pos, 1.0);
    vec3 n = normalize(a_nrm);
    vec3 dc = u_cam_pos - a_pos;
    float dc2 = max(dot(dc, dc), 1e-4);
    vec3 vdir = dc * inversesqrt(dc2);
    if (dot(n, vdir) < 0.0) n = -n;   // two-sided surfaces (planes, props)
    vec3 e = u_ambient;
    vec3 spec = vec3(0.0);
    for (int i = 0; i < u_n_lights; ++i) {
        vec3 l;
        vec3 irr = u_light_rgb[i];
        if (u_light_kind[i] == 0) {
            l = -normalize(u_light_vec[i]);
        } else {
            vec3 d = u_light_vec[i] - a_pos;
            float r2 = max(dot(d, d), 1e-4);
            l = d * inversesqrt(r2);
            irr /= r2;
        }
        float ndl = max(dot(n, l), 0.0);
        e += irr * ndl;
        vec3 h = normalize(l + vdir);
        float s = max(dot(n, h), 0.0);
        s *= s; s *= s; s *= s; s *= s; s *= s;  // s^32 by squaring: pow() is exp2(log2) on llvmpipe, ~1/3 of the vertex stage
        spec += irr * (ndl > 0.0 ? s : 0.0);
    }
    v_irr = e * 0.318309886;
    v_uv = a_uv;
    v_rad = (a_uv.x < 0.0 ? a_alb * v_irr : vec3(0.0)) + u_specular * spec * 0.05;
    // Retro-reflective material returns light towards its source: with a ring light
    // around the lens the whole sphere appears uniformly bright (glass-bead tape).
    v_rad += a_retro * u_ring_rgb / dc2;
    v_id = a_id;
    v_z = pc.z;
    gl_Position = u_proj * pc;
}
""" % {"n": MAX_LIGHTS}

# TEXTURED is 1 for meshes with printed (textured) faces, else 0: without the texture
# branch the compiler drops two varyings, and the moving body's fragments cost ~20 %
# less on llvmpipe (same output: untextured vertices never take the branch).
_FRAG = """
#version 330 core
#define TEXTURED %(textured)d
in vec3 v_rad;
in vec3 v_irr;
in vec2 v_uv;
flat in int v_id;
in float v_z;
uniform sampler2D u_tex;
layout(location = 0) out vec4 o_rad;
layout(location = 1) out int o_id;
layout(location = 2) out float o_depth;
void main() {
    vec3 rad = v_rad;
#if TEXTURED
    if (v_uv.x >= 0.0) rad += texture(u_tex, v_uv).rgb * v_irr;  // printed boards
#endif
    o_rad = vec4(rad, 1.0);
    o_id = v_id;
    o_depth = v_z;
}
"""


@dataclass
class Light:
    """A light in world coordinates.

    kind : ``"directional"`` or ``"point"``
    vector : (3,) travel direction (directional) or position in metres (point)
    rgb : (3,) linear irradiance at normal incidence (directional) or at 1 m (point)
    """

    kind: str
    vector: np.ndarray
    rgb: np.ndarray


@dataclass
class GeometryBuffers:
    """Indexed vertex arrays for one draw call.

    positions, normals : (V, 3) float32, world frame (static) or updated per frame
    albedo : (V, 3) float32 linear RGB in 0..1
    ids : (V,) int32 (0 is background; see :mod:`simbench.render.ids`)
    retro : (V,) float32 retro-reflective gain (0 for ordinary surfaces)
    faces : (T, 3) uint32 vertex indices
    uv : (V, 2) float32 texture coordinates in 0..1 for textured vertices, -1 elsewhere
        (None: untextured); the texture is set with :meth:`Rasterizer.set_texture`
    """

    positions: np.ndarray
    normals: np.ndarray
    albedo: np.ndarray
    ids: np.ndarray
    retro: np.ndarray
    faces: np.ndarray
    uv: np.ndarray | None = None


Rect = tuple[int, int, int, int]  # x0, y0, x1, y1: pixel columns x0..x1-1, rows y0..y1-1


def _union(a: Rect | None, b: Rect) -> Rect:
    return b if a is None else (min(a[0], b[0]), min(a[1], b[1]), max(a[2], b[2]), max(a[3], b[3]))


@dataclass
class _View:
    """The cached static set of one view and light state, and this view's working target.

    static : the static set alone, drawn once
    work : the static set with the moving geometry of the last render drawn over it
    dirty : per attachment (radiance, ids, camera depth, depth buffer), the rectangle
        where ``work`` may differ from ``static`` (None: nowhere)
    host : per output name, the view's last read-back of it (see ``Rasterizer._read_view``)
    host_dirty : per output name, the rectangle where ``host`` may differ from the static set
    """

    static: "_Target"
    work: "_Target"
    dirty: list
    host: dict = field(default_factory=dict)
    host_dirty: dict = field(default_factory=dict)


@dataclass
class _Target:
    """A render target: framebuffer, radiance texture, id / camera-z / depth renderbuffers."""

    fbo: int
    radiance: int
    ids: int
    zcam: int
    depth: int
    width: int
    height: int


@numba.njit(cache=True, nogil=True)
def _ndc_bounds(pos, M):
    """Bounds of points ``pos (N, 3)`` float32 projected by ``M (4, 4)`` float32: minimum
    and maximum of normalised x and y, and the minimum clip w (x and y bounds are
    meaningful only when it is positive); one pass where numpy took ~0.35 ms for the body."""
    xmin = ymin = wmin = np.inf
    xmax = ymax = -np.inf
    for i in range(pos.shape[0]):
        px, py, pz = pos[i, 0], pos[i, 1], pos[i, 2]
        w = M[3, 0] * px + M[3, 1] * py + M[3, 2] * pz + M[3, 3]
        x = (M[0, 0] * px + M[0, 1] * py + M[0, 2] * pz + M[0, 3]) / w
        y = (M[1, 0] * px + M[1, 1] * py + M[1, 2] * pz + M[1, 3]) / w
        wmin = min(wmin, w)
        xmin = min(xmin, x)
        xmax = max(xmax, x)
        ymin = min(ymin, y)
        ymax = max(ymax, y)
    return xmin, xmax, ymin, ymax, wmin


def _compile(src: str, kind) -> int:
    sh = gl.glCreateShader(kind)
    gl.glShaderSource(sh, src)
    gl.glCompileShader(sh)
    if not gl.glGetShaderiv(sh, gl.GL_COMPILE_STATUS):
        raise RuntimeError(gl.glGetShaderInfoLog(sh).decode())
    return sh


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


class _Mesh:
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


def projection_from_K(K: np.ndarray, width: int, height: int, znear: float, zfar: float) -> np.ndarray:
    """OpenCV camera frame to GL clip space, such that window pixel row v is OpenCV's v.

    ``u_gl = fx x/z + cx + 0.5`` (GL pixel centres are at +0.5); y is *not* flipped, so
    rows come out top-first and triangles' winding is mirrored (handled with glFrontFace).
    """
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    P = np.zeros((4, 4))
    P[0, 0] = 2 * fx / width
    P[0, 1] = 2 * K[0, 1] / width
    P[0, 2] = 2 * (cx + 0.5) / width - 1
    P[1, 1] = 2 * fy / height
    P[1, 2] = 2 * (cy + 0.5) / height - 1
    P[2, 2] = (zfar + znear) / (zfar - znear)
    P[2, 3] = -2 * zfar * znear / (zfar - znear)
    P[3, 2] = 1.0
    return P


class Rasterizer:
    """Renders static and dynamic triangle geometry into (radiance, ids, depth).

    Holds GL objects (programs, meshes, a texture, framebuffers) and, unless one is given,
    its own off-screen context: :meth:`free` releases them all, and ``with Rasterizer() as r:``
    does so on the way out.
    """

    def __init__(self, context: GLContext | None = None) -> None:
        self._owns_context = context is None
        self.context = context or GLContext(64, 64)
        self.context.make_current()
        self._texture: int | None = None
        # Programs for textured and untextured meshes (see _FRAG), with their uniform locations.
        self._progs: dict[bool, int] = {}
        self._locs: dict[bool, dict[str, int]] = {}
        for textured in (True, False):
            prog = gl.glCreateProgram()
            shaders = [_compile(src, kind) for src, kind in ((_VERT, gl.GL_VERTEX_SHADER),
                                                             (_FRAG % {"textured": int(textured)}, gl.GL_FRAGMENT_SHADER))]
            for shader in shaders:
                gl.glAttachShader(prog, shader)
            gl.glLinkProgram(prog)
            if not gl.glGetProgramiv(prog, gl.GL_LINK_STATUS):
                raise RuntimeError(gl.glGetProgramInfoLog(prog).decode())
            for shader in shaders:
                gl.glDeleteShader(shader)  # flagged: freed with the program
            self._progs[textured] = prog
            self._locs[textured] = {
                name: gl.glGetUniformLocation(prog, name)
                for name in ("u_world_to_cam", "u_proj", "u_n_lights", "u_light_kind", "u_light_vec",
                             "u_light_rgb", "u_ambient", "u_cam_pos", "u_ring_rgb", "u_specular")
            }
        self._fbos: dict[tuple[int, int], _Target] = {}
        self._static: _Mesh | None = None
        self._dynamic: _Mesh | None = None
        self._static_cache: dict[tuple, _View] = {}
        self._dynamic_positions: np.ndarray | None = None

    def _framebuffer(self, width: int, height: int) -> "_Target":
        """The working framebuffer of this size (made once)."""
        key = (width, height)
        if key not in self._fbos:
            self._fbos[key] = self._new_framebuffer(width, height)
        return self._fbos[key]

    def _new_framebuffer(self, width: int, height: int) -> "_Target":
        """Framebuffer with radiance (a texture, so that the GL sensor pass can sample it),
        id, camera-depth and depth-buffer attachments."""
        fbo = gl.glGenFramebuffers(1)
        gl.glBindFramebuffer(gl.GL_FRAMEBUFFER, fbo)
        tex = gl.glGenTextures(1)
        # A spare texture unit: unit 0 holds the board texture the draw samples.
        gl.glActiveTexture(gl.GL_TEXTURE0 + _SCRATCH_UNIT)
        gl.glBindTexture(gl.GL_TEXTURE_2D, tex)
        gl.glTexStorage2D(gl.GL_TEXTURE_2D, 1, gl.GL_RGBA32F, width, height)
        gl.glTexParameteri(gl.GL_TEXTURE_2D, gl.GL_TEXTURE_MIN_FILTER, gl.GL_NEAREST)
        gl.glTexParameteri(gl.GL_TEXTURE_2D, gl.GL_TEXTURE_MAG_FILTER, gl.GL_NEAREST)
        gl.glBindTexture(gl.GL_TEXTURE_2D, 0)
        gl.glActiveTexture(gl.GL_TEXTURE0)
        gl.glFramebufferTexture2D(gl.GL_FRAMEBUFFER, gl.GL_COLOR_ATTACHMENT0, gl.GL_TEXTURE_2D, tex, 0)
        rbs = [int(r) for r in gl.glGenRenderbuffers(3)]
        formats = (gl.GL_R32I, gl.GL_R32F, gl.GL_DEPTH_COMPONENT24)
        attach = (gl.GL_COLOR_ATTACHMENT1, gl.GL_COLOR_ATTACHMENT2, gl.GL_DEPTH_ATTACHMENT)
        for rb, fmt, att in zip(rbs, formats, attach):
            gl.glBindRenderbuffer(gl.GL_RENDERBUFFER, rb)
            gl.glRenderbufferStorage(gl.GL_RENDERBUFFER, fmt, width, height)
            gl.glFramebufferRenderbuffer(gl.GL_FRAMEBUFFER, att, gl.GL_RENDERBUFFER, rb)
        status = gl.glCheckFramebufferStatus(gl.GL_FRAMEBUFFER)
        if status != gl.GL_FRAMEBUFFER_COMPLETE:
            raise RuntimeError(f"incomplete framebuffer (status {status:#x})")
        gl.glDrawBuffers(3, _ALL_COLOR)
        return _Target(int(fbo), int(tex), rbs[0], rbs[1], rbs[2], width, height)

    def _delete_target(self, target: "_Target") -> None:
        gl.glDeleteFramebuffers(1, [target.fbo])
        gl.glDeleteTextures(1, [target.radiance])
        gl.glDeleteRenderbuffers(3, [target.ids, target.zcam, target.depth])

    def free(self) -> None:
        """Release every GL object (and the context, if this rasteriser made it); idempotent."""
        if self.context is None:
            return
        self.context.make_current()
        for mesh in (self._static, self._dynamic):
            if mesh is not None:
                mesh.free()
        self._static = self._dynamic = None
        self._clear_static_cache()
        for target in self._fbos.values():
            self._delete_target(target)
        self._fbos.clear()
        if self._texture is not None:
            gl.glDeleteTextures(1, [self._texture])
            self._texture = None
        gl.glUseProgram(0)  # a program in use is only flagged for deletion
        for prog in self._progs.values():
            gl.glDeleteProgram(prog)
        self._progs.clear()
        if self._owns_context:
            self.context.close()
        self.context = None

    def __enter__(self) -> "Rasterizer":
        return self

    def __exit__(self, *exc) -> None:
        self.free()

    def _clear_static_cache(self) -> None:
        for view in self._static_cache.values():
            self._delete_target(view.static)
            self._delete_target(view.work)
        self._static_cache.clear()

    # ---------------------------------------------------------------- geometry
    def set_static(self, buf: GeometryBuffers) -> None:
        """The static set (replacing, and freeing, the previous one)."""
        self.context.make_current()
        if self._static is not None:
            self._static.free()
        self._static = _Mesh(buf, dynamic=False)
        self._clear_static_cache()

    def set_dynamic(self, buf: GeometryBuffers) -> None:
        """Topology and per-vertex attributes of the moving geometry (replacing, and freeing, the previous one)."""
        self.context.make_current()
        if self._dynamic is not None:
            self._dynamic.free()
        self._dynamic = _Mesh(buf, dynamic=True)
        self._dynamic_positions = np.array(buf.positions, np.float32)

    def set_texture(self, image: np.ndarray) -> None:
        """The one texture (linear albedo 0..1, ``(H, W)`` or ``(H, W, 3)``), bilinear with mipmaps."""
        self.context.make_current()
        img = np.asarray(image, np.float32)
        if img.ndim == 2:
            img = np.repeat(img[..., None], 3, axis=2)
        if self._texture is not None:
            gl.glDeleteTextures(1, [self._texture])
        tex = gl.glGenTextures(1)
        gl.glActiveTexture(gl.GL_TEXTURE0)
        gl.glBindTexture(gl.GL_TEXTURE_2D, tex)
        gl.glTexImage2D(gl.GL_TEXTURE_2D, 0, gl.GL_RGB32F, img.shape[1], img.shape[0], 0, gl.GL_RGB, gl.GL_FLOAT,
                        np.ascontiguousarray(img))
        gl.glGenerateMipmap(gl.GL_TEXTURE_2D)
        gl.glTexParameteri(gl.GL_TEXTURE_2D, gl.GL_TEXTURE_MIN_FILTER, gl.GL_LINEAR_MIPMAP_LINEAR)
        gl.glTexParameteri(gl.GL_TEXTURE_2D, gl.GL_TEXTURE_MAG_FILTER, gl.GL_LINEAR)
        gl.glTexParameteri(gl.GL_TEXTURE_2D, gl.GL_TEXTURE_WRAP_S, gl.GL_CLAMP_TO_EDGE)
        gl.glTexParameteri(gl.GL_TEXTURE_2D, gl.GL_TEXTURE_WRAP_T, gl.GL_CLAMP_TO_EDGE)
        prog = self._progs[True]
        gl.glUseProgram(prog)
        gl.glUniform1i(gl.glGetUniformLocation(prog, "u_tex"), 0)
        self._texture = tex

    def update_dynamic(self, positions: np.ndarray, normals: np.ndarray) -> None:
        """New world positions/normals ``(V, 3)`` of the moving geometry."""
        self.context.make_current()
        if self._dynamic is None:
            raise RuntimeError("call set_dynamic before update_dynamic")
        self._dynamic.update(positions, normals)
        # Kept to bound the image region the moving geometry covers (see _dynamic_rect).
        self._dynamic_positions = np.array(positions, np.float32)

    # ---------------------------------------------------------------- render
    def _draw(self, fbo: int, width: int, height: int, meshes, clear: bool, uniforms: tuple,
              attachments: tuple[bool, bool, bool] = (True, True, True)) -> None:
        """Draw ``meshes`` into the colour attachments flagged in ``attachments``
        (radiance, ids, camera depth); the others are left as they are."""
        gl.glBindFramebuffer(gl.GL_FRAMEBUFFER, fbo)
        # Only the attachments that will be read: llvmpipe then skips the others' writes.
        gl.glDrawBuffers(3, [a if on else gl.GL_NONE for a, on in zip(_ALL_COLOR, attachments)])
        gl.glViewport(0, 0, width, height)
        gl.glEnable(gl.GL_DEPTH_TEST)
        gl.glDepthFunc(gl.GL_LESS)
        gl.glDisable(gl.GL_BLEND)
        gl.glDisable(gl.GL_MULTISAMPLE)
        gl.glDisable(gl.GL_CULL_FACE)
        if clear:
            if attachments[0]:
                gl.glClearBufferfv(gl.GL_COLOR, 0, _ZEROS_F)
            if attachments[1]:
                gl.glClearBufferiv(gl.GL_COLOR, 1, _ZEROS_I)
            if attachments[2]:
                gl.glClearBufferfv(gl.GL_COLOR, 2, _ZEROS_F)
            gl.glClear(gl.GL_DEPTH_BUFFER_BIT)
        W2C, P, kinds, vecs, rgbs, n, ambient, cam_pos, ring, specular = uniforms
        current = None
        for mesh in meshes:  # in the given order (it decides exact depth ties)
            if mesh is None:
                continue
            textured = mesh.textured
            if textured == current:
                mesh.draw()
                continue
            current = textured
            gl.glUseProgram(self._progs[textured])
            loc = self._locs[textured]
            gl.glUniformMatrix4fv(loc["u_world_to_cam"], 1, gl.GL_TRUE, W2C)
            gl.glUniformMatrix4fv(loc["u_proj"], 1, gl.GL_TRUE, P)
            gl.glUniform1i(loc["u_n_lights"], n)
            gl.glUniform1iv(loc["u_light_kind"], MAX_LIGHTS, kinds)
            gl.glUniform3fv(loc["u_light_vec"], MAX_LIGHTS, vecs)
            gl.glUniform3fv(loc["u_light_rgb"], MAX_LIGHTS, rgbs)
            gl.glUniform3fv(loc["u_ambient"], 1, ambient)
            gl.glUniform3fv(loc["u_cam_pos"], 1, cam_pos)
            gl.glUniform3fv(loc["u_ring_rgb"], 1, ring)
            gl.glUniform1f(loc["u_specular"], specular)
            mesh.draw()

    def _restore(self, view: _View, attachments: tuple[bool, bool, bool]) -> None:
        """Copy the static set back over the dirty rectangles of the flagged colour
        attachments and of the depth buffer of the view's working target.

        Only where the last renders drew moving geometry: the body covers a small part of
        the image, and a whole-frame copy of radiance, ids and depth cost ~1 ms per frame
        here. ``glCopyImageSubData`` is a plain memory copy on llvmpipe; a blit per
        attachment draws a textured quad each and cost ~4x as much.
        """
        src, dst = view.static, view.work
        names = [(src.radiance, dst.radiance, gl.GL_TEXTURE_2D), (src.ids, dst.ids, gl.GL_RENDERBUFFER),
                 (src.zcam, dst.zcam, gl.GL_RENDERBUFFER), (src.depth, dst.depth, gl.GL_RENDERBUFFER)]
        for k, ((a, b, target), on) in enumerate(zip(names, attachments + (True,))):
            rect = view.dirty[k]
            if on and rect is not None:
                x0, y0, x1, y1 = rect
                gl.glCopyImageSubData(a, target, 0, x0, y0, 0, b, target, 0, x0, y0, 0, x1 - x0, y1 - y0, 1)
                view.dirty[k] = None

    @staticmethod
    def _read_view(view: _View, name: str, rect: Rect | None, fmt, typ, dtype, shape: tuple[int, ...]) -> np.ndarray:
        """Read-back of output ``name`` of a cached view from the bound read buffer: the
        view keeps its last read-back, and only the rectangle where that or the current
        render drew moving geometry is read again (outside it both hold the static set).

        Returns a read-only view of the view's array ``shape`` ``dtype``, valid until
        the next render of this view. A 640x480 float RGB read-back cost ~1 ms a frame
        here, the body's rectangle about a quarter of it.
        """
        host = view.host.get(name)
        if host is None:
            host = view.host[name] = np.empty(shape, dtype)
            region = (0, 0, shape[1], shape[0])
        else:
            old = view.host_dirty.get(name)
            region = old if rect is None else _union(old, rect)
        view.host_dirty[name] = rect
        if region is not None:
            x0, y0, x1, y1 = region
            width = shape[1]
            pixel_bytes = host.nbytes // (shape[0] * width)
            # Rows of the rectangle land in rows of the whole image (GL row y is image row y).
            gl.glPixelStorei(gl.GL_PACK_ROW_LENGTH, width)
            _raw_read_pixels(x0, y0, x1 - x0, y1 - y0, fmt, typ,
                             ctypes.c_void_p(host.ctypes.data + (y0 * width + x0) * pixel_bytes))
            gl.glPixelStorei(gl.GL_PACK_ROW_LENGTH, 0)
        out = host.view()
        out.flags.writeable = False  # the view's own array: a caller's change would outlive this frame
        return out

    def _dynamic_rect(self, P: np.ndarray, W2C: np.ndarray, width: int, height: int, znear: float) -> Rect | None:
        """Pixel rectangle that contains every fragment of the moving geometry (None: no
        geometry), from its vertices' projection with ``P @ W2C`` (4, 4).

        A triangle's pixels lie within its vertices' bounding box when all three are in
        front of the near plane; a vertex nearer than that (a triangle may then be clipped
        into any shape) makes it the whole image. Two pixels of margin cover pixel-centre
        conventions and rounding.
        """
        pos = self._dynamic_positions
        if pos is None or len(pos) == 0:
            return None
        xmin, xmax, ymin, ymax, wmin = _ndc_bounds(pos, (P @ W2C).astype(np.float32))
        if not wmin > znear:
            return (0, 0, width, height)
        # NDC -> window pixels (y is not flipped, see projection_from_K).
        x0 = int(np.floor((xmin + 1) * 0.5 * width)) - 2
        x1 = int(np.ceil((xmax + 1) * 0.5 * width)) + 2
        y0 = int(np.floor((ymin + 1) * 0.5 * height)) - 2
        y1 = int(np.ceil((ymax + 1) * 0.5 * height)) + 2
        x0, y0 = max(x0, 0), max(y0, 0)
        x1, y1 = min(x1, width), min(y1, height)
        if x1 <= x0 or y1 <= y0:
            return None
        return (x0, y0, x1, y1)

    def render(
        self,
        width: int,
        height: int,
        K: np.ndarray,
        R: np.ndarray,
        t: np.ndarray,
        lights: list[Light],
        ambient_rgb: np.ndarray,
        ring_rgb: np.ndarray | None = None,
        outputs: tuple[str, ...] = ("radiance", "ids", "depth"),
        znear: float = 0.05,
        zfar: float = 50.0,
        specular: float = 1.0,
        cache_static: bool = True,
        buffers: dict[str, np.ndarray] | None = None,
    ) -> dict[str, np.ndarray]:
        """Render one view.

        Returns a dict with the requested ``outputs``: ``radiance`` (H, W, 3) float32
        linear (``radiance_red`` gives only its first channel, (H, W, 1), as
        ``radiance``), ``ids`` (H, W) int32, ``depth`` (H, W) float32 camera z in metres
        (0 where nothing was drawn), ``radiance_rgba`` (H, W, 4) float32 with alpha 1,
        ``radiance_texture`` the GL name (int) of the
        ``RGBA32F`` radiance texture, drawn but not read back (for the GL sensor pass,
        :mod:`simbench.render.gl_sensor`; its content is valid until the next ``render``
        call). Only the requested images are drawn.

        ``buffers`` optionally maps output names (``radiance``, ``radiance_rgba``,
        ``radiance_red`` (H, W, 1), ``ids``, ``depth``) to C-contiguous
        arrays of the output's shape and dtype to read into (then returned, and
        overwritten by the next call that uses them). With the static cache (below)
        they are not used: the outputs are then read-only arrays of the view, valid
        until the next render of the same view and light state.

        With ``cache_static`` the static set (floor, walls, clutter) is drawn once per
        view and light state (up to 16 of them kept) and copied in before the moving
        geometry is drawn: it covers most pixels, and shading it is most of a frame's
        cost. Each view keeps a working copy, into which only the rectangles the moving
        geometry covered in earlier renders are copied back, and its last read-backs, of
        which only those rectangles are read again (``_read_view``). This is exact because the
        renderer casts no shadows (the body does not change how the set is lit).
        """
        if len(lights) > MAX_LIGHTS:
            raise ValueError(f"at most {MAX_LIGHTS} lights are supported, got {len(lights)}")
        self.context.make_current()
        W2C = np.eye(4)
        W2C[:3, :3] = R
        W2C[:3, 3] = t
        P = projection_from_K(np.asarray(K, float), width, height, znear, zfar)
        cam_pos = -np.asarray(R).T @ np.asarray(t)
        kinds = np.zeros(MAX_LIGHTS, np.int32)
        vecs = np.zeros((MAX_LIGHTS, 3), np.float32)
        rgbs = np.zeros((MAX_LIGHTS, 3), np.float32)
        for i, light in enumerate(lights):
            kinds[i] = 0 if light.kind == "directional" else 1
            vecs[i] = light.vector
            rgbs[i] = light.rgb
        uniforms = (W2C.astype(np.float32), P.astype(np.float32), kinds, vecs, rgbs, len(lights),
                    np.asarray(ambient_rgb, np.float32), cam_pos.astype(np.float32),
                    np.zeros(3, np.float32) if ring_rgb is None else np.asarray(ring_rgb, np.float32), float(specular))
        want_rad = any(o in outputs for o in ("radiance", "radiance_rgba", "radiance_red", "radiance_texture"))
        attachments = (want_rad, "ids" in outputs, "depth" in outputs)
        if cache_static and self._static is not None:
            key = (width, height, b"".join(np.asarray(u).tobytes() for u in uniforms))
            view = self._static_cache.get(key)
            if view is None:
                if len(self._static_cache) >= 16:  # bounded: drop the oldest view/light state
                    old = self._static_cache.pop(next(iter(self._static_cache)))
                    self._delete_target(old.static)
                    self._delete_target(old.work)
                static = self._new_framebuffer(width, height)
                self._draw(static.fbo, width, height, (self._static,), True, uniforms)
                # A working target of its own per view, so that only what the moving geometry
                # drew needs restoring: the first restore copies the whole image.
                view = _View(static, self._new_framebuffer(width, height), [(0, 0, width, height)] * 4)
                self._static_cache[key] = view
            self._restore(view, attachments)
            self._draw(view.work.fbo, width, height, (self._dynamic,), False, uniforms, attachments)
            rect = self._dynamic_rect(P, W2C, width, height, znear)
            if rect is not None:
                for k, on in enumerate(attachments + (True,)):
                    if on:
                        view.dirty[k] = _union(view.dirty[k], rect)
            target = view.work
        else:
            view = None
            target = self._framebuffer(width, height)
            self._draw(target.fbo, width, height, (self._static, self._dynamic), True, uniforms, attachments)
        out: dict = {}
        H, W = height, width
        if "radiance_texture" in outputs:
            out["radiance_texture"] = target.radiance

        def read(attachment, fmt, typ, dtype, shape, name):
            gl.glReadBuffer(attachment)
            if view is not None:
                return self._read_view(view, name, rect, fmt, typ, dtype, shape)
            # Into the caller's array when given: PyOpenGL's own fresh array costs page
            # faults on every call (~40 % of a float read-back here).
            dst = None if buffers is None else buffers.get(name)
            if dst is not None:
                if dst.shape != shape or dst.dtype != dtype or not dst.flags.c_contiguous:
                    raise ValueError(f"buffer {name!r} must be C-contiguous {shape} {np.dtype(dtype)}")
                gl.glReadPixels(0, 0, W, H, fmt, typ, dst)
                return dst
            return np.frombuffer(gl.glReadPixels(0, 0, W, H, fmt, typ), dtype).reshape(shape)

        if "radiance" in outputs:
            # Straight to RGB: measured here (Mesa llvmpipe, 640x480) it costs ~10 % more
            # than the RGBA read-back, where dropping alpha afterwards costs another ~100 %.
            out["radiance"] = read(gl.GL_COLOR_ATTACHMENT0, gl.GL_RGB, gl.GL_FLOAT, np.float32, (H, W, 3), "radiance")
        if "radiance_rgba" in outputs:
            out["radiance_rgba"] = read(gl.GL_COLOR_ATTACHMENT0, gl.GL_RGBA, gl.GL_FLOAT, np.float32, (H, W, 4),
                                        "radiance_rgba")
        if "radiance_red" in outputs:  # monochrome (IR) sensors: one channel is enough
            out["radiance"] = read(gl.GL_COLOR_ATTACHMENT0, gl.GL_RED, gl.GL_FLOAT, np.float32, (H, W, 1),
                                   "radiance_red")
        if "ids" in outputs:
            out["ids"] = read(gl.GL_COLOR_ATTACHMENT1, gl.GL_RED_INTEGER, gl.GL_INT, np.int32, (H, W), "ids")
        if "depth" in outputs:
            out["depth"] = read(gl.GL_COLOR_ATTACHMENT2, gl.GL_RED, gl.GL_FLOAT, np.float32, (H, W), "depth")
        return out
