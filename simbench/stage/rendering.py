"""Render a scenario: frames of every camera plus exact ground truth.

``render_scenario`` streams frames to MP4 (and optionally PNG) while it renders, keeps
the ground truth of every frame (a few kB each; the images are dropped as they are
written, so memory does not grow with the take: :func:`render_frames`), and writes
everything into a temporary directory that replaces ``out`` only when the render has
finished: an interrupted render leaves nothing half-written (:mod:`simbench.output_dir`: which paths may be replaced).
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from pathlib import Path
from contextlib import ExitStack, contextmanager
from typing import Callable, Iterator

import cv2
import numpy as np

from simbench import interrupts
from simbench.stage.build import build_stage
from simbench.stage.clocks import CameraClocks
from simbench.stage.stage import Stage
from simbench.stage.ground_truth import GroundTruth
from simbench.output_dir import AtomicOutputDir  # noqa: F401  (re-exported: the bench's output folders)
from simbench.render.contact_sheet import contact_sheet
from simbench.render.frames import FrameOutput, iterate_frames
from simbench.render.video import Mp4Writer
from simbench.scenario import Scenario
from simbench.scenes.humanoid import BODY_NAMES

# A marker counts as visible in a camera when it is inside the image and at least this
# fraction of its projected area is unoccluded in the id render. Below it the blob's
# centroid is pulled off the marker centre by more than ~0.3 px (measured on the
# quickstart), as on a real camera where a marker peeks out from behind a limb.
VISIBLE_FRACTION = 0.75


@dataclass
class RenderedSequence:
    """What a render hands to the pipeline and the scorer (kept in memory)."""

    ground_truth: GroundTruth
    frames: np.ndarray | None    # (F, C, H, W, 3) uint8 when kept in memory


@dataclass
class FrameRecord:
    """What the ground truth keeps of one rendered frame (a few kB; the images are not kept).

    marker_visible_fraction : (C, M) float, visible area / expected area of each marker
    """

    time_s: float
    marker_visible_fraction: np.ndarray
    n_subframes: int

    @classmethod
    def of(cls, out: FrameOutput) -> "FrameRecord":
        return cls(out.time_s, out.marker_visible_fraction, out.n_subframes)


def _ground_truth(bench: Stage, records: list[FrameRecord], id_maps: list[np.ndarray] | None,
                  clocks: CameraClocks | None = None) -> GroundTruth:
    """The ground truth of the frames ``records`` describe; ``id_maps``: one ``(F, H, W)`` int16 array per camera, or None.

    With unsynchronised ``clocks`` the frame times (and the 3D truth) are camera 0's, and each
    camera's 2D truth is projected at its own frames' instants."""
    sc = bench.scenario
    times = np.array([o.time_s for o in records])
    unsynced = clocks is not None and not clocks.synchronised
    cams = bench.cameras
    M = len(bench.marker_names)
    F, C = len(times), len(cams)
    if unsynced:
        uniq, inv = np.unique(clocks.true_times_s[:F], return_inverse=True)
        inv = inv.reshape(F, C)
        st_all = bench.states(uniq)
        st = dataclasses.replace(st_all, **{f: getattr(st_all, f)[inv[:, 0]] for f in
                                            ("times", "qpos", "body_xpos", "body_xmat", "marker_xpos", "joint_centres")},
                                 prop_poses={n: v[inv[:, 0]] for n, v in st_all.prop_poses.items()})
    else:
        st = bench.states(times)
    m2d = np.full((F, C, M, 2), np.nan)
    for ci, cam in enumerate(cams):
        if M:
            xyz = st_all.marker_xpos[inv[:, ci]] if unsynced else st.marker_xpos
            m2d[:, ci] = cam.project(xyz.reshape(-1, 3)).reshape(F, M, 2)
    vis_frac = np.stack([o.marker_visible_fraction for o in records]) if records else np.zeros((0, C, M))
    P = len(bench.prop_names)
    prop_poses = np.stack([st.prop_poses[n] for n in bench.prop_names], axis=1) if P else np.zeros((F, 0, 4, 4))
    light = np.stack([bench.lighting.intensities_at(float(t)) for t in times]) if F else np.zeros((0, len(bench.lighting.names)))
    gt = GroundTruth(
        times=times, camera_names=[c.name for c in cams],
        K=np.stack([c.K for c in cams]), dist=np.stack([c.dist for c in cams]),
        R=np.stack([c.R for c in cams]), t=np.stack([c.t for c in cams]),
        image_size=(cams[0].width, cams[0].height),
        marker_names=list(bench.marker_names), markers_3d=st.marker_xpos.copy(), markers_2d=m2d,
        marker_visible=vis_frac >= VISIBLE_FRACTION, marker_visible_frac=vis_frac,
        joint_names=list(BODY_NAMES), hinge_names=bench.hinge_names, qpos=st.qpos[:, :40].copy(),
        joint_centres=st.joint_centres.copy(), prop_names=list(bench.prop_names), prop_poses=prop_poses,
        light_names=list(bench.lighting.names), light_intensity=light,
        n_subframes=np.array([o.n_subframes for o in records]), fps=sc.fps,
        scenario_name=sc.name, scenario_hash=sc.content_hash(),
    )
    if id_maps is not None:
        gt.id_maps = {c.name: id_maps[ci] for ci, c in enumerate(cams)}
    if unsynced:
        gt.camera_times = clocks.true_times_s[:F].copy()
        gt.camera_timestamps = clocks.timestamps_s[:F].copy()
        gt.clock_offset_s, gt.clock_rate = clocks.offset_s.copy(), clocks.rate.copy()
    if sc.sensor.readout_ms > 0 and F:
        gt.readout_s = sc.sensor.readout_ms * 1e-3
        cam_times = clocks.true_times_s[:F] if unsynced else np.repeat(times[:, None], C, axis=1)
        gt.markers_2d_rolling = rolling_shutter_markers_2d(bench, cam_times, gt.readout_s) if M else np.zeros((F, C, 0, 2))
    return gt


#: Step (s) of the grid the row-time model's marker positions are interpolated on (linear
#: interpolation over 1 ms: under 0.01 mm at 20 m/s^2).
_ROLLING_GRID_S = 1e-3


def rolling_shutter_markers_2d(bench: Stage, cam_times: np.ndarray, readout_s: float, iterations: int = 4) -> np.ndarray:
    """Where a rolling shutter shows each marker, ``(F, C, M, 2)`` px: the image point ``uv`` of
    camera ``c`` with ``uv = project(X(t + v / H * readout_s))`` (the marker at the instant its
    row is exposed; :func:`simbench.render.frames.row_times`), solved by fixed-point iteration
    from the projection at the frame's time ``cam_times (F, C)`` (the row's motion over the
    readout is a fraction of a pixel per pixel, so a few iterations converge to well under 0.01 px)."""
    F, C = cam_times.shape
    grid = np.arange(max(cam_times.min() - 2 * _ROLLING_GRID_S, 0.0), cam_times.max() + readout_s + 3 * _ROLLING_GRID_S,
                     _ROLLING_GRID_S)
    X = bench.states(grid).marker_xpos                                     # (G, M, 3)
    M = X.shape[1]

    def at(t: np.ndarray) -> np.ndarray:                                   # t (F, M) -> (F, M, 3)
        u = np.clip((t - grid[0]) / _ROLLING_GRID_S, 0.0, len(grid) - 1.000001)
        i = np.floor(u).astype(int)
        w = (u - i)[..., None]
        m = np.arange(M)[None, :]
        return (1.0 - w) * X[i, m] + w * X[np.minimum(i + 1, len(grid) - 1), m]

    out = np.empty((F, C, M, 2))
    for ci, cam in enumerate(bench.cameras):
        t0 = np.repeat(cam_times[:, ci:ci + 1], M, axis=1)
        uv = cam.project(at(t0).reshape(-1, 3)).reshape(F, M, 2)
        for _ in range(iterations):
            t = t0 + np.nan_to_num(uv[..., 1], nan=0.0) / cam.height * readout_s
            uv = cam.project(at(t).reshape(-1, 3)).reshape(F, M, 2)
        out[:, ci] = uv
    return out


def render_frames(bench: Stage, on_frame: Callable[[FrameOutput], None] | None = None,
                  keep_frames: bool = True, keep_ids: bool = True, progress=None) -> RenderedSequence:
    """Render every frame, calling ``on_frame`` for each as it is made.

    Memory does not grow with the take unless asked: of each frame only a
    :class:`FrameRecord` is kept (its time, marker visibility and sub-frame count, what
    the ground truth needs besides the simulated states); the images are dropped once
    ``on_frame`` has returned (``on_frame`` copies what it wants to keep). ``keep_frames``
    keeps every image (``(F, C, H, W, 3)`` uint8, ~0.9 MiB per 640x480 camera-frame) and
    ``keep_ids`` every id map (``(F, H, W)`` int16 per camera, ~0.6 MiB per camera-frame),
    each in one array filled in place (no second copy when the take ends).
    """
    records: list[FrameRecord] = []
    F, cams = len(bench.frame_times()), bench.cameras
    clocks = bench.clocks()
    times = bench.frame_times() if clocks.synchronised else clocks.true_times_s  # (F,) or each camera's (F, C)
    frames = np.empty((F, len(cams), cams[0].height, cams[0].width, 3), np.uint8) if keep_frames and F else None
    ids = [np.empty((F, c.height, c.width), np.int16) for c in cams] if keep_ids else None
    with bench.frame_renderer() as renderer:
        for out in iterate_frames(renderer, times, bench.pose_at, bench.scenario.seed):
            if on_frame is not None:
                on_frame(out)
            if frames is not None:
                frames[out.index] = out.images
            if ids is not None:
                for ci in range(len(cams)):
                    ids[ci][out.index] = out.ids[ci]
            records.append(FrameRecord.of(out))
            del out  # the frame's images and id maps go now, not when the next frame replaces them
            if progress is not None:
                progress(1)
    gt = _ground_truth(bench, records, ids, clocks)
    return RenderedSequence(gt, frames)


@contextmanager
def render_writer(bench: Stage, folder: Path, png: bool) -> Iterator[Callable[[FrameOutput], None]]:
    """``with render_writer(stage, folder, png) as on_frame:`` writes each frame given to
    ``on_frame`` into ``folder/videos/<camera>.mp4`` (and ``folder/frames/<camera>/NNNNNN.png``);
    the videos are closed on the way out, whatever happens."""
    sc = bench.scenario
    videos = folder / "videos"
    videos.mkdir(parents=True, exist_ok=True)
    if png:
        for c in bench.cameras:
            (folder / "frames" / c.name).mkdir(parents=True, exist_ok=True)
    with ExitStack() as stack:
        writers = [stack.enter_context(Mp4Writer(videos / f"{c.name}.mp4", c.width, c.height, sc.fps)) for c in bench.cameras]

        def on_frame(out: FrameOutput) -> None:
            interrupts.raise_if_pending()  # a signal swallowed by a C callback stops the render here
            for ci, c in enumerate(bench.cameras):
                writers[ci].write(out.images[ci])
                if png:
                    cv2.imwrite(str(folder / "frames" / c.name / f"{out.index:06d}.png"), out.images[ci][..., ::-1])

        yield on_frame
    if sc.sensor.clock is not None:
        write_timestamps(bench.clocks(), [c.name for c in bench.cameras], videos)


def write_timestamps(clocks: CameraClocks, camera_names: list[str], videos: Path) -> None:
    """``videos/<camera>.timestamps.csv``: each frame's timestamp from the camera's own clock
    (what a real webcam gives; its offset and drift are unknown to the pipeline)."""
    for ci, name in enumerate(camera_names):
        rows = "".join(f"{k},{t:.9f}\n" for k, t in enumerate(clocks.timestamps_s[:, ci]))
        (videos / f"{name}.timestamps.csv").write_text("frame,timestamp_s\n" + rows)


def read_timestamps(path: Path) -> np.ndarray:
    """The ``(F,)`` timestamps (s) of a ``<camera>.timestamps.csv``."""
    return np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)[:, 1]


def contact_sheet_rows(n_frames: int, n_rows: int = 3) -> list[int]:
    """The frames a contact sheet shows: the first, the middle and the last (``n_rows`` spread evenly)."""
    return sorted(set(np.linspace(0, n_frames - 1, min(n_rows, n_frames)).round().astype(int).tolist()))


def write_contact_sheet(stage: Stage, gt: GroundTruth, frames: dict[int, np.ndarray], path: Path) -> None:
    """One row per frame index of ``frames`` (``(C, H, W, 3)`` images of every camera), one column
    per camera, with the visible markers' true projections drawn over them."""
    rows = sorted(frames)
    images = {(k, c.name): frames[k][ci] for k in rows for ci, c in enumerate(stage.cameras)}
    overlays = {(k, c.name): gt.markers_2d[k, ci][gt.marker_visible[k, ci]] for k in rows for ci, c in enumerate(stage.cameras)}
    contact_sheet(images, {k: float(gt.times[k]) for k in rows}, path, overlays=overlays)


def save_scenario_copy(scenario: Scenario, directory: Path) -> None:
    (directory / "scenario.json").write_text(json.dumps(scenario.model_dump(mode="json"), indent=2))


def render_scenario(scenario: Scenario, out: str | Path, png: bool = False, progress=None) -> RenderedSequence:
    """``simbench render``: MP4 per camera, optional PNGs, ground truth, contact sheet.

    ``out`` is replaced only if it is an earlier bench output (or an empty folder);
    see :mod:`simbench.output_dir`.
    """
    with AtomicOutputDir(out, scenario=scenario.name, kind="render") as tmp:  # refuses before anything renders
        bench = build_stage(scenario)
        rows = set(contact_sheet_rows(scenario.n_frames))
        sheet: dict[int, np.ndarray] = {}  # the contact sheet's frames: the only images kept
        with render_writer(bench, tmp, png) as write:

            def on_frame(fo: FrameOutput) -> None:
                write(fo)
                if fo.index in rows:
                    sheet[fo.index] = fo.images.copy()

            # The id maps are kept for ground_truth/ids.npz (~0.6 MiB per 640x480 camera-frame).
            seq = render_frames(bench, on_frame=on_frame, keep_frames=False, keep_ids=True, progress=progress)
        seq.ground_truth.save(tmp / "ground_truth")
        cal = seq.ground_truth.calibration()
        cal.save_opencv_yaml(tmp / "calibration.yml")
        cal.save_toml(tmp / "calibration.toml")
        write_contact_sheet(bench, seq.ground_truth, sheet, tmp / "contact_sheet.png")
        save_scenario_copy(scenario, tmp)
    return seq
