"""The webcam's optics and sensor as OpenGL passes over the rasteriser's radiance texture.

Same model and order of operations as the numpy reference in
:mod:`simbench.render.sensor` (which stays the reference implementation), run on the
GL side so that only the final 8-bit frame is read back:

1. shutter: sub-frames are added into a float accumulation texture (additive
   blending) and divided by their count in the sensor pass;
2. supersampling: box filter over ``ss x ss`` canvas pixels (what ``cv2.resize``
   with ``INTER_AREA`` does at an integer factor);
3. distortion: each output pixel samples the 1x canvas bilinearly at its
   ``map_xy`` position, zero outside (``cv2.remap``, ``BORDER_CONSTANT``; here with
   exact float weights where OpenCV rounds them to 1/32 px);
4. optics blur: separable Gaussian, the kernel of
   :func:`simbench.render.sensor.gaussian_half_kernel`, ``BORDER_REFLECT_101``,
   horizontal pass then vertical pass (fused into the sensor pass);
5. sensor: electrons, shot noise (Gaussian approximation of Poisson, variance =
   electrons) + read noise, full-well clip, gain x white balance, the 14-bit gamma
   table's index and curve (computed, not looked up), 8-bit output; one channel in
   ``ir`` mode.

Why it is not the renderer's default (``FrameRenderer(sensor_backend="gl")`` opts in):
the idea was to run the sensor's arithmetic in one SIMD fragment pass and read back
8-bit frames instead of ``RGBA32F`` (4.9 MB per 640x480 frame). Measured on one
llvmpipe core (LP_NUM_THREADS=1), a full-screen 640x480 pass costs ~4 ms before
any arithmetic (fetch, per-4x4-stamp overhead, store), each transcendental per
channel ~0.7 ms, each extra texture tap 1-3 ms: blur + sensor passes took about
twice as long as :meth:`simbench.render.sensor.Sensor.frame` plus the float
read-back, measured side by side. With a real GPU or a multi-threaded llvmpipe the balance differs;
the passes are kept, tested against the reference, for that case.

Noise comes from a counter-based hash (``pcg4d``, Jarzynski & Olano, "Hash
Functions for GPU Rendering", JCGT 2020) of (pixel x, pixel y, two 32-bit seeds);
the seeds are drawn from the frame's ``numpy.random.Generator``, so frames depend
only on the scenario seed and the frame index, as with the numpy sensor. Normal
deviates come from the Box-Muller transform of 24-bit uniforms.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from simbench.render.rasterizer import Rasterizer
from simbench.render.shaders import compile_shader
from simbench.render.sensor import _LUT_BITS, Sensor, WhiteBalance, gaussian_half_kernel

from OpenGL import GL as gl  # noqa: E402  (after the platform is configured)

MAX_BLUR_RADIUS = 24  # taps each side; OpenCV's kernel for sigma = 5 px (the config maximum) has 20
_UNIT_SRC = 1  # texture units: 0 is the rasteriser's board texture, left alone
_UNIT_MAP = 2
_REDUCE_BLOCK = 8  # px: block size of the auto-white-balance mean reduction

_VERT = """
#version 330 core
// One triangle covering the viewport; no vertex buffers.
void main() {
    vec2 p = vec2(float((gl_VertexID << 1) & 2), float(gl_VertexID & 2));
    gl_Position = vec4(p * 2.0 - 1.0, 0.0, 1.0);
}
"""

_COPY = """
#version 330 core
uniform sampler2D u_src;
out vec4 o;
void main() { o = texelFetch(u_src, ivec2(gl_FragCoord.xy), 0); }
"""

_BOX = """
#version 330 core
uniform sampler2D u_src;
uniform int u_ss;
out vec4 o;
void main() {
    ivec2 p = ivec2(gl_FragCoord.xy) * u_ss;
    vec4 s = vec4(0.0);
    for (int j = 0; j < u_ss; ++j)
        for (int i = 0; i < u_ss; ++i)
            s += texelFetch(u_src, p + ivec2(i, j), 0);
    o = s / float(u_ss * u_ss);
}
"""

_REMAP = """
#version 330 core
uniform sampler2D u_src;
uniform sampler2D u_map;   // RG32F: position on the source of each output pixel
out vec4 o;
vec4 tap(ivec2 q, ivec2 size) {
    bool inside = all(greaterThanEqual(q, ivec2(0))) && all(lessThan(q, size));
    return inside ? texelFetch(u_src, q, 0) : vec4(0.0);
}
void main() {
    ivec2 size = textureSize(u_src, 0);
    vec2 m = texelFetch(u_map, ivec2(gl_FragCoord.xy), 0).xy;
    vec2 f0 = floor(m);
    vec2 f = m - f0;
    ivec2 q = ivec2(f0);
    o = (tap(q, size) * (1.0 - f.x) + tap(q + ivec2(1, 0), size) * f.x) * (1.0 - f.y)
      + (tap(q + ivec2(0, 1), size) * (1.0 - f.x) + tap(q + ivec2(1, 1), size) * f.x) * f.y;
}
"""

_REFLECT = """
// OpenCV's BORDER_REFLECT_101 (... 2 1 | 0 1 2 ... n-1 | n-2 ...), branch-free; exact
// for -n < i < 2n - 1 (clamped beyond: only images narrower than the blur radius).
int reflect101(int i, int n) {
    return clamp((n - 1) - abs((n - 1) - abs(i)), 0, n - 1);
}
"""

# Passes are compiled per variant (blur radius, noise, colour) with the choices as
# constants: llvmpipe runs both sides of a branch on a uniform and does not unroll
# loops with a uniform bound, which cost up to 2x here.
_BLUR_H = """
#version 330 core
#define R %(r)d
uniform sampler2D u_src;
uniform float u_w[R + 1];
out vec4 o;
%(reflect)s
void main() {
    ivec2 p = ivec2(gl_FragCoord.xy);
    int n = textureSize(u_src, 0).x;
    vec4 s = u_w[0] * texelFetch(u_src, p, 0);
    for (int k = 1; k <= R; ++k)
        s += u_w[k] * (texelFetch(u_src, ivec2(reflect101(p.x - k, n), p.y), 0)
                       + texelFetch(u_src, ivec2(reflect101(p.x + k, n), p.y), 0));
    o = s;
}
"""

_REDUCE = """
#version 330 core
// Sum of full-well-clipped electrons over a block, count in alpha (auto white balance).
uniform sampler2D u_src;
uniform float u_scale;
uniform float u_full_well;
out vec4 o;
void main() {
    ivec2 size = textureSize(u_src, 0);
    ivec2 p0 = ivec2(gl_FragCoord.xy) * %(B)d;
    vec3 s = vec3(0.0);
    float n = 0.0;
    for (int j = 0; j < %(B)d; ++j)
        for (int i = 0; i < %(B)d; ++i) {
            ivec2 q = p0 + ivec2(i, j);
            if (q.x < size.x && q.y < size.y) {
                s += min(texelFetch(u_src, q, 0).rgb * u_scale, vec3(u_full_well));
                n += 1.0;
            }
        }
    o = vec4(s, n);
}
""" % {"B": _REDUCE_BLOCK}

_SENSOR = """
#version 330 core
#define R %(r)d              // vertical optics blur radius (0: none)
#define NOISE %(noise)d
#define SHOT %(shot)d
#define SRGB %(srgb)d        // sRGB OETF, else linear
#define MONO %(mono)d        // one channel (IR)
#if MONO
#define VEC float
#define CH(v) (v).r
#define LE(a, b) ((a) <= (b))
#else
#define VEC vec3
#define CH(v) (v).rgb
#define LE(a, b) lessThanEqual(a, b)
#endif
uniform sampler2D u_src;      // linear radiance (sum of the shutter's sub-frames)
uniform float u_w[R + 1];
uniform float u_scale;        // electrons per radiance unit
uniform float u_inv_n;        // 1 / number of sub-frames
uniform float u_read_var;     // read noise variance, e-^2
uniform float u_full_well;
uniform vec3 u_k;             // gamma-table index per electron (gain x white balance)
uniform float u_top;          // last index of the 14-bit gamma table
uniform uvec2 u_seed;
out vec4 o;
%(reflect)s
uvec4 pcg4d(uvec4 v) {
    v = v * 1664525u + 1013904223u;
    v.x += v.y * v.w; v.y += v.z * v.x; v.z += v.x * v.y; v.w += v.y * v.z;
    v ^= v >> 16u;
    v.x += v.y * v.w; v.y += v.z * v.x; v.z += v.x * v.y; v.w += v.y * v.z;
    return v;
}
void main() {
    ivec2 p = ivec2(gl_FragCoord.xy);
    int n = textureSize(u_src, 0).y;
    vec4 s = u_w[0] * texelFetch(u_src, p, 0);
    for (int k = 1; k <= R; ++k)
        s += u_w[k] * (texelFetch(u_src, ivec2(p.x, reflect101(p.y - k, n)), 0)
                       + texelFetch(u_src, ivec2(p.x, reflect101(p.y + k, n)), 0));
    VEC e = (CH(s) * u_inv_n) * u_scale;
#if NOISE
    uvec4 h = pcg4d(uvec4(uint(p.x), uint(p.y), u_seed.x, u_seed.y));
    vec4 u = (vec4(h >> 8u) + 0.5) * (1.0 / 16777216.0);   // in (0, 1)
    float r1 = sqrt(-2.0 * log(u.x));
#if MONO
    float z = r1 * cos(6.28318531 * u.y);
#else
    float r2 = sqrt(-2.0 * log(u.z));
    vec3 z = vec3(r1 * cos(6.28318531 * u.y), r1 * sin(6.28318531 * u.y), r2 * cos(6.28318531 * u.w));
#endif
#if SHOT
    e += z * sqrt(max(e + u_read_var, 0.0));
#else
    e += z * sqrt(u_read_var);
#endif
#endif
    e = clamp(e, 0.0, u_full_well);
    // The numpy sensor's 14-bit gamma table, computed instead of looked up (gathers
    // from a table cost llvmpipe more than the arithmetic). Index truncated, as numpy's astype.
    VEC x = floor(clamp(e * CH(u_k) + 0.5, 0.0, u_top)) / u_top;
#if SRGB
    x = mix(1.055 * pow(x, VEC(1.0 / 2.4)) - 0.055, 12.92 * x, LE(x, VEC(0.0031308)));
#endif
    x = floor(x * 255.0 + 0.5) / 255.0;
#if MONO
    o = vec4(x, x, x, 1.0);
#else
    o = vec4(x, 1.0);
#endif
}
"""


@dataclass
class _Pass:
    prog: int
    loc: dict


@dataclass
class _Tex:
    """A texture with a framebuffer rendering into it."""

    fbo: int
    tex: int
    width: int
    height: int


def gaussian_weights(sigma_px: float) -> np.ndarray:
    """Centre-first half ``(r + 1,)`` float32 of the optics blur kernel
    (:func:`simbench.render.sensor.gaussian_half_kernel`)."""
    half = gaussian_half_kernel(sigma_px)
    if len(half) - 1 > MAX_BLUR_RADIUS:
        raise ValueError(f"optics blur sigma {sigma_px} px needs {len(half) - 1} taps each side; at most {MAX_BLUR_RADIUS}")
    return half.astype(np.float32)


class GLSensorPipeline:
    """Shutter accumulation, supersampling, distortion, optics blur and sensor on the GL side.

    Shares the rasteriser's context; textures are bound on units 1-2 only, so the
    rasteriser's state (its board texture on unit 0) is untouched.
    """

    def __init__(self, raster: Rasterizer) -> None:
        self.raster = raster
        raster.context.make_current()
        self._vao = gl.glGenVertexArrays(1)
        self._passes = {name: self._program(src) for name, src in
                        (("copy", _COPY), ("box", _BOX), ("remap", _REMAP), ("reduce", _REDUCE))}
        self._variants: dict[tuple, _Pass] = {}
        self._targets: dict[tuple, _Tex] = {}
        self._maps: dict[int, tuple[np.ndarray, int]] = {}

    # ---------------------------------------------------------------- GL objects
    @staticmethod
    def _program(frag: str) -> _Pass:
        prog = gl.glCreateProgram()
        for src, kind in ((_VERT, gl.GL_VERTEX_SHADER), (frag, gl.GL_FRAGMENT_SHADER)):
            gl.glAttachShader(prog, compile_shader(src, kind))
        gl.glLinkProgram(prog)
        if not gl.glGetProgramiv(prog, gl.GL_LINK_STATUS):
            raise RuntimeError(gl.glGetProgramInfoLog(prog).decode())
        names = ("u_src", "u_map", "u_ss", "u_w", "u_scale", "u_inv_n", "u_read_var", "u_full_well", "u_k", "u_top",
                 "u_seed")
        loc = {n: gl.glGetUniformLocation(prog, n) for n in names}
        return _Pass(prog, {n: v for n, v in loc.items() if v >= 0})

    def _variant(self, template: str, **defines: int) -> _Pass:
        """The pass compiled from ``template`` with ``defines`` as constants (cached)."""
        key = (template,) + tuple(sorted(defines.items()))
        p = self._variants.get(key)
        if p is None:
            src = {"blur_h": _BLUR_H, "sensor": _SENSOR}[template]
            p = self._variants[key] = self._program(src % dict(defines, reflect=_REFLECT))
        return p

    @staticmethod
    def _texture(internal, width: int, height: int, fmt=None, typ=None, data=None) -> int:
        tex = gl.glGenTextures(1)
        gl.glActiveTexture(gl.GL_TEXTURE0 + _UNIT_SRC)
        gl.glBindTexture(gl.GL_TEXTURE_2D, tex)
        gl.glTexStorage2D(gl.GL_TEXTURE_2D, 1, internal, width, height)
        if data is not None:
            gl.glPixelStorei(gl.GL_UNPACK_ALIGNMENT, 1)
            gl.glTexSubImage2D(gl.GL_TEXTURE_2D, 0, 0, 0, width, height, fmt, typ, data)
        # texelFetch only, but a texture with the default mipmap filter and one level is incomplete.
        gl.glTexParameteri(gl.GL_TEXTURE_2D, gl.GL_TEXTURE_MIN_FILTER, gl.GL_NEAREST)
        gl.glTexParameteri(gl.GL_TEXTURE_2D, gl.GL_TEXTURE_MAG_FILTER, gl.GL_NEAREST)
        gl.glActiveTexture(gl.GL_TEXTURE0)
        return int(tex)

    def _target(self, name: str, width: int, height: int, internal=gl.GL_RGBA32F) -> _Tex:
        key = (name, width, height, int(internal))
        t = self._targets.get(key)
        if t is None:
            tex = self._texture(internal, width, height)
            fbo = gl.glGenFramebuffers(1)
            gl.glBindFramebuffer(gl.GL_FRAMEBUFFER, fbo)
            gl.glFramebufferTexture2D(gl.GL_FRAMEBUFFER, gl.GL_COLOR_ATTACHMENT0, gl.GL_TEXTURE_2D, tex, 0)
            gl.glDrawBuffers(1, [gl.GL_COLOR_ATTACHMENT0])
            if gl.glCheckFramebufferStatus(gl.GL_FRAMEBUFFER) != gl.GL_FRAMEBUFFER_COMPLETE:
                raise RuntimeError(f"incomplete post-process framebuffer {key}")
            t = self._targets[key] = _Tex(int(fbo), tex, width, height)
        return t

    def _map_texture(self, map_xy: np.ndarray) -> int:
        entry = self._maps.get(id(map_xy))
        if entry is None or entry[0] is not map_xy:  # keyed by identity; holds the array so the id stays valid
            H, W = map_xy.shape[:2]
            tex = self._texture(gl.GL_RG32F, W, H, gl.GL_RG, gl.GL_FLOAT, np.ascontiguousarray(map_xy, np.float32))
            entry = self._maps[id(map_xy)] = (map_xy, tex)
        return entry[1]

    def _run(self, p: _Pass, src: int, dst: _Tex, **uniforms) -> None:
        gl.glBindFramebuffer(gl.GL_FRAMEBUFFER, dst.fbo)
        gl.glViewport(0, 0, dst.width, dst.height)
        gl.glDisable(gl.GL_DEPTH_TEST)
        gl.glUseProgram(p.prog)
        gl.glActiveTexture(gl.GL_TEXTURE0 + _UNIT_SRC)
        gl.glBindTexture(gl.GL_TEXTURE_2D, src)
        if "u_src" in p.loc:
            gl.glUniform1i(p.loc["u_src"], _UNIT_SRC)
        for name, value in uniforms.items():
            loc = p.loc.get(name)
            if loc is None:
                continue
            if name == "u_ss":
                gl.glUniform1i(loc, int(value))
            elif name == "u_w":
                gl.glUniform1fv(loc, len(value), value)
            elif name == "u_k":
                gl.glUniform3fv(loc, 1, value)
            elif name == "u_seed":
                gl.glUniform2ui(loc, int(value[0]), int(value[1]))
            elif name == "u_map":
                gl.glActiveTexture(gl.GL_TEXTURE0 + _UNIT_MAP)
                gl.glBindTexture(gl.GL_TEXTURE_2D, value)
                gl.glUniform1i(loc, _UNIT_MAP)
            else:
                gl.glUniform1f(loc, float(value))
        gl.glActiveTexture(gl.GL_TEXTURE0)
        gl.glBindVertexArray(self._vao)
        gl.glDrawArrays(gl.GL_TRIANGLES, 0, 3)

    def upload(self, radiance: np.ndarray) -> int:
        """A new ``RGBA32F`` texture holding ``radiance`` ``(H, W, 4)`` float32 (row 0 = top),
        as :meth:`finish` takes it (tests and offline use; the renderer passes its own)."""
        self.raster.context.make_current()
        rad = np.ascontiguousarray(radiance, np.float32)
        if rad.ndim != 3 or rad.shape[2] != 4:
            raise ValueError(f"radiance must be (H, W, 4), got {rad.shape}")
        return self._texture(gl.GL_RGBA32F, rad.shape[1], rad.shape[0], gl.GL_RGBA, gl.GL_FLOAT, rad)

    # ---------------------------------------------------------------- shutter
    def accumulate(self, radiance_tex: int, width: int, height: int, first: bool) -> int:
        """Add one sub-frame's radiance texture into the shutter accumulator; returns its texture.

        ``first`` overwrites instead of adding. Sums in float32 with additive blending.
        """
        self.raster.context.make_current()
        acc = self._target("acc", width, height)
        if first:
            gl.glDisable(gl.GL_BLEND)
        else:
            gl.glEnable(gl.GL_BLEND)
            gl.glBlendEquation(gl.GL_FUNC_ADD)
            gl.glBlendFunc(gl.GL_ONE, gl.GL_ONE)
        self._run(self._passes["copy"], radiance_tex, acc)
        gl.glDisable(gl.GL_BLEND)
        return acc.tex

    # ---------------------------------------------------------------- frame
    def finish(self, radiance_tex: int, n_subframes: int, canvas_size: tuple[int, int], ss: int,
               map_xy: np.ndarray | None, out_size: tuple[int, int], sensor: Sensor, wb: WhiteBalance | None,
               psf_sigma_px: float, rng: np.random.Generator | None) -> np.ndarray:
        """Canvas radiance texture -> the camera's 8-bit frame.

        Parameters
        ----------
        radiance_tex : GL texture (``RGBA32F``, canvas size) holding the sum of the
            ``n_subframes`` sub-frames' linear radiance (row 0 = top)
        canvas_size : (width, height) of the supersampled canvas, px
        ss : supersampling factor per axis
        map_xy : (H, W, 2) float32 position on the 1x canvas of each output pixel, or
            None (no distortion: the 1x canvas is the image)
        out_size : (W, H) of the frame, px
        sensor, wb : the camera's sensor (its config and gamma table) and white balance
        psf_sigma_px : Gaussian optics blur, px (0: none)
        rng : the frame's generator (two uint32 seeds are drawn from it when the
            sensor adds noise); None: no noise

        Returns
        -------
        (H, W, 3) uint8 RGB frame (equal channels in ``ir`` mode), JPEG applied if configured.
        """
        self.raster.context.make_current()
        cfg = sensor.cfg
        W, H = out_size
        cw, ch = canvas_size
        src = radiance_tex
        if ss > 1:
            t = self._target("box", cw // ss, ch // ss)
            self._run(self._passes["box"], src, t, u_ss=ss)
            src = t.tex
        if map_xy is not None:
            t = self._target("remap", W, H)
            self._run(self._passes["remap"], src, t, u_map=self._map_texture(map_xy))
            src = t.tex
        if psf_sigma_px > 0:
            w = gaussian_weights(psf_sigma_px)
            t = self._target("blur_h", W, H)
            self._run(self._variant("blur_h", r=len(w) - 1), src, t, u_w=w)
            src = t.tex
        else:
            w = np.ones(1, np.float32)
        inv_n = np.float32(1.0) / np.float32(n_subframes)
        top = 2**_LUT_BITS - 1
        k = np.float32(cfg.gain / cfg.full_well_e * top)
        mono = cfg.mode == "ir"
        if not mono and wb is not None and wb.mode != "fixed":
            # Grey world needs the frame's mean before its gains: block sums on the GL
            # side, a (H/8, W/8) read-back. Taken before the vertical optics blur (which
            # moves no mean but at the border) and noise (zero mean but at the clip).
            rt = self._target("reduce", -(-W // _REDUCE_BLOCK), -(-H // _REDUCE_BLOCK))
            self._run(self._passes["reduce"], src, rt, u_scale=sensor.scale * inv_n, u_full_well=cfg.full_well_e)
            sums = np.frombuffer(gl.glReadPixels(0, 0, rt.width, rt.height, gl.GL_RGBA, gl.GL_FLOAT),
                                 np.float32).reshape(-1, 4).astype(np.float64).sum(axis=0)
            k3 = (wb.update_means(sums[:3] / max(sums[3], 1.0)) * k).astype(np.float32)
        else:
            k3 = np.full(3, k, np.float32) if (mono or wb is None) else (wb.gains * k).astype(np.float32)
        noise = rng is not None and (cfg.shot_noise or cfg.read_noise_e > 0)
        seed = rng.integers(0, 2**32, size=2, dtype=np.uint32) if noise else np.zeros(2, np.uint32)
        out = self._target("out_mono" if mono else "out_rgb", W, H, gl.GL_R8 if mono else gl.GL_RGBA8)
        prog = self._variant("sensor", r=len(w) - 1, noise=int(noise), shot=int(cfg.shot_noise),
                             srgb=int(cfg.gamma == "srgb"), mono=int(mono))
        self._run(prog, src, out, u_w=w, u_scale=sensor.scale, u_inv_n=inv_n,
                  u_read_var=np.float32(cfg.read_noise_e**2), u_full_well=cfg.full_well_e, u_k=k3, u_top=float(top),
                  u_seed=seed)
        gl.glPixelStorei(gl.GL_PACK_ALIGNMENT, 1)
        if mono:
            buf = gl.glReadPixels(0, 0, W, H, gl.GL_RED, gl.GL_UNSIGNED_BYTE)
            frame = np.empty((H, W, 3), np.uint8)
            frame[...] = np.frombuffer(buf, np.uint8).reshape(H, W, 1)
        else:
            # RGBA then drop alpha: a 4-byte read-back is a plain copy in Mesa.
            buf = gl.glReadPixels(0, 0, W, H, gl.GL_RGBA, gl.GL_UNSIGNED_BYTE)
            frame = np.ascontiguousarray(np.frombuffer(buf, np.uint8).reshape(H, W, 4)[..., :3])
        return sensor.compress(frame)
