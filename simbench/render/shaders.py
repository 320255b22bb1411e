"""The rasteriser's GLSL programs: one vertex shader (per-vertex lighting, retro-reflection,
ids, camera depth) and one fragment shader (three render targets; the texture branch compiled
in only for textured meshes), and shader compilation. See :mod:`simbench.render.rasterizer`.
"""

from __future__ import annotations

import simbench.render.gl_context  # noqa: F401  (configures the GL platform before PyOpenGL loads)

from OpenGL import GL as gl  # noqa: E402  (after the platform is configured)

MAX_LIGHTS = 8

# Lighting is evaluated per vertex (Gouraud): on llvmpipe the fragment stage dominates,
# and per-fragment lighting of a 640x480 view costs ~4x the whole rest of the frame.
# Meshes are tessellated finely enough (floor and walls are grids) that the
# interpolation error is far below the sensor noise.
VERTEX_SHADER = """
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
FRAGMENT_SHADER = """
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


def compile_shader(src: str, kind) -> int:
    sh = gl.glCreateShader(kind)
    gl.glShaderSource(sh, src)
    gl.glCompileShader(sh)
    if not gl.glGetShaderiv(sh, gl.GL_COMPILE_STATUS):
        raise RuntimeError(gl.glGetShaderInfoLog(sh).decode())
    return sh
