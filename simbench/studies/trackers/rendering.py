"""A planned video rendered through the bench's camera, sensor and renderer, and its marker
blobs detected (:func:`render_video`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh

from eval import tracking_metrics as tm
from mocap.detection import detect_markers, DetectionParams
from simbench.render import ids
from simbench.render.camera import VirtualCamera
from simbench.render.frames import iterate_frames, Pose
from simbench.render.geometry import moving_geometry
from simbench.render.lighting import Lighting
from simbench.render.rasterizer import Rasterizer
from simbench.scenario import CameraConfig, LightingConfig, SensorConfig, SetConfig
from simbench.studies.trackers.config import IMAGE_H, IMAGE_W, StudyConfig
from simbench.stage.renderer import build_frame_renderer, mid_exposure_times
from simbench.studies.trackers.videos import Barrier, VideoPlan


@dataclass
class RenderedVideo:
    """A rendered video reduced to what the trackers and the scores need.

    true_xy : (F, M, 2) float, px at mid-exposure; visible_fraction : (F, M) float;
    visible_area : (F, M) bool, enough area shows and in the image; visible : (F, M) bool,
    also not merged with another marker's blob; detections : list of F (n, 2) float px;
    sample_frame : int; sample_image : (H, W, 3) uint8 or None; mean_subframes : float.
    """

    true_xy: np.ndarray
    visible_fraction: np.ndarray
    visible_area: np.ndarray
    visible: np.ndarray
    detections: list[np.ndarray]
    sample_frame: int
    sample_image: np.ndarray | None
    mean_subframes: float


def study_camera(config: StudyConfig):
    """The webcam: 640x480 at the origin's side, looking at the markers' plane along +y."""
    h = 1.2
    return VirtualCamera.from_config(CameraConfig(
        name="webcam", position=(0.0, -config.plane_distance_m, h), look_at=(0.0, 0.0, h),
        width=IMAGE_W, height=IMAGE_H, hfov_deg=config.hfov_deg))


def back_project(camera, xy: np.ndarray, depth_m: np.ndarray) -> np.ndarray:
    """World points (..., 3) m of image points ``xy`` (..., 2) px at camera depths ``depth_m``
    (broadcast against ``xy[..., 0]``); the camera has no distortion."""
    xy = np.asarray(xy, dtype=np.float64)
    rays = np.concatenate([xy, np.ones(xy.shape[:-1] + (1,))], axis=-1) @ np.linalg.inv(camera.K).T
    cam_pts = rays * np.asarray(depth_m)[..., None]
    return (cam_pts - camera.t) @ camera.R  # R^T (p - t) for row vectors


def _barrier_transform(camera, barrier: Barrier, distance_m: float) -> tuple[np.ndarray, tuple[float, float, float]]:
    """Pose (4, 4) and size (x, y, z) m of the box that covers ``barrier`` in the image."""
    f = 0.5 * (camera.K[0, 0] + camera.K[1, 1])
    centre = back_project(camera, np.array(barrier.centre_px), np.array(distance_m))
    T = np.eye(4)
    T[:3, 3] = centre
    # The camera looks along +y with z up: image width is world x, image height world z.
    size = (barrier.width_px * distance_m / f, 0.03, barrier.height_px * distance_m / f)
    return T, size


def render_video(plan: VideoPlan, config: StudyConfig, rasterizer: Rasterizer, keep_sample: bool = False) -> RenderedVideo:
    """Render ``plan`` through the bench's camera model and detect the marker blobs (``rasterizer``
    is reused from video to video; it stays with the caller)."""
    cam = study_camera(config)
    sensor = SensorConfig(mode=config.sensor_mode, exposure_ms=config.exposure_ms, motion_blur=config.motion_blur,
                          antialias=config.antialias, blur_step_px=1.0)
    props, prop_T = [], np.zeros((0, 4, 4))
    if plan.barrier is not None:
        T, size = _barrier_transform(cam, plan.barrier, config.barrier_distance_m)
        props = [(trimesh.creation.box(size), np.array([0.04, 0.04, 0.05]), ids.PROP_BASE)]
        prop_T = T[None]
    M = plan.n_markers
    moving = moving_geometry([], {}, n_markers=M, prop_meshes=props, marker_radius=config.marker_radius_m)
    renderer = build_frame_renderer([cam], sensor, config.fps, Lighting(LightingConfig()),
                                    SetConfig(floor=True, walls=True, room_size_m=8.0, clutter=0), 0, moving, M,
                                    config.marker_radius_m, rasterizer=rasterizer)
    no_bodies, no_rots = np.zeros((0, 3)), np.zeros((0, 3, 3))

    def pose_at(times: np.ndarray) -> list[Pose]:
        world = back_project(cam, plan.xy_at(times), plan.depth_m[None, :])  # (T, M, 3)
        return [Pose(no_bodies, no_rots, w, prop_T, w) for w in world]

    times = mid_exposure_times(config.n_frames, config.fps, config.exposure_ms)
    params = DetectionParams(mode=config.sensor_mode)
    true_xy = np.empty((config.n_frames, M, 2))
    frac = np.empty((config.n_frames, M))
    dets: list[np.ndarray] = []
    images: list[np.ndarray] = []
    subframes = []
    noise_px = config.difficulty.detection_noise_px
    noise_rng = np.random.default_rng(np.random.SeedSequence([plan.render_seed, 1]))
    for out in iterate_frames(renderer, times, pose_at, seed=plan.render_seed):
        f = out.index
        true_xy[f] = cam.project(back_project(cam, plan.xy_at(times[f:f + 1])[0], plan.depth_m))
        frac[f] = out.marker_visible_fraction[0]
        xy = detect_markers(out.images[0], params).xy
        if noise_px > 0:
            xy = xy + noise_rng.normal(0.0, noise_px, xy.shape)
        dets.append(xy)
        subframes.append(out.n_subframes)
        if keep_sample:
            images.append(out.images[0])
    in_image = ((true_xy[..., 0] >= 0) & (true_xy[..., 0] <= IMAGE_W - 1)
                & (true_xy[..., 1] >= 0) & (true_xy[..., 1] <= IMAGE_H - 1))
    visible_area = (frac >= config.min_visible_fraction) & in_image
    visible = visible_area & ~tm.merged_markers(true_xy, config.merge_px)
    sample = _sample_frame(plan, true_xy, visible)
    return RenderedVideo(true_xy, frac, visible_area, visible, dets, sample, images[sample] if keep_sample else None,
                         float(np.mean(subframes)))


def _sample_frame(plan: VideoPlan, true_xy: np.ndarray, visible: np.ndarray) -> int:
    """The frame shown in the report: the marker behind the barrier (occlusion), the
    closest approach (swap), else the middle."""
    F = len(true_xy)
    if plan.category == "occlusion" and (~visible[:, 0]).any():
        hidden = np.flatnonzero(~visible[:, 0])
        return int(hidden[len(hidden) // 2])
    if plan.category == "swap":
        return int(np.argmin(np.linalg.norm(true_xy[:, 0] - true_xy[:, 1], axis=1)))
    return F // 2
