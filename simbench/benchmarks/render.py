"""``simbench bench render``: the renderer's speed, with a reference measured in the same run.

Frames per second at 640x480 on one core (llvmpipe limited to one thread with
``LP_NUM_THREADS=1`` and OpenCV to one thread) for the bench's renderer in its
configurations, and ``mujoco.Renderer`` on the same MuJoCo scene (humanoid geoms,
floor, props) with MSAA, shadows and reflections off, as the reference.

MuJoCo chooses its GL platform when it is first imported (``MUJOCO_GL``), so
:func:`run_render_benchmark` sets it (:func:`~simbench.render.gl_context.configure_gl_environment`)
before it imports anything that imports MuJoCo (the scenario's registries, the stage).
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING

import numpy as np

from simbench.benchmarks.timing import frames_per_second, one_core
from simbench.render.gl_context import configure_gl_environment

if TYPE_CHECKING:
    from simbench.scenario import Scenario

log = logging.getLogger(__name__)


def bench_scenario(n_frames: int) -> "Scenario":
    """The measured scene: 4 cameras around the humanoid (floor, walls), zigzag_fast, visible light, no blur."""
    from simbench.scenario import RigConfig, Scenario  # after configure_gl_environment (module doc)

    return Scenario(name="bench_render", duration_s=max(n_frames + 5, 4) / 30.0,
                    rig=RigConfig(count=4, radius_m=3.2, height_m=2.0, look_at=(0, 0, 0.95), hfov_deg=56),
                    motion={"clip": "zigzag_fast"},
                    sensor={"mode": "visible", "motion_blur": False, "antialias": 1, "exposure_ms": 8.0})


def run_render_benchmark(n_frames: int = 60) -> dict[str, float]:
    """Log (the command line prints) and return camera-frames per second for each configuration."""
    one_core()
    configure_gl_environment()
    base = bench_scenario(n_frames)
    log.info("simbench render benchmark: 640x480, one core (LP_NUM_THREADS=1, cv2 1 thread), "
             f"{n_frames} frames (fastest of 3 passes), scene = humanoid + floor + walls, zigzag_fast")
    results: dict[str, float] = {}
    configurations = [
        ("lit RGB, 1 camera (antialias 1)", base, 1, "full"),
        ("lit RGB, 4 cameras (antialias 1)", base, 4, "full"),
        ("lit RGB, 1 camera (antialias 2, default)", base.with_overrides({"sensor.antialias": 2}), 1, "full"),
        ("lit RGB, 1 camera, blur 25 ms shutter (antialias 1)",
         base.with_overrides({"sensor.motion_blur": True, "sensor.exposure_ms": 25.0}), 1, "full"),
        ("ir mode + 39 markers, 1 camera (antialias 1)",
         base.with_overrides({"sensor.mode": "ir", "subject.markers": "plugin_gait_full"}), 1, "full"),
        ("id render only, 1 camera", base, 1, "ids"),
        ("lit RGB rasterise + read back only (no sensor), 1 camera", base, 1, "radiance"),
    ]
    for label, sc, n_cams, what in configurations:
        fps, sub_mean = measure_renderer(sc, n_cams, what, n_frames)
        results[label] = fps
        log.info(f"{label:<52} {fps:8.1f} camera-frames/s" + (f"   (mean {sub_mean:.1f} shutter sub-frames)" if sub_mean > 1 else ""))
    # The timing model (issue 15): every camera exposed at its own instant, so each frame is posed
    # and shuttered once per camera instead of once; both rows render through iterate_frames.
    clocked = base.with_overrides({"sensor.clock": {"offset_ms_max": 500.0, "drift_ppm_max": 100.0, "jitter_ms": 0.5}})
    sync4 = measure_frames(base, n_frames)
    own4 = measure_frames(clocked, n_frames)
    results["lit RGB, 4 cameras, synchronised (iterate_frames)"] = sync4
    results["lit RGB, 4 cameras on their own clocks (iterate_frames)"] = own4
    results["ratio_own_clocks_vs_synchronised"] = own4 / sync4
    log.info(f"{'lit RGB, 4 cameras, synchronised (iterate_frames)':<52} {sync4:8.1f} camera-frames/s")
    log.info(f"{'lit RGB, 4 cameras on their own clocks (+-500 ms, 100 ppm)':<52} {own4:8.1f} camera-frames/s   "
             f"(ratio to synchronised {own4 / sync4:.2f}x)")
    # Rolling shutter (issue 15): each row band at its own instant, so a frame is rendered at as
    # many sub-frames as keep the image motion over the readout within the blur step.
    rolling = base.with_overrides({"sensor.readout_ms": 25.0})
    rs4 = measure_frames(rolling, n_frames)
    results["lit RGB, 4 cameras, rolling shutter 25 ms readout (iterate_frames)"] = rs4
    results["ratio_rolling_shutter_vs_global"] = rs4 / sync4
    sub_rs = _mean_subframes(rolling, n_frames)
    results["rolling_shutter_mean_subframes"] = sub_rs
    log.info(f"{'lit RGB, 4 cameras, rolling shutter 25 ms readout':<52} {rs4:8.1f} camera-frames/s   "
             f"(mean {sub_rs:.1f} sub-frames; ratio to the global shutter {rs4 / sync4:.2f}x)")
    lit1 = results["lit RGB, 1 camera (antialias 1)"]
    raster = results["lit RGB rasterise + read back only (no sensor), 1 camera"]
    ref = measure_mujoco_renderer(base, n_frames)
    results["mujoco.Renderer reference"] = ref
    log.info(f"{'mujoco.Renderer, same scene, 1 camera (reference)':<52} {ref:8.1f} camera-frames/s")
    log.info(f"ratio lit RGB rasterisation (like for like) / mujoco.Renderer: {raster / ref:.2f}x")
    log.info(f"ratio lit RGB full camera (rasterise + optics blur + sensor noise + 8-bit; no lens distortion in this scene) "
             f"/ mujoco.Renderer: {lit1 / ref:.2f}x")
    results["ratio_vs_mujoco"] = raster / ref
    results["ratio_full_camera_vs_mujoco"] = lit1 / ref
    return results


def measure_renderer(sc: "Scenario", n_cams: int, what: str, n_frames: int) -> tuple[float, float]:
    """Camera-frames per second of the first ``n_cams`` cameras and the mean shutter sub-frames.

    ``what``: ``"full"`` (shutter, sensor, every camera), or one camera's ``"ids"`` or
    ``"radiance"`` rasterisation and read-back only.
    """
    from simbench.render.frames import frame_rng, plan_subframes, poses_at_times  # after the GL platform is set
    from simbench.stage.build import build_stage

    stage = build_stage(sc)
    times = stage.frame_times()[: n_frames + 3]
    stage.cameras = stage.cameras[:n_cams]
    poses = stage.pose_at(times)
    with stage.frame_renderer() as fr:
        plan = plan_subframes(fr, times, stage.pose_at)
        sub = [poses_at_times(stage.pose_at, p) for p in plan]
        if what == "full":
            def one(k: int) -> None:
                fr.render_frame(k, float(times[k]), sub[k], poses[k], frame_rng(0, k))
        else:
            cam = fr.cameras[0]
            canvas = cam.canvas(1)

            def one(k: int) -> None:
                P, N = fr.moving.pose(poses[k].body_pos, poses[k].body_rot, poses[k].marker_pos, poses[k].prop_T)
                fr.raster.update_dynamic(P, N)
                fr.raster.render(canvas.width, canvas.height, canvas.K, cam.R, cam.t, stage.lighting.lights_at(0.0),
                                 stage.lighting.ambient_rgb, outputs=(what,))
        fps = frames_per_second(one, n_frames) * (n_cams if what == "full" else 1)
    return fps, float(np.mean([len(p) for p in plan[3:]]))


def measure_frames(sc: "Scenario", n_frames: int) -> float:
    """Camera-frames per second of :func:`~simbench.render.frames.iterate_frames` over every camera,
    one frame per call (simulation, shutter, sensor): the scenario's cameras at one instant per
    frame, or each at its own when ``[sensor.clock]`` says so."""
    from simbench.render.frames import iterate_frames  # after the GL platform is set
    from simbench.stage.build import build_stage

    stage = build_stage(sc)
    clocks = stage.clocks()
    times = stage.frame_times() if clocks.synchronised else clocks.true_times_s
    with stage.frame_renderer() as fr:
        def one(k: int) -> None:
            for _ in iterate_frames(fr, times[k: k + 1], stage.pose_at, sc.seed):
                pass
        return frames_per_second(one, n_frames) * len(stage.cameras)


def _mean_subframes(sc: "Scenario", n_frames: int) -> float:
    """Mean sub-frames per frame the scenario's renderer plans over the measured frames."""
    from simbench.render.frames import plan_subframes  # after the GL platform is set
    from simbench.stage.build import build_stage

    stage = build_stage(sc)
    with stage.frame_renderer() as fr:
        return float(np.mean([len(p) for p in plan_subframes(fr, stage.frame_times()[: n_frames + 3], stage.pose_at)]))


def measure_mujoco_renderer(sc: "Scenario", n_frames: int) -> float:
    """Frames per second of ``mujoco.Renderer`` on the stage's MuJoCo scene from its first camera
    (MSAA, shadows, reflections and skybox off)."""
    import mujoco  # after the GL platform is set

    from simbench.stage.build import build_stage

    stage = build_stage(sc)
    model = mujoco.MjModel.from_xml_string(stage.scene.mjcf_xml)
    model.vis.quality.offsamples = 0
    data = mujoco.MjData(model)
    renderer = mujoco.Renderer(model, 480, 640)
    for flag in (mujoco.mjtRndFlag.mjRND_SHADOW, mujoco.mjtRndFlag.mjRND_REFLECTION, mujoco.mjtRndFlag.mjRND_SKYBOX):
        renderer.scene.flags[flag] = False
    cam = stage.cameras[0]
    mjcam = mujoco.MjvCamera()
    mjcam.type = mujoco.mjtCamera.mjCAMERA_FREE
    target = np.array(sc.rig.look_at)
    d = cam.center - target
    mjcam.lookat[:] = target
    mjcam.distance = float(np.linalg.norm(d))
    mjcam.azimuth = float(np.degrees(np.arctan2(d[1], d[0]))) + 180.0
    mjcam.elevation = -float(np.degrees(np.arcsin(d[2] / np.linalg.norm(d))))
    qpos = stage.motion.qpos(stage.frame_times()[: n_frames + 3])
    nq = qpos.shape[1]

    def one(k: int) -> None:
        data.qpos[:nq] = qpos[k]
        mujoco.mj_kinematics(model, data)
        renderer.update_scene(data, camera=mjcam)
        renderer.render()

    return frames_per_second(one, n_frames)
