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
faces of closed meshes (see :func:`simbench.render.gl_mesh.closed_outward_faces`). The GLSL
programs are in :mod:`simbench.render.shaders`.

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

from simbench.render.gl_context import GLContext
from simbench.render.gl_mesh import GeometryBuffers, Mesh, closed_outward_faces
from simbench.render.shaders import FRAGMENT_SHADER, MAX_LIGHTS, VERTEX_SHADER, compile_shader

from OpenGL import GL as gl  # noqa: E402  (after the platform is configured)
from OpenGL.raw.GL.VERSION.GL_1_0 import glReadPixels as _raw_read_pixels  # noqa: E402  (a plain pointer)

__all__ = ["GeometryBuffers", "Light", "MAX_LIGHTS", "Rasterizer", "closed_outward_faces", "projection_from_K"]

_SCRATCH_UNIT = 7  # texture unit for creating textures without disturbing unit 0 (the board texture)
_ALL_COLOR = (gl.GL_COLOR_ATTACHMENT0, gl.GL_COLOR_ATTACHMENT1, gl.GL_COLOR_ATTACHMENT2)
_ZEROS_F = np.zeros(4, np.float32)
_ZEROS_I = np.zeros(4, np.int32)


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
        # Programs for textured and untextured meshes (see shaders.FRAGMENT_SHADER), with their uniform locations.
        self._progs: dict[bool, int] = {}
        self._locs: dict[bool, dict[str, int]] = {}
        for textured in (True, False):
            prog = gl.glCreateProgram()
            sources = ((VERTEX_SHADER, gl.GL_VERTEX_SHADER),
                       (FRAGMENT_SHADER % {"textured": int(textured)}, gl.GL_FRAGMENT_SHADER))
            shaders = [compile_shader(src, kind) for src, kind in sources]
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
        self._static: Mesh | None = None
        self._dynamic: Mesh | None = None
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
        self._static = Mesh(buf, dynamic=False)
        self._clear_static_cache()

    def set_dynamic(self, buf: GeometryBuffers) -> None:
        """Topology and per-vertex attributes of the moving geometry (replacing, and freeing, the previous one)."""
        self.context.make_current()
        if self._dynamic is not None:
            self._dynamic.free()
        self._dynamic = Mesh(buf, dynamic=True)
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
        W2C, P, uniforms = _view_uniforms(width, height, K, R, t, lights, ambient_rgb, ring_rgb, znear, zfar, specular)
        want_rad = any(o in outputs for o in ("radiance", "radiance_rgba", "radiance_red", "radiance_texture"))
        attachments = (want_rad, "ids" in outputs, "depth" in outputs)
        view = rect = None
        if cache_static and self._static is not None:
            view = self._cached_view(width, height, uniforms)
            self._restore(view, attachments)
            self._draw(view.work.fbo, width, height, (self._dynamic,), False, uniforms, attachments)
            rect = self._dynamic_rect(P, W2C, width, height, znear)
            if rect is not None:
                for k, on in enumerate(attachments + (True,)):
                    if on:
                        view.dirty[k] = _union(view.dirty[k], rect)
            target = view.work
        else:
            target = self._framebuffer(width, height)
            self._draw(target.fbo, width, height, (self._static, self._dynamic), True, uniforms, attachments)
        out: dict = {}
        if "radiance_texture" in outputs:
            out["radiance_texture"] = target.radiance
        for name, key, attachment, fmt, typ, dtype, channels in _READ_BACKS:
            if name in outputs:
                shape = (height, width) if channels is None else (height, width, channels)
                out[key] = self._read(view, rect, buffers, attachment, fmt, typ, dtype, shape, name)
        return out

    def _cached_view(self, width: int, height: int, uniforms: tuple) -> _View:
        """The cached view of this size and these uniforms (view and light state); a new
        one, with the static set drawn into it, when there is none (up to 16 are kept)."""
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
        return view

    def _read(self, view: _View | None, rect: Rect | None, buffers: dict[str, np.ndarray] | None,
              attachment, fmt, typ, dtype, shape: tuple[int, ...], name: str) -> np.ndarray:
        """Read-back of output ``name`` from colour ``attachment`` of the target just drawn:
        through the cached ``view`` when there is one (``_read_view``), else the whole image,
        into the caller's array ``buffers[name]`` when given."""
        gl.glReadBuffer(attachment)
        if view is not None:
            return self._read_view(view, name, rect, fmt, typ, dtype, shape)
        # Into the caller's array when given: PyOpenGL's own fresh array costs page
        # faults on every call (~40 % of a float read-back here).
        dst = None if buffers is None else buffers.get(name)
        H, W = shape[:2]
        if dst is not None:
            if dst.shape != shape or dst.dtype != dtype or not dst.flags.c_contiguous:
                raise ValueError(f"buffer {name!r} must be C-contiguous {shape} {np.dtype(dtype)}")
            gl.glReadPixels(0, 0, W, H, fmt, typ, dst)
            return dst
        return np.frombuffer(gl.glReadPixels(0, 0, W, H, fmt, typ), dtype).reshape(shape)


# The outputs read back, in this order: output name, key of the returned dict, attachment,
# GL format and type, dtype, channels (None: an (H, W) image). Radiance goes straight to RGB:
# measured here (Mesa llvmpipe, 640x480) that costs ~10 % more than the RGBA read-back, where
# dropping alpha afterwards costs another ~100 %. Monochrome (IR) sensors ask for
# ``radiance_red``: one channel is enough.
_READ_BACKS = (
    ("radiance", "radiance", gl.GL_COLOR_ATTACHMENT0, gl.GL_RGB, gl.GL_FLOAT, np.float32, 3),
    ("radiance_rgba", "radiance_rgba", gl.GL_COLOR_ATTACHMENT0, gl.GL_RGBA, gl.GL_FLOAT, np.float32, 4),
    ("radiance_red", "radiance", gl.GL_COLOR_ATTACHMENT0, gl.GL_RED, gl.GL_FLOAT, np.float32, 1),
    ("ids", "ids", gl.GL_COLOR_ATTACHMENT1, gl.GL_RED_INTEGER, gl.GL_INT, np.int32, None),
    ("depth", "depth", gl.GL_COLOR_ATTACHMENT2, gl.GL_RED, gl.GL_FLOAT, np.float32, None),
)


def _view_uniforms(width: int, height: int, K: np.ndarray, R: np.ndarray, t: np.ndarray, lights: list[Light],
                   ambient_rgb: np.ndarray, ring_rgb: np.ndarray | None, znear: float, zfar: float,
                   specular: float) -> tuple[np.ndarray, np.ndarray, tuple]:
    """World-to-camera ``W2C`` (4, 4), projection ``P`` (4, 4) and the uniforms of one view
    and light state, in the order :meth:`Rasterizer._draw` takes them."""
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
    return W2C, P, uniforms
