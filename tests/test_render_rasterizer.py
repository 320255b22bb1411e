"""The rasteriser's static-set cache against drawing everything afresh."""

from __future__ import annotations

import numpy as np

from simbench.stage.build import build_stage
from simbench.scenario import RigConfig, Scenario


def test_cached_static_set_with_dirty_rectangles_equals_a_full_redraw():
    """Views rendered in turn with the static set cached (only the rectangles the moving
    body covered restored) give the same radiance, ids and depth as drawing the whole
    scene afresh, whatever the order of views, poses and requested outputs."""
    sc = Scenario(name="raster_cache", duration_s=1.0, rig=RigConfig(count=3, radius_m=3.2, height_m=2.0,
                                                                    look_at=(0, 0, 0.95), hfov_deg=56),
                  motion={"clip": "zigzag_fast"}, sensor={"mode": "visible", "antialias": 1})
    bench = build_stage(sc)
    fr = bench.frame_renderer()
    raster = fr.raster
    poses = bench.pose_at(bench.frame_times()[[0, 9, 18, 27]])
    lights, ambient = bench.lighting.lights_at(0.0), bench.lighting.ambient_rgb
    plan = [(0, 0, ("radiance", "ids")), (1, 0, ("radiance", "ids")), (0, 1, ("ids",)), (0, 2, ("radiance", "depth")),
            (2, 3, ("radiance", "ids", "depth")), (0, 3, ("radiance", "ids", "depth")), (1, 2, ("depth",)),
            (1, 1, ("radiance", "ids", "depth"))]
    for ci, k, outputs in plan:
        cam = fr.cameras[ci]
        p = poses[k]
        raster.update_dynamic(*fr.moving.pose(p.body_pos, p.body_rot, p.marker_pos, p.prop_T))
        args = (cam.width, cam.height, cam.K, cam.R, cam.t, lights, ambient)
        cached = {name: a.copy() for name, a in raster.render(*args, outputs=outputs).items()}
        fresh = raster.render(*args, outputs=outputs, cache_static=False)
        if "ids" in outputs:  # the body is in view
            assert np.count_nonzero(fresh["ids"] == 1) > 2000, (ci, k)
        for name in outputs:
            assert np.array_equal(cached[name], fresh[name]), (ci, k, name)


def test_replaced_geometry_is_freed_and_free_releases_every_gl_object():
    """set_static/set_dynamic/set_texture delete what they replace, and free() deletes the
    rest (programs, meshes, texture, framebuffers) but not a context it was given."""
    from OpenGL import GL as gl

    from simbench.render.gl_context import GLContext
    from simbench.render.rasterizer import GeometryBuffers, Rasterizer

    tri = GeometryBuffers(positions=np.array([[-1, -1, 0], [1, -1, 0], [0, 1, 0]], np.float32),
                          normals=np.array([[0, 0, -1]] * 3, np.float32), albedo=np.ones((3, 3), np.float32),
                          ids=np.full(3, 7, np.int32), retro=np.zeros(3, np.float32), faces=np.array([[0, 1, 2]], np.uint32))
    K = np.array([[32.0, 0, 31.5], [0, 32.0, 31.5], [0, 0, 1]])
    context = GLContext(64, 64)
    try:
        r = Rasterizer(context)
        r.set_static(tri)
        r.set_dynamic(tri)
        r.set_texture(np.ones((4, 4)))
        first = (r._static.vao, r._static.vbo_pos, r._dynamic.vao, r._texture)
        r.set_static(tri)
        r.set_dynamic(tri)
        r.set_texture(np.ones((4, 4)))
        assert not gl.glIsVertexArray(first[0]) and not gl.glIsBuffer(first[1])
        assert not gl.glIsVertexArray(first[2]) and not gl.glIsTexture(first[3])
        out = r.render(64, 64, K, np.eye(3), np.array([0, 0, 3.0]), [], np.ones(3))
        assert out["ids"][32, 32] == 7
        held = (r._static.vao, r._dynamic.vao, r._texture, *r._progs.values(), *(t.fbo for t in r._fbos.values()))
        with r:
            pass  # the context manager frees on the way out
        r.free()  # and free() may be called again
        context.make_current()  # the context was given, so it is still usable
        assert not any(gl.glIsVertexArray(o) or gl.glIsTexture(o) or gl.glIsProgram(o) or gl.glIsFramebuffer(o)
                       for o in held)
    finally:
        context.close()
