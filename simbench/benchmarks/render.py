"""``simbench bench ...``: speed figures, each with a reference measured in the same run.

Renderer: frames per second at 640x480 on one core (llvmpipe limited to one thread
with ``LP_NUM_THREADS=1`` and OpenCV to one thread) for the bench's renderer in its
configurations, and ``mujoco.Renderer`` on the same MuJoCo scene (humanoid geoms,
floor, props) with MSAA, shadows and reflections off, as the reference.
"""

from __future__ import annotations

import os
import time

import numpy as np


def _one_core() -> None:
    os.environ["LP_NUM_THREADS"] = "1"  # read by Mesa when the GL context is created
    import cv2

    cv2.setNumThreads(1)


def _time_frames(fn, n: int, warm_up: int = 3, passes: int = 3) -> float:
    """Frames per second of ``fn(k)`` for ``k = warm_up .. warm_up + n - 1``, after
    ``fn(0..warm_up-1)``: the fastest of ``passes`` passes over these frames.

    Several warm-up frames: llvmpipe compiles a shader variant the first time each
    state combination is drawn, and the first frames also fault in buffers; one
    warm-up frame left the first configuration measured up to 1.5x slow. The fastest
    pass: on a machine shared with other work, a single pass of 30 frames moved by up to
    25 % from run to run, and the least disturbed pass is the repeatable figure (as
    ``timeit`` reports); every configuration and the reference are measured alike.
    """
    for k in range(warm_up):
        fn(k)
    best = np.inf
    for _ in range(passes):
        t0 = time.perf_counter()
        for k in range(warm_up, warm_up + n):
            fn(k)
        best = min(best, time.perf_counter() - t0)
    return n / best


def run_render_benchmark(n_frames: int = 60, scenario_path: str | None = None, echo=print) -> dict[str, float]:
    """Print and return camera-frames per second for each configuration."""
    _one_core()
    from simbench.render.gl_context import configure_gl_environment

    configure_gl_environment()
    import mujoco

    from simbench.stage.build import build_stage
    from simbench.render.frames import frame_rng
    from simbench.scenario import RigConfig, Scenario

    base = Scenario(name="bench_render", duration_s=max(n_frames + 5, 4) / 30.0, rig=RigConfig(count=4, radius_m=3.2, height_m=2.0, look_at=(0, 0, 0.95), hfov_deg=56),
                    motion={"clip": "zigzag_fast"}, sensor={"mode": "visible", "motion_blur": False, "antialias": 1,
                                                          "exposure_ms": 8.0})
    times = base.frame_times()
    results: dict[str, float] = {}

    def measure(label: str, sc: Scenario, n_cams: int, ids: bool = False, raster_only: bool = False) -> float:
        times = sc.frame_times()
        bench = build_stage(sc)
        bench.cameras = bench.cameras[:n_cams]
        fr = bench.frame_renderer()
        poses = bench.pose_at(times[: n_frames + 3])
        from simbench.render.frames import plan_subframes, poses_at_times

        plan = plan_subframes(fr, times[: n_frames + 3], bench.pose_at)
        sub = [poses_at_times(bench.pose_at, p) for p in plan]

        if ids or raster_only:
            cam = fr.cameras[0]
            canvas = cam.canvas(1)
            outputs = ("ids",) if ids else ("radiance",)

            def one(k):
                P, N = fr.moving.pose(poses[k].body_pos, poses[k].body_rot, poses[k].marker_pos, poses[k].prop_T)
                fr.raster.update_dynamic(P, N)
                fr.raster.render(canvas.width, canvas.height, canvas.K, cam.R, cam.t, bench.lighting.lights_at(0.0),
                                 bench.lighting.ambient_rgb, outputs=outputs)
        else:
            def one(k):
                fr.render_frame(k, float(times[k]), sub[k], poses[k], frame_rng(0, k))
        fps = _time_frames(one, n_frames) * (1 if ids or raster_only else n_cams)
        sub_mean = float(np.mean([len(p) for p in plan[3:]]))
        results[label] = fps
        echo(f"{label:<52} {fps:8.1f} camera-frames/s" + (f"   (mean {sub_mean:.1f} shutter sub-frames)" if sub_mean > 1 else ""))
        return fps

    echo("simbench render benchmark: 640x480, one core (LP_NUM_THREADS=1, cv2 1 thread), "
         f"{n_frames} frames (fastest of 3 passes), scene = humanoid + floor + walls, zigzag_fast")
    lit1 = measure("lit RGB, 1 camera (antialias 1)", base, 1)
    measure("lit RGB, 4 cameras (antialias 1)", base, 4)
    measure("lit RGB, 1 camera (antialias 2, default)", base.with_overrides({"sensor.antialias": 2}), 1)
    measure("lit RGB, 1 camera, blur 25 ms shutter (antialias 1)",
            base.with_overrides({"sensor.motion_blur": True, "sensor.exposure_ms": 25.0}), 1)
    ir = base.with_overrides({"sensor.mode": "ir", "subject.markers": "plugin_gait_full"})
    measure("ir mode + 39 markers, 1 camera (antialias 1)", ir, 1)
    measure("id render only, 1 camera", base, 1, ids=True)
    raster = measure("lit RGB rasterise + read back only (no sensor), 1 camera", base, 1, raster_only=True)

    # Reference: mujoco.Renderer on the same MuJoCo scene, MSAA/shadows/reflections off.
    bench = build_stage(base)
    model = mujoco.MjModel.from_xml_string(bench.scene.mjcf_xml)
    model.vis.quality.offsamples = 0
    data = mujoco.MjData(model)
    renderer = mujoco.Renderer(model, 480, 640)
    renderer.scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = False
    renderer.scene.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = False
    renderer.scene.flags[mujoco.mjtRndFlag.mjRND_SKYBOX] = False
    cam = bench.cameras[0]
    mjcam = mujoco.MjvCamera()
    mjcam.type = mujoco.mjtCamera.mjCAMERA_FREE
    target = np.array(base.rig.look_at)
    d = cam.center - target
    mjcam.lookat[:] = target
    mjcam.distance = float(np.linalg.norm(d))
    mjcam.azimuth = float(np.degrees(np.arctan2(d[1], d[0]))) + 180.0
    mjcam.elevation = -float(np.degrees(np.arcsin(d[2] / np.linalg.norm(d))))
    qpos = bench.motion.qpos(times[: n_frames + 3])
    nq = qpos.shape[1]

    def mj_one(k):
        data.qpos[:nq] = qpos[k]
        mujoco.mj_kinematics(model, data)
        renderer.update_scene(data, camera=mjcam)
        renderer.render()

    ref = _time_frames(mj_one, n_frames)
    results["mujoco.Renderer reference"] = ref
    echo(f"{'mujoco.Renderer, same scene, 1 camera (reference)':<52} {ref:8.1f} camera-frames/s")
    echo(f"ratio lit RGB rasterisation (like for like) / mujoco.Renderer: {raster / ref:.2f}x")
    echo(f"ratio lit RGB full camera (rasterise + optics blur + sensor noise + 8-bit; no lens distortion in this scene) "
         f"/ mujoco.Renderer: {lit1 / ref:.2f}x")
    results["ratio_vs_mujoco"] = raster / ref
    results["ratio_full_camera_vs_mujoco"] = lit1 / ref
    return results
