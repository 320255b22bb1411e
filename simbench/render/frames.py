"""From scene states to camera frames: shutter integration, distortion, sensor.

:class:`FrameRenderer` renders, for each frame and each camera, the mean radiance
over the shutter interval from sub-frame renders (their count adapts to how far
the body moves in the image during the exposure), applies distortion and optics
blur, and runs the sensor model. It also returns the id map and marker visibility
at mid-exposure, the instant the ground truth describes.

Rolling shutter (``sensor.readout_ms`` > 0): row ``y`` of an ``H``-row frame whose timestamp
is ``t`` is exposed over ``[t_y - e/2, t_y + e/2]`` with ``t_y = t + y / H * readout`` (row 0
at the frame's timestamp; :func:`row_times`). The frame is rendered at sub-frame instants
spread over ``[t - e/2, t + readout + e/2]``, as many as keep the image motion between two
within ``blur_step_px`` (the blur step's accuracy), and each output row averages the
sub-frames that fall in its own exposure window (:func:`rolling_weights`; without motion
blur, the sub-frame nearest its instant). The id map and visibility stay at ``t``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Iterator

import cv2
import numba
import numpy as np

from simbench.render import ids as idc
from simbench.render.camera import VirtualCamera
from simbench.render.geometry import MovingGeometry
from simbench.render.gl_sensor import GLSensorPipeline
from simbench.render.lighting import Lighting
from simbench.render.rasterizer import GeometryBuffers, Light, Rasterizer
from simbench.render.sensor import AutoExposure, Sensor, WhiteBalance
from simbench.scenario import SensorConfig


@dataclass
class Pose:
    """Everything that moves, at one instant (arrays as :meth:`MovingGeometry.pose` takes)."""

    body_pos: np.ndarray     # (B, 3)
    body_rot: np.ndarray     # (B, 3, 3)
    marker_pos: np.ndarray   # (M, 3)
    prop_T: np.ndarray       # (P, 4, 4)
    probe_points: np.ndarray  # (K, 3) points whose image motion sets the blur sub-frame count


@dataclass
class FrameOutput:
    """One frame of every camera.

    images : (C, H, W, 3) uint8 RGB
    ids : (C, H, W) int16 id map at mid-exposure (see :mod:`simbench.render.ids`)
    marker_visible_fraction : (C, M) float, visible area / expected area of each marker
    n_subframes : int
    """

    index: int
    time_s: float
    images: np.ndarray
    ids: np.ndarray
    marker_visible_fraction: np.ndarray
    n_subframes: int


class FrameRenderer:
    def __init__(
        self,
        cameras: list[VirtualCamera],
        sensor_cfg: SensorConfig,
        fps: float,
        lighting: Lighting,
        static: GeometryBuffers,
        moving: MovingGeometry,
        n_markers: int,
        marker_radius: float,
        rasterizer: Rasterizer | None = None,
        sensor_backend: str = "numpy",
    ) -> None:
        """``sensor_backend`` (same model in all three; noise realisations differ):
        ``"numpy"`` reads back float radiance and runs :meth:`Sensor.frame`, the fast
        path; ``"reference"`` runs the reference implementation
        (``cv2.GaussianBlur``, :meth:`Sensor.electrons`, :meth:`Sensor.to_frame`);
        ``"gl"`` runs shutter sum, supersampling, distortion, optics blur and sensor
        as GL passes and reads back 8-bit frames (:mod:`simbench.render.gl_sensor`).
        Measured on one llvmpipe core at 640x480, the GL passes cost more than the
        numpy fast path (each full-screen pass is ~4 ms there), hence the default."""
        self.cameras = cameras
        self.cfg = sensor_cfg
        self.fps = fps
        self.lighting = lighting
        self.moving = moving
        self.n_markers = n_markers
        self.marker_radius = marker_radius
        self._owns_raster = rasterizer is None
        self.raster = rasterizer or Rasterizer()
        self.raster.set_static(static)
        self.raster.set_dynamic(moving.buffers)
        work: dict = {}  # cameras are processed in turn: one set of sensor scratch arrays
        self.sensors = [Sensor(sensor_cfg, fps, work) for _ in cameras]
        self.wbs = [WhiteBalance(sensor_cfg, fps) for _ in cameras]
        self.aes = [AutoExposure(sensor_cfg, fps) if sensor_cfg.auto_exposure else None for _ in cameras]
        self.exposure_s = sensor_cfg.exposure_ms * 1e-3
        self.readout_s = sensor_cfg.readout_ms * 1e-3
        self._gl = None
        self._buffers: dict[tuple[int, int], dict[str, np.ndarray]] = {}
        self.set_sensor_backend(sensor_backend)

    def free(self) -> None:
        """Release the rasteriser's GL objects if this renderer made it (a rasteriser passed in
        stays with its owner); ``with FrameRenderer(...) as r:`` does so on the way out."""
        if self._owns_raster:
            self.raster.free()

    def __enter__(self) -> "FrameRenderer":
        return self

    def __exit__(self, *exc) -> None:
        self.free()

    def set_sensor_backend(self, backend: str) -> None:
        """Switch between ``"numpy"``, ``"reference"`` and ``"gl"`` (see the constructor)."""
        if backend not in ("numpy", "reference", "gl"):
            raise ValueError(f"sensor_backend must be 'numpy', 'reference' or 'gl', got {backend!r}")
        if backend == "gl" and (self.readout_s > 0 or self.cfg.auto_exposure or self.cfg.vignetting > 0):
            raise ValueError("the gl sensor backend has no rolling shutter, auto exposure or vignetting: use 'numpy'")
        self.sensor_backend = backend
        if backend == "gl":
            self._gl = self._gl or GLSensorPipeline(self.raster)

    def _read_buffers(self, width: int, height: int) -> dict[str, np.ndarray]:
        """Read-back arrays of one canvas size, reused from render to render: each is
        consumed (added to the shutter sum, passed to the sensor, or counted) before the
        next render of that size overwrites it."""
        key = (width, height)
        bufs = self._buffers.get(key)
        if bufs is None:
            bufs = self._buffers[key] = {
                "radiance": np.empty((height, width, 3), np.float32),
                "radiance_red": np.empty((height, width, 1), np.float32),
                "ids": np.empty((height, width), np.int32),
            }
        return bufs

    # ------------------------------------------------------------------ shutter
    def subframe_count(self, pose_open: Pose, pose_mid: Pose, pose_close: Pose) -> int:
        """Sub-frames needed so that nothing moves more than ``blur_step_px`` between two
        (between shutter open and close; with a rolling shutter, over :meth:`shutter_span`,
        motion blur or not, up to ``max(max_subframes, 64)``)."""
        rolling = self.readout_s > 0
        if not self.cfg.motion_blur and not rolling:
            return 1
        worst = 0.0
        for cam in self.cameras:
            a, b, c = (cam.project(p.probe_points) for p in (pose_open, pose_mid, pose_close))
            d = np.linalg.norm(b - a, axis=1) + np.linalg.norm(c - b, axis=1)
            inside = cam.calibration_camera().in_image(b, margin_px=-50)
            if np.any(inside & np.isfinite(d)):
                worst = max(worst, float(np.nanmax(d[inside])))
        n = int(np.ceil(worst / self.cfg.blur_step_px))
        return int(np.clip(n, 1, max(self.cfg.max_subframes, ROLLING_MAX_SUBFRAMES) if rolling else self.cfg.max_subframes))

    def shutter_span(self, t_mid: float) -> tuple[float, float]:
        """First and last instant any row of the frame stamped ``t_mid`` is exposed at."""
        e = self.exposure_s if self.cfg.motion_blur else 0.0
        return t_mid - e / 2, t_mid + self.readout_s + e / 2

    def subframe_times(self, t_mid: float, n: int) -> np.ndarray:
        if self.readout_s > 0:  # spread over every row's exposure
            a, b = self.shutter_span(t_mid)
            return a + (b - a) * (np.arange(n) + 0.5) / n
        if n == 1:
            return np.array([t_mid])
        return t_mid + self.exposure_s * ((np.arange(n) + 0.5) / n - 0.5)

    # ------------------------------------------------------------------ lights
    def _lights(self, t: float, cam: VirtualCamera) -> tuple[list[Light], np.ndarray, np.ndarray | None]:
        if self.cfg.mode == "ir":
            # IR: an IR-pass filter blocks the room lights; each camera's ring light
            # lights the scene dimly and makes retro-reflective markers glow.
            ring = np.full(3, self.cfg.ring_light)
            lights = [Light("point", c.center, np.full(3, 0.15 * self.cfg.ring_light)) for c in self.cameras]
            return lights, np.full(3, 0.02), ring
        return self.lighting.lights_at(t), self.lighting.ambient_rgb, None

    # ------------------------------------------------------------------ render
    def render_frame(self, index: int, t_mid: float, subframe_poses: list[Pose], mid_pose: Pose,
                     rng: np.random.Generator, only: frozenset[int] | None = None) -> FrameOutput:
        """Every camera's frame at ``t_mid``; with ``only``, just those cameras' (the others'
        images, ids and visibility are left unset: :func:`iterate_frames` fills them from
        their own instants)."""
        C = len(self.cameras)
        ss = self.cfg.antialias
        H, W = self.cameras[0].height, self.cameras[0].width
        images = np.empty((C, H, W, 3), np.uint8)  # every camera's frame is written whole
        id_maps = np.zeros((C, H, W), np.int16)
        vis = np.zeros((C, self.n_markers))
        n = len(subframe_poses)
        # Pose every sub-frame once; all cameras share them (synchronised global shutters).
        posed = [self._pose(p) for p in subframe_poses]
        mid_posed = None if n == 1 else self._pose(mid_pose)
        sub_times = self.subframe_times(t_mid, n)
        for ci, cam in enumerate(self.cameras):
            if only is not None and ci not in only:
                continue
            canvas = cam.canvas(ss)
            gl_post = self._gl if self.sensor_backend == "gl" else None
            rows_w = rolling_weights(sub_times, t_mid, self.readout_s, self.exposure_s if self.cfg.motion_blur else 0.0,
                                     H) if self.readout_s > 0 else None
            acc, idr = self._shutter_sum(cam, canvas, posed, sub_times, rows_w, gl_post)
            if idr is None:  # ids and visibility at mid-exposure (the instant of the ground truth)
                if mid_posed is None:
                    mid_posed = self._pose(mid_pose)
                idr = self._mid_ids(cam, canvas, mid_posed, t_mid)
            vis[ci] = self._visible_fraction(cam, idr, mid_pose.marker_pos, ss)
            id_maps[ci] = cam.finish_nearest(idr, ss)
            if gl_post is not None:
                images[ci] = gl_post.finish(acc, n, (canvas.width, canvas.height), ss, canvas.map_xy, (W, H),
                                            self.sensors[ci], self.wbs[ci], self.cfg.psf_sigma_px, rng)
            elif self.sensor_backend == "numpy":
                self._sense(ci, cam, acc, n, rows_w, rng, images[ci])
            else:
                images[ci] = self._sense_reference(ci, cam, acc, n, rows_w, rng)
        return FrameOutput(index, t_mid, images, id_maps, vis, n)

    def _pose(self, p: Pose) -> tuple[np.ndarray, np.ndarray]:
        """The moving geometry's vertex positions and normals in pose ``p``."""
        return self.moving.pose(p.body_pos, p.body_rot, p.marker_pos, p.prop_T)

    def _shutter_sum(self, cam: VirtualCamera, canvas, posed: list, sub_times: np.ndarray,
                     rows_w: np.ndarray | None, gl_post: GLSensorPipeline | None) -> tuple:
        """:meth:`render_frame`'s shutter step for camera ``cam``: its sub-frames rendered and
        summed, and the id map if the one pass made it (else None). The sum: with a rolling
        shutter (``rows_w``), each output row's weighted mean at the image; with the gl backend,
        a texture; else at the canvas, for one sub-frame the read-back buffer as it is."""
        ss = self.cfg.antialias
        n = len(posed)
        acc = None
        idr = None
        if gl_post is not None:
            rad_out = ("radiance_texture",)
        elif self.cfg.mode == "ir":
            rad_out = ("radiance_red",)
        else:
            rad_out = ("radiance",)
        for i, ((P, N), ts) in enumerate(zip(posed, sub_times)):
            if rows_w is not None and not rows_w[i].any():
                continue  # no row is exposed at this sub-frame
            self.raster.update_dynamic(P, N)
            lights, ambient, ring = self._lights(float(ts), cam)
            # Without blur the one sub-frame *is* mid-exposure: take its ids from the same pass.
            outs = rad_out + (("ids",) if n == 1 and rows_w is None else ())
            out = self.raster.render(canvas.width, canvas.height, canvas.K, cam.R, cam.t, lights, ambient, ring,
                                     outputs=outs, buffers=self._read_buffers(canvas.width, canvas.height))
            if rows_w is not None:  # rolling shutter: each output row its own weights
                part = cam.finish_radiance(out["radiance"], ss)
                part = part * rows_w[i].astype(np.float32).reshape((-1,) + (1,) * (part.ndim - 1))
                if acc is None:
                    acc = part
                else:
                    acc += part
            elif gl_post is not None:
                acc = out["radiance_texture"] if n == 1 else gl_post.accumulate(
                    out["radiance_texture"], canvas.width, canvas.height, first=i == 0)
            else:
                rad = out["radiance"]
                if acc is None:  # one sub-frame: use the read-back buffer as it is
                    acc = rad if n == 1 else rad.copy()
                else:
                    acc += rad
            idr = out.get("ids")
        return acc, idr

    def _mid_ids(self, cam: VirtualCamera, canvas, mid_posed: tuple, t_mid: float) -> np.ndarray:
        """The canvas id map of camera ``cam`` at mid-exposure, posed ``mid_posed``, in a pass of its own."""
        self.raster.update_dynamic(*mid_posed)
        lights, ambient, ring = self._lights(t_mid, cam)
        return self.raster.render(canvas.width, canvas.height, canvas.K, cam.R, cam.t, lights, ambient, ring,
                                  outputs=("ids",), buffers=self._read_buffers(canvas.width, canvas.height))["ids"]

    def _sense(self, ci: int, cam: VirtualCamera, acc: np.ndarray, n: int, rows_w: np.ndarray | None,
               rng: np.random.Generator, image: np.ndarray) -> None:
        """Camera ``ci``'s frame from its shutter sum ``acc`` by the fast path
        (:meth:`Sensor.frame`), written into ``image``."""
        if rows_w is not None:  # already the weighted mean in the output image
            self.sensors[ci].frame(acc, rng, self.wbs[ci], self.cfg.psf_sigma_px, 1, out=image, ae=self.aes[ci])
            return
        img = cam.finish_radiance(acc, self.cfg.antialias)  # the sum: the sensor divides by n
        self.sensors[ci].frame(img, rng, self.wbs[ci], self.cfg.psf_sigma_px, n, out=image, ae=self.aes[ci])

    def _sense_reference(self, ci: int, cam: VirtualCamera, acc: np.ndarray, n: int, rows_w: np.ndarray | None,
                         rng: np.random.Generator) -> np.ndarray:
        """Camera ``ci``'s frame from its shutter sum ``acc`` by the reference implementation
        (``cv2.GaussianBlur``, :meth:`Sensor.electrons`, :meth:`Sensor.to_frame`)."""
        if rows_w is not None:
            img = acc
        else:
            radiance = acc / np.float32(n) if n > 1 else acc
            img = cam.finish_radiance(radiance, self.cfg.antialias)
        if self.cfg.psf_sigma_px > 0:
            img = cv2.GaussianBlur(img, (0, 0), self.cfg.psf_sigma_px)
        if img.ndim == 2:  # OpenCV drops a single channel axis
            img = img[..., None]
        e = self.sensors[ci].electrons(img, rng)
        return self.sensors[ci].to_frame(e, self.wbs[ci], self.aes[ci])

    def _visible_fraction(self, cam: VirtualCamera, canvas_ids: np.ndarray, marker_pos: np.ndarray, ss: int) -> np.ndarray:
        """Visible marker area over its expected (unoccluded) area, per marker ``(M,)``."""
        M = self.n_markers
        if M == 0:
            return np.zeros(0)
        counts = _marker_pixel_counts(canvas_ids.reshape(-1), idc.MARKER_BASE, M).astype(float) / ss**2
        z = cam.depth(marker_pos)
        f = 0.5 * (cam.K[0, 0] + cam.K[1, 1])
        with np.errstate(divide="ignore", invalid="ignore"):
            expected = np.pi * (f * self.marker_radius / z) ** 2
            frac = np.where(z > 0, counts / np.maximum(expected, 1e-9), 0.0)
        uv = cam.project(marker_pos)
        frac[~cam.calibration_camera().in_image(uv)] = 0.0
        return np.clip(frac, 0.0, 1.5)


@numba.njit(cache=True, nogil=True)
def _marker_pixel_counts(ids, base, n_markers):
    """Pixels ``(n_markers,)`` int64 of each marker ``m`` (id ``base + m``) in the id map
    ``ids (N,)``: one pass, where a mask, a selection and a bincount took ~0.6 ms a frame."""
    counts = np.zeros(n_markers, np.int64)
    for i in range(ids.size):
        m = ids[i] - base
        if 0 <= m < n_markers:
            counts[m] += 1
    return counts


#: A rolling shutter's sub-frames may go up to this many (or ``max_subframes`` if more): its span
#: (readout + exposure) is several exposures long.
ROLLING_MAX_SUBFRAMES = 64


def row_times(t_frame: float, rows: np.ndarray, height: int, readout_s: float) -> np.ndarray:
    """The rolling shutter's row-time model: row ``y`` (pixels, 0 at the top) of an ``height``-row
    frame stamped ``t_frame`` is exposed (mid-exposure) at ``t_frame + y / height * readout_s``."""
    return t_frame + np.asarray(rows, float) / height * readout_s


def rolling_weights(sub_times: np.ndarray, t_mid: float, readout_s: float, exposure_s: float, height: int) -> np.ndarray:
    """Weights ``(n, H)`` of ``n`` evenly spaced sub-frames ``sub_times`` in each output row of a
    rolling-shutter frame stamped ``t_mid``: each sub-frame stands for the interval around it, and
    row ``y`` takes the overlap of those intervals with its exposure window (:func:`row_times`
    +- ``exposure_s / 2``), normalised to sum to 1; with no exposure (no motion blur), the
    sub-frame nearest its instant."""
    sub_times = np.asarray(sub_times, float)
    n = len(sub_times)
    ty = row_times(t_mid, np.arange(height), height, readout_s)
    step = (sub_times[-1] - sub_times[0]) / (n - 1) if n > 1 else max(readout_s + exposure_s, 1e-9)
    w = np.zeros((n, height))
    if exposure_s <= 0 or n == 1:
        nearest = np.argmin(np.abs(sub_times[:, None] - ty[None, :]), axis=0)
        w[nearest, np.arange(height)] = 1.0
        return w
    lo = np.maximum(sub_times[:, None] - step / 2, ty[None, :] - exposure_s / 2)
    hi = np.minimum(sub_times[:, None] + step / 2, ty[None, :] + exposure_s / 2)
    w = np.clip(hi - lo, 0.0, None)
    return w / np.maximum(w.sum(axis=0, keepdims=True), 1e-300)


def plan_subframes(renderer: FrameRenderer, times_mid: np.ndarray, pose_at: Callable[[np.ndarray], list[Pose]]) -> list[np.ndarray]:
    """Sub-frame times of every frame (adaptive count), from poses at shutter open/mid/close
    (with a rolling shutter, at the start, middle and end of :meth:`FrameRenderer.shutter_span`)."""
    e = renderer.exposure_s
    if renderer.readout_s > 0:
        span = np.array([renderer.shutter_span(float(t)) for t in times_mid]).reshape(-1, 2)
        probe_times = np.stack([span[:, 0], span.mean(axis=1), span[:, 1]], axis=1).ravel()
        poses = poses_at_times(pose_at, probe_times)
        return [renderer.subframe_times(float(t), renderer.subframe_count(*poses[3 * k: 3 * k + 3]))
                for k, t in enumerate(times_mid)]
    if not renderer.cfg.motion_blur or e <= 0:
        return [np.array([t]) for t in times_mid]
    probe_times = np.stack([times_mid - e / 2, times_mid, times_mid + e / 2], axis=1).ravel()
    poses = poses_at_times(pose_at, probe_times)
    out = []
    for k, t in enumerate(times_mid):
        n = renderer.subframe_count(poses[3 * k], poses[3 * k + 1], poses[3 * k + 2])
        out.append(renderer.subframe_times(float(t), n))
    return out


def poses_at_times(pose_at: Callable[[np.ndarray], list[Pose]], times: np.ndarray) -> list[Pose]:
    """``pose_at`` needs strictly increasing times: sort, drop repeats, and map back."""
    uniq, inv = np.unique(np.asarray(times, float), return_inverse=True)
    poses_u = pose_at(uniq)
    return [poses_u[i] for i in inv.ravel()]


def frame_rng(seed: int, frame: int) -> np.random.Generator:
    """The noise generator of one frame: independent of how many frames came before."""
    return np.random.default_rng(np.random.SeedSequence([seed, 0x5EB5, frame]))


def iterate_frames(renderer: FrameRenderer, times_mid: np.ndarray, pose_at: Callable[[np.ndarray], list[Pose]],
                   seed: int) -> Iterator[FrameOutput]:
    """Render every frame in order (a generator: frames are written as they come).

    ``times_mid`` is ``(F,)`` (every camera's frame ``k`` at one instant) or ``(F, C)``, each
    camera's frame at its own instant (:mod:`simbench.stage.clocks`): see :func:`_iterate_per_camera`.
    """
    times_mid = np.asarray(times_mid, float)
    if times_mid.ndim == 2:
        if (times_mid == times_mid[:, :1]).all():
            times_mid = times_mid[:, 0]  # one instant per frame: exactly the synchronised render
        else:
            yield from _iterate_per_camera(renderer, times_mid, pose_at, seed)
            return
    plan = plan_subframes(renderer, times_mid, pose_at)
    all_times = np.concatenate([np.concatenate([p, [t]]) for p, t in zip(plan, times_mid)])
    poses = poses_at_times(pose_at, all_times)
    pos = 0
    for k, (sub, t) in enumerate(zip(plan, times_mid)):
        sub_poses = poses[pos: pos + len(sub)]
        mid_pose = poses[pos + len(sub)]
        pos += len(sub) + 1
        yield renderer.render_frame(k, float(t), sub_poses, mid_pose, frame_rng(seed, k))


def _iterate_per_camera(renderer: FrameRenderer, times_mid: np.ndarray, pose_at: Callable[[np.ndarray], list[Pose]],
                        seed: int) -> Iterator[FrameOutput]:
    """Frames whose cameras expose at their own instants ``times_mid (F, C)``.

    Frame ``k`` is rendered once per distinct instant among its cameras (each render drawing
    just the cameras at that instant, with its own noise stream), and the pieces are merged.
    A camera whose frame repeats its previous instant (a duplicated frame) gets that frame's
    image again, as a webcam repeating a frame does. As for synchronised frames, the poses of
    every instant are simulated up front (a few kB each); the images go frame by frame.
    """
    F, C = times_mid.shape
    H, W = renderer.cameras[0].height, renderer.cameras[0].width
    groups: list[list[tuple[float, list[int]]]] = []  # per frame: (instant, cameras) to render
    for k in range(F):
        by_t: dict[float, list[int]] = {}
        for ci in range(C):
            if k == 0 or times_mid[k, ci] != times_mid[k - 1, ci]:
                by_t.setdefault(float(times_mid[k, ci]), []).append(ci)
        groups.append(list(by_t.items()))
    instants = np.array([t for g in groups for t, _ in g])
    plan = plan_subframes(renderer, instants, pose_at)
    poses = poses_at_times(pose_at, np.concatenate([np.concatenate([p, [t]]) for p, t in zip(plan, instants)]))
    prev: FrameOutput | None = None
    pos, j = 0, 0
    for k in range(F):
        images = np.empty((C, H, W, 3), np.uint8)
        ids = np.zeros((C, H, W), np.int16)
        vis = np.zeros((C, renderer.n_markers))
        done: set[int] = set()
        n_sub = 1
        for t, cams in groups[k]:
            sub = plan[j]
            sub_poses, mid_pose = poses[pos: pos + len(sub)], poses[pos + len(sub)]
            pos += len(sub) + 1
            j += 1
            rng = np.random.default_rng(np.random.SeedSequence([seed, 0x5EB5, k, 1 + cams[0]]))
            out = renderer.render_frame(k, t, sub_poses, mid_pose, rng, only=frozenset(cams))
            images[cams], ids[cams], vis[cams] = out.images[cams], out.ids[cams], out.marker_visible_fraction[cams]
            n_sub = max(n_sub, out.n_subframes)
            done.update(cams)
        for ci in set(range(C)) - done:  # duplicated frames
            images[ci], ids[ci], vis[ci] = prev.images[ci], prev.ids[ci], prev.marker_visible_fraction[ci]
        prev = FrameOutput(k, float(times_mid[k, 0]), images, ids, vis, n_sub)
        yield prev
