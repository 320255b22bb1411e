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
