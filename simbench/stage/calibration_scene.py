"""The calibration session of a scenario, rendered: a printed board and a wand seen by the rig.

What a user does before a take, done in the simulator with the scenario's own cameras,
sensor (noise, optics blur, distortion) and lights:

1. **Board pictures** (``visible`` mode, room lights, board held still so no motion
   blur). A printed checkerboard or ChArUco board (:func:`mocap.calib.boards.render_board_texture`
   mapped on a tessellated quad, :func:`simbench.render.geometry.board_buffers`) is held
   in ``n_views`` poses. Each pose faces a *pair* of cameras whose lines of sight to the
   board are at most ``max_view_angle_deg`` from its normal (so both see the print), is
   tilted ``tilt_deg`` away from facing them exactly and rolled up to 25 deg, lies
   entirely inside both images, and is placed so that its centre falls in a given cell
   of a 3 x 3 grid over one camera's image (cells cycle, so the poses cover the image).
   With ``floor_view`` a first view (index 0) shows the board lying printed face up on the
   floor, its origin at the world origin and its rows along world ``+x`` (board ``+y``
   along world ``-y``, see :mod:`mocap.calib.world_frame`): its face is
   ``board_thickness_m`` above the floor.
2. **Wand** (``ir`` mode, ring lights, the scenario's shutter and motion blur). Three
   retro-reflective spheres on a thin black stick, ``wand_d01_m`` and ``wand_d12_m`` apart,
   are waved along a smooth random path through the volume. Every frame goes through
   the real blob detector (:func:`mocap.detection.detect_markers`); a camera's frame is
   kept when it shows exactly three blobs, well separated, which the calibration tool's
   :func:`mocap.calib.wand.label_collinear_wand` then labels.

Exact ground truth comes with it: the board poses and the wand marker positions, and
their projections through the exact cameras.

Units: metres, pixels (x right, y down, pixel centres at integers, as OpenCV).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from mocap.calib.boards import BoardSpec, BoardTextureLayout, board_object_points, board_texture_layout, render_board_texture
from mocap.calib.wand import WandSpec, label_collinear_wand
from mocap.calib.world_frame import FLOOR_FROM_BOARD
from mocap.calibration import Calibration
from mocap.detection import DetectionParams, detect_markers
from simbench.errors import ScenarioError
from simbench.render import ids as idc
from simbench.render.camera import VirtualCamera, cameras_from_scenario
from simbench.render.frames import FrameRenderer, Pose, frame_rng, iterate_frames
from simbench.render.geometry import MovingGeometry, board_buffers, wand_geometry
from simbench.render.lighting import Lighting
from simbench.render.rasterizer import Rasterizer
from simbench.scenario import CalibrationSceneConfig, Scenario
from simbench.stage.renderer import build_frame_renderer, mid_exposure_times

#: Linear albedo of the printed board's white paper and black ink.
PAPER_ALBEDO = 0.80
INK_ALBEDO = 0.04
#: Texture resolution of the printed board (texels per metre; mipmapped by the rasteriser).
BOARD_TEXTURE_PX_PER_M = 2000.0
#: White quiet zone around the printed board, in squares.
BOARD_MARGIN_SQUARES = 1.0
#: Radius of the wand's stick (m): a 1.5 mm carbon rod. Where the stick leaves a sphere
#: towards the camera it hides a sliver of it, pulling the blob centroid along the wand
#: by an amount that changes with the wand's orientation, smoothly over a wave: with a
#: 3 mm rod that bias (about 0.05 px) moved the calibrated principal points by 0.5-1 px.
WAND_STICK_RADIUS_M = 0.00075
#: Smallest blob (px) taken for a wand marker: wand spheres are large, sensor noise specks are not.
WAND_MIN_BLOB_AREA_PX = 6
#: Smallest projected corner spacing (px) accepted for a board pose. The detector asks
#: for squares of 10 px or more; on boards seen so obliquely that the squares are
#: squashed to 8 px, cornerSubPix was seen to slip by 4 px onto the board's edge.
MIN_CORNER_SPACING_PX = 11.0
#: Largest in-plane roll of a board pose (deg).
MAX_ROLL_DEG = 25.0


# ---------------------------------------------------------------------- specs
def board_spec(cfg: CalibrationSceneConfig) -> BoardSpec:
    """The :class:`BoardSpec` of a scenario's ``[calibration_scene]``."""
    if cfg.board == "checkerboard":
        return BoardSpec("checkerboard", (cfg.board_cols, cfg.board_rows), cfg.square_m)
    marker = cfg.marker_m if cfg.marker_m is not None else 0.75 * cfg.square_m
    return BoardSpec("charuco", (cfg.board_cols, cfg.board_rows), cfg.square_m, marker, cfg.dictionary)


def wand_spec(cfg: CalibrationSceneConfig) -> WandSpec:
    """The collinear :class:`WandSpec` of a scenario's ``[calibration_scene]``."""
    return WandSpec.collinear(cfg.wand_d01_m, cfg.wand_d12_m)


def board_albedo_texture(spec: BoardSpec) -> tuple[np.ndarray, BoardTextureLayout]:
    """Linear albedo ``(H, W)`` float32 of the printed board and where the board frame is in it."""
    tex = render_board_texture(spec, BOARD_TEXTURE_PX_PER_M, BOARD_MARGIN_SQUARES)
    layout = board_texture_layout(spec, BOARD_TEXTURE_PX_PER_M, BOARD_MARGIN_SQUARES)
    albedo = INK_ALBEDO + (PAPER_ALBEDO - INK_ALBEDO) * (tex.astype(np.float32) / 255.0)
    return albedo.astype(np.float32), layout


def sheet_points(layout: BoardTextureLayout, n: int = 3) -> np.ndarray:
    """An ``n x n`` grid over the whole printed sheet (board plus margin), board frame ``(n*n, 3)`` m."""
    w, h = layout.size_m
    ox, oy = layout.origin_m
    gx, gy = np.meshgrid(np.linspace(-ox, w - ox, n), np.linspace(-oy, h - oy, n))
    return np.column_stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)])


# ---------------------------------------------------------------------- board poses
@dataclass
class BoardPoses:
    """World-from-board poses of the board views.

    Attributes
    ----------
    R_wb : (V, 3, 3) float
    t_wb : (V, 3) float
        Metres; board frame as in :mod:`mocap.calib.boards` (printed face ``z = 0``).
    pairs : list of (int, int) or None, length V
        The camera pair each view faces (None for the floor view).
    floor_view : int or None
        Index of the view with the board on the floor.
    """

    R_wb: np.ndarray
    t_wb: np.ndarray
    pairs: list[tuple[int, int] | None]
    floor_view: int | None

    @property
    def n_views(self) -> int:
        return len(self.R_wb)

    def transforms(self) -> np.ndarray:
        """``(V, 4, 4)`` homogeneous world-from-board transforms."""
        T = np.tile(np.eye(4), (self.n_views, 1, 1))
        T[:, :3, :3] = self.R_wb
        T[:, :3, 3] = self.t_wb
        return T


def camera_pairs(cameras: list[VirtualCamera], max_view_angle_deg: float) -> list[tuple[int, int]]:
    """Camera pairs a board can face together: viewing directions at most ``2 x max_view_angle_deg`` apart."""
    z = np.stack([c.R[2] for c in cameras])
    cos = np.clip(z @ z.T, -1.0, 1.0)
    limit = np.cos(np.radians(min(2.0 * max_view_angle_deg, 179.0)))
    return [(a, b) for a in range(len(cameras)) for b in range(a + 1, len(cameras)) if cos[a, b] >= limit]


def _pinhole(cam: VirtualCamera, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Undistorted pixels ``(n, 2)`` and depth ``(n,)`` of world points ``(n, 3)``."""
    pc = p @ cam.R.T + cam.t
    z = pc[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = pc[:, :2] / z[:, None] * np.diag(cam.K)[:2] + cam.K[:2, 2]
    return uv, z


def _visible_mask(cam: VirtualCamera, pts: np.ndarray, n_per: int, margin_px: float) -> np.ndarray:
    """Per candidate ``(N,)``: all its ``n_per`` world points ``(N * n_per, 3)`` in the image, in front."""
    W, H = cam.width, cam.height
    uv0, z = _pinhole(cam, pts)
    # The pinhole position guards against distortion polynomials folding far-off points back in.
    sane = (z > 0.2) & (uv0[:, 0] > -0.5 * W) & (uv0[:, 0] < 1.5 * W) & (uv0[:, 1] > -0.5 * H) & (uv0[:, 1] < 1.5 * H)
    uv = cam.project(pts)
    inside = cam.calibration_camera().in_image(uv, margin_px) & sane
    return inside.reshape(-1, n_per).all(axis=1)


def _corner_spacing(cam: VirtualCamera, corners_w: np.ndarray, grid: tuple[int, int]) -> np.ndarray:
    """Smallest projected spacing ``(N,)`` px between neighbouring corners ``(N * n_corners, 3)``."""
    cols, rows = grid
    uv = cam.project(corners_w).reshape(-1, rows, cols, 2)
    dx = np.linalg.norm(np.diff(uv, axis=2), axis=3).reshape(len(uv), -1)
    dy = np.linalg.norm(np.diff(uv, axis=1), axis=3).reshape(len(uv), -1)
    return np.nan_to_num(np.minimum(dx.min(axis=1), dy.min(axis=1)), nan=0.0)


def _facing_rotation(normal: np.ndarray) -> np.ndarray:
    """World-from-board rotations ``(N, 3, 3)`` of upright boards whose printed face looks along ``normal (N, 3)``."""
    z_b = -normal / np.linalg.norm(normal, axis=1, keepdims=True)  # board +z points into the board
    down = np.array([0.0, 0.0, -1.0])
    y_b = down - (z_b @ down)[:, None] * z_b
    y_b /= np.linalg.norm(y_b, axis=1, keepdims=True)
    x_b = np.cross(y_b, z_b)
    return np.stack([x_b, y_b, z_b], axis=2)


def _sample_pair_pose(cameras: list[VirtualCamera], pair: tuple[int, int], target: int, cell: tuple[int, int] | None,
                      cfg: CalibrationSceneConfig, spec: BoardSpec, layout: BoardTextureLayout,
                      rng: np.random.Generator, n: int = 1500) -> tuple[np.ndarray, np.ndarray] | None:
    """One board pose facing ``pair`` with its centre in ``cell`` (col, row of a 3 x 3 grid) of camera ``target``."""
    cam_t = cameras[target]
    W, H = cam_t.width, cam_t.height
    if cell is None:
        u = rng.uniform(0.1 * W, 0.9 * W, n)
        v = rng.uniform(0.1 * H, 0.9 * H, n)
    else:
        u = (cell[0] + rng.uniform(0, 1, n)) * W / 3.0
        v = (cell[1] + rng.uniform(0, 1, n)) * H / 3.0
    depth = rng.uniform(1.2, 5.0, n)
    rays = cam_t.calibration_camera().normalized_rays(np.column_stack([u, v]))
    z_along = rays @ cam_t.R[2]
    centre = cam_t.center + rays * (depth / z_along)[:, None]
    # Facing the pair: the bisector of the directions to its two cameras, then tilted.
    to_a = cameras[pair[0]].center - centre
    to_b = cameras[pair[1]].center - centre
    n0 = to_a / np.linalg.norm(to_a, axis=1, keepdims=True) + to_b / np.linalg.norm(to_b, axis=1, keepdims=True)
    n0 /= np.linalg.norm(n0, axis=1, keepdims=True)
    R0 = _facing_rotation(n0)
    lo, hi = cfg.tilt_deg
    tilt = np.radians(rng.uniform(lo, hi, n))
    phi = rng.uniform(0, 2 * np.pi, n)
    axis = np.cos(phi)[:, None] * R0[:, :, 0] + np.sin(phi)[:, None] * R0[:, :, 1]  # in the board plane
    roll = Rotation.from_rotvec(np.radians(rng.uniform(-MAX_ROLL_DEG, MAX_ROLL_DEG, n))[:, None] * np.array([0, 0, 1.0]))
    R = (Rotation.from_rotvec(axis * tilt[:, None]) * Rotation.from_matrix(R0) * roll).as_matrix()
    # Place the board so that its *centre* is at ``centre``.
    obj = board_object_points(spec)
    mid = 0.5 * (obj.min(axis=0) + obj.max(axis=0))
    t = centre - R @ mid
    ok = np.ones(n, dtype=bool)
    sheet = sheet_points(layout)
    sheet_w = np.einsum("nij,kj->nki", R, sheet) + t[:, None, :]
    ok &= sheet_w[..., 2].min(axis=1) > 0.05  # held above the floor
    face_normal = -R[:, :, 2]
    cos_max = np.cos(np.radians(cfg.max_view_angle_deg))
    corners_w = np.einsum("nij,kj->nki", R, obj) + t[:, None, :]
    size = np.full(n, np.inf)
    for c in pair:
        cam = cameras[c]
        sight = cam.center - centre
        sight /= np.linalg.norm(sight, axis=1, keepdims=True)
        ok &= np.einsum("ni,ni->n", sight, face_normal) >= cos_max
        idx = np.flatnonzero(ok)
        if not len(idx):
            return None
        vis = _visible_mask(cam, sheet_w[idx].reshape(-1, 3), len(sheet), 3.0)
        ok[idx[~vis]] = False
        idx = np.flatnonzero(ok)
        if not len(idx):
            return None
        spacing = _corner_spacing(cam, corners_w[idx].reshape(-1, 3), spec.corner_grid)
        ok[idx[spacing < MIN_CORNER_SPACING_PX]] = False
        size[idx] = np.minimum(size[idx], spacing)
    good = np.flatnonzero(ok)
    if not len(good):
        return None
    # Held as close as the two views allow (larger in the image, more accurate corners):
    # one of the largest third of the candidates that fit.
    big = good[size[good] >= np.quantile(size[good], 2.0 / 3.0)]
    k = big[rng.integers(len(big))]
    return R[k], t[k]


def floor_pose(cfg: CalibrationSceneConfig) -> tuple[np.ndarray, np.ndarray]:
    """World-from-board pose of the board lying printed face up with its origin above the world origin."""
    return FLOOR_FROM_BOARD.T.copy(), np.array([0.0, 0.0, cfg.board_thickness_m])


def sample_board_poses(cameras: list[VirtualCamera], cfg: CalibrationSceneConfig, spec: BoardSpec,
                       layout: BoardTextureLayout, rng: np.random.Generator,
                       scenario_path: str = "<scenario>") -> BoardPoses:
    """The floor view (if asked) and ``cfg.n_views`` poses facing camera pairs in turn (module doc).

    Raises
    ------
    ScenarioError
        When no two cameras can see the board together, or a pair cannot see it whole.
    """
    pairs = camera_pairs(cameras, cfg.max_view_angle_deg)
    if not pairs:
        raise ScenarioError(scenario_path, "calibration_scene.max_view_angle_deg", cfg.max_view_angle_deg,
                            "no two cameras look along directions close enough to see one board face together; "
                            "raise max_view_angle_deg or place cameras with overlapping views")
    Rs, ts, used = [], [], []
    floor_index = None
    if cfg.floor_view:
        R, t = floor_pose(cfg)
        Rs.append(R)
        ts.append(t)
        used.append(None)
        floor_index = 0
    # Each camera cycles through the cells of a 3 x 3 grid over its image (centre,
    # corners, edges) as the target of the pairs it belongs to.
    cells = [(1, 1), (0, 0), (2, 2), (2, 0), (0, 2), (1, 0), (1, 2), (0, 1), (2, 1)]
    targeted = np.zeros(len(cameras), dtype=int)
    for k in range(cfg.n_views):
        pair = pairs[k % len(pairs)]
        target = pair[0] if targeted[pair[0]] <= targeted[pair[1]] else pair[1]
        cell = cells[targeted[target] % len(cells)]
        targeted[target] += 1
        pose = _sample_pair_pose(cameras, pair, target, cell, cfg, spec, layout, rng)
        if pose is None:  # this image cell cannot hold the whole board for both cameras: anywhere
            pose = _sample_pair_pose(cameras, pair, target, None, cfg, spec, layout, rng, n=6000)
        if pose is None:
            names = f"{cameras[pair[0]].name} and {cameras[pair[1]].name}"
            raise ScenarioError(scenario_path, "calibration_scene.square_m", cfg.square_m,
                                f"cameras {names} cannot both see the whole board (with its margin) at a view angle "
                                f"under {cfg.max_view_angle_deg:g} deg; use a smaller board or raise max_view_angle_deg")
        Rs.append(pose[0])
        ts.append(pose[1])
        used.append(pair)
    return BoardPoses(np.array(Rs), np.array(ts), used, floor_index)


# ---------------------------------------------------------------------- wand motion
@dataclass(frozen=True)
class WandMotion:
    """A smooth random wave of a straight wand through a box.

    The centre of the wand follows two sinusoids per axis (0.1-0.45 Hz) inside
    ``center +- half``; its direction turns about the vertical at a steady rate while
    its elevation swings up to +-45 deg.
    """

    center: np.ndarray         # (3,) m
    half: np.ndarray           # (3,) m
    freq_hz: np.ndarray        # (2, 3)
    phase: np.ndarray          # (2, 3) rad
    weight: np.ndarray         # (2,)
    yaw0: float
    yaw_rate: float            # rad/s
    elev_amp: float            # rad
    elev_freq_hz: float
    elev_phase: float
    offsets_m: np.ndarray      # (3,) marker positions along the wand from marker 0

    @classmethod
    def random(cls, cfg: CalibrationSceneConfig, rng: np.random.Generator) -> "WandMotion":
        return cls(
            center=np.asarray(cfg.volume_center, float), half=np.asarray(cfg.volume_half_m, float),
            freq_hz=rng.uniform(0.1, 0.45, (2, 3)), phase=rng.uniform(0, 2 * np.pi, (2, 3)), weight=np.array([0.6, 0.4]),
            yaw0=float(rng.uniform(0, 2 * np.pi)), yaw_rate=float(rng.choice([-1, 1]) * rng.uniform(0.8, 1.6)),
            elev_amp=float(np.radians(45.0)), elev_freq_hz=float(rng.uniform(0.15, 0.35)),
            elev_phase=float(rng.uniform(0, 2 * np.pi)),
            offsets_m=np.array([0.0, cfg.wand_d01_m, cfg.wand_d01_m + cfg.wand_d12_m]),
        )

    def direction(self, times: np.ndarray) -> np.ndarray:
        """Unit wand direction (marker 0 to 2) ``(n, 3)``."""
        t = np.asarray(times, float)
        yaw = self.yaw0 + self.yaw_rate * t
        el = self.elev_amp * np.sin(2 * np.pi * self.elev_freq_hz * t + self.elev_phase)
        return np.column_stack([np.cos(el) * np.cos(yaw), np.cos(el) * np.sin(yaw), np.sin(el)])

    def points(self, times: np.ndarray) -> np.ndarray:
        """Marker centres ``(n, 3, 3)`` m at ``times (n,)`` s."""
        t = np.asarray(times, float)[:, None, None]
        s = np.sin(2 * np.pi * self.freq_hz[None] * t + self.phase[None])  # (n, 2, 3)
        c = self.center + self.half * np.einsum("k,nkd->nd", self.weight, s)
        d = self.direction(times)
        mid = 0.5 * (self.offsets_m[0] + self.offsets_m[-1])
        return c[:, None, :] + (self.offsets_m - mid)[None, :, None] * d[:, None, :]

    def stick_transforms(self, times: np.ndarray) -> np.ndarray:
        """World-from-stick ``(n, 4, 4)``: origin at marker 0, ``+z`` along the wand."""
        d = self.direction(times)
        p0 = self.points(times)[:, 0]
        helper = np.where(np.abs(d[:, 2:3]) < 0.9, np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0]))
        x = np.cross(helper, d)
        x /= np.linalg.norm(x, axis=1, keepdims=True)
        y = np.cross(d, x)
        T = np.tile(np.eye(4), (len(d), 1, 1))
        T[:, :3, :3] = np.stack([x, y, d], axis=2)
        T[:, :3, 3] = p0
        return T


# ---------------------------------------------------------------------- the rendered session
@dataclass
class CalibrationScene:
    """A rendered calibration session and its exact truth.

    Attributes
    ----------
    board : BoardSpec
    truth : Calibration
        The exact cameras (names in rendering order).
    board_images : (V, C, H, W) uint8
        Grey board pictures (luma of the rendered RGB frames).
    board_poses : BoardPoses
    floor_height_m : float
        Height of the floor board's printed face above the floor (its thickness).
    wand : WandSpec or None
    wand_times : (F,) float
    wand_points : (F, 3, 3) float
        True marker centres, metres, at mid-exposure.
    wand_blobs_px : (C, F, 3, 2) float
        Blobs of each camera frame that showed exactly three well-separated blobs
        (detector order), NaN otherwise.
    wand_markers_px : (C, F, 3, 2) float
        The same labelled as markers 0, 1, 2 by :func:`mocap.calib.wand.label_collinear_wand`.
    wand_true_px : (C, F, 3, 2) float
        Exact projections of the true marker centres.
    wand_blob_counts : (C, F) int
        Blobs the detector found.
    """

    board: BoardSpec
    truth: Calibration
    board_images: np.ndarray
    board_poses: BoardPoses
    floor_height_m: float
    wand: WandSpec | None = None
    wand_times: np.ndarray | None = None
    wand_points: np.ndarray | None = None
    wand_blobs_px: np.ndarray | None = None
    wand_markers_px: np.ndarray | None = None
    wand_true_px: np.ndarray | None = None
    wand_blob_counts: np.ndarray | None = None

    @property
    def camera_names(self) -> list[str]:
        return self.truth.names

    def board_corners_true(self) -> np.ndarray:
        """Exact distorted pixels ``(C, V, N, 2)`` of every board corner (NaN behind a camera)."""
        obj = board_object_points(self.board)
        pw = np.einsum("vij,nj->vni", self.board_poses.R_wb, obj) + self.board_poses.t_wb[:, None, :]
        V, N = pw.shape[:2]
        return np.stack([cam.project(pw.reshape(-1, 3)).reshape(V, N, 2) for cam in self.truth])

    def camera_images(self) -> dict[str, list[np.ndarray]]:
        """Per camera name, its board pictures in view order (what ``calibrate_cameras`` takes)."""
        return {n: list(self.board_images[:, c]) for c, n in enumerate(self.camera_names)}

    def write_images(self, folder: str | Path) -> dict[str, Path]:
        """Write ``folder/<camera>/view_NNN.png`` per camera (for ``mocap calibrate``); folder per camera."""
        out = {}
        for c, name in enumerate(self.camera_names):
            d = Path(folder) / name
            d.mkdir(parents=True, exist_ok=True)
            for v in range(self.board_images.shape[0]):
                cv2.imwrite(str(d / f"view_{v:03d}.png"), self.board_images[v, c])
            out[name] = d
        return out


def _rigid_pose(prop_T: np.ndarray, marker_pos: np.ndarray | None = None) -> Pose:
    """A scene without a body: props at ``prop_T (P, 4, 4)``, markers at ``marker_pos (M, 3)`` (also the blur probes)."""
    m = np.zeros((0, 3)) if marker_pos is None else marker_pos
    return Pose(np.zeros((0, 3)), np.zeros((0, 3, 3)), m, prop_T, m.copy())


def render_board_views(scenario: Scenario, cameras: list[VirtualCamera], lighting: Lighting, spec: BoardSpec,
                       poses: BoardPoses, noise_seed: int, rasterizer: Rasterizer | None = None,
                       progress: Callable[[int], None] | None = None) -> np.ndarray:
    """Grey pictures ``(V, C, H, W)`` uint8 of the board at ``poses``, through the scenario's sensor in visible mode.

    Every view is a still (no motion blur) lit by the scenario's lights at ``t = 0``.
    ``rasterizer``: one to reuse (it stays with the caller); else one is made and freed here.
    """
    cfg = scenario.calibration_scene
    sensor = scenario.sensor.model_copy(update={
        "mode": "visible", "motion_blur": False,
        "exposure_ms": cfg.board_exposure_ms if cfg.board_exposure_ms is not None else scenario.sensor.exposure_ms})
    albedo, layout = board_albedo_texture(spec)
    buf = board_buffers(layout.size_m, layout.origin_m, cfg.board_thickness_m, idc.BOARD)
    moving = MovingGeometry(buf, [("prop", 0, slice(0, len(buf.positions)))])
    T = poses.transforms()
    V, C = poses.n_views, len(cameras)
    out = np.zeros((V, C, cameras[0].height, cameras[0].width), np.uint8)
    with build_frame_renderer(cameras, sensor, scenario.fps, lighting, scenario.set, scenario.seed, moving,
                              rasterizer=rasterizer) as renderer:
        renderer.raster.set_texture(albedo)
        for v in range(V):
            pose = _rigid_pose(T[v:v + 1])
            fo = renderer.render_frame(v, 0.0, [pose], pose, frame_rng(noise_seed, v))
            for c in range(C):
                out[v, c] = cv2.cvtColor(fo.images[c], cv2.COLOR_RGB2GRAY)
            if progress is not None:
                progress(1)
    return out


def detect_wand_blobs(image: np.ndarray, params: DetectionParams | None = None, background: np.ndarray | None = None,
                      min_separation: float = 3.0) -> tuple[np.ndarray, int]:
    """The three wand blobs ``(3, 2)`` px of one IR frame (NaN unless exactly three, well apart) and the blob count.

    ``background``: the camera's frame of the empty volume (see
    :func:`mocap.detection.detect_markers`). ``min_separation``: blobs closer than this
    many blob radii (from their areas) are probably touching markers, whose centroids
    pull on each other: the frame is left out.
    """
    det = detect_markers(image, params if params is not None else DetectionParams(mode="ir"), background)
    xy = np.full((3, 2), np.nan)
    n = len(det.xy)
    if n != 3:
        return xy, n
    r = np.sqrt(np.max(det.area) / np.pi)
    d = np.linalg.norm(det.xy[:, None] - det.xy[None], axis=2)[np.triu_indices(3, 1)]
    if d.min() < min_separation * r:
        return xy, n
    return det.xy.copy(), n


def render_wand(scenario: Scenario, cameras: list[VirtualCamera], lighting: Lighting, motion: WandMotion,
                n_frames: int, noise_seed: int, rasterizer: Rasterizer | None = None,
                progress: Callable[[int], None] | None = None) -> dict[str, np.ndarray]:
    """Render the wand in IR and find its blobs; returns the arrays of :class:`CalibrationScene`'s ``wand_*``.

    ``rasterizer``: one to reuse (it stays with the caller); else one is made and freed here.
    """
    cfg = scenario.calibration_scene
    sensor = scenario.sensor.model_copy(update={"mode": "ir"})
    geo = wand_geometry(motion.offsets_m, cfg.wand_marker_radius_m, WAND_STICK_RADIUS_M)
    with build_frame_renderer(cameras, sensor, scenario.fps, lighting, scenario.set, scenario.seed, geo, 3,
                              cfg.wand_marker_radius_m, rasterizer=rasterizer) as renderer:
        blobs, counts, times = _wand_blobs(renderer, motion, n_frames, noise_seed, progress)
    pts = motion.points(times)
    true_px = np.stack([cam.project(pts.reshape(-1, 3)).reshape(n_frames, 3, 2) for cam in cameras])
    return {"times": times, "points": pts, "blobs": blobs, "true_px": true_px, "counts": counts}


def _wand_blobs(renderer: FrameRenderer, motion: WandMotion, n_frames: int, noise_seed: int,
                progress: Callable[[int], None] | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The three blobs ``(C, F, 3, 2)`` of every camera frame, the blob counts ``(C, F)`` and the frame times ``(F,)``."""
    cameras = renderer.cameras
    times = mid_exposure_times(n_frames, renderer.fps, renderer.cfg.exposure_ms)

    def pose_at(ts: np.ndarray) -> list[Pose]:
        pts = motion.points(ts)
        T = motion.stick_transforms(ts)
        return [_rigid_pose(T[i:i + 1], pts[i]) for i in range(len(ts))]

    C = len(cameras)
    blobs = np.full((C, n_frames, 3, 2), np.nan)
    counts = np.zeros((C, n_frames), np.int64)
    # As mocap systems mask the room before the wand wave: a frame of the empty volume
    # (wand under the floor) is the static background; only what is brighter counts.
    under_floor = np.eye(4)
    under_floor[2, 3] = -1.0
    hidden = _rigid_pose(under_floor[None], np.tile([0.0, 0.0, -1.0], (len(motion.offsets_m), 1)))
    empty = renderer.render_frame(0, 0.0, [hidden], hidden, frame_rng(noise_seed, 1 << 20)).images
    params = DetectionParams(mode="ir", min_area_px=WAND_MIN_BLOB_AREA_PX)
    for fo in iterate_frames(renderer, times, pose_at, noise_seed):
        for c in range(C):
            blobs[c, fo.index], counts[c, fo.index] = detect_wand_blobs(fo.images[c], params, empty[c])
        if progress is not None:
            progress(1)
    return blobs, counts, times


def render_calibration_scene(scenario: Scenario, rng: np.random.Generator,
                             cameras: list[VirtualCamera] | None = None, lighting: Lighting | None = None,
                             progress: Callable[[int], None] | None = None) -> CalibrationScene:
    """Pose, render and detect the whole calibration session of ``scenario`` (module doc).

    Parameters
    ----------
    scenario : Scenario
        Must have a ``[calibration_scene]`` section.
    rng : numpy.random.Generator
        Board poses, wand motion and the sensor noise seeds all come from it.
    cameras, lighting : optional
        The scenario's (built from it when not given).
    progress : callable, optional
        Called with 1 after every rendered view / wand frame.
    """
    cfg = scenario.calibration_scene
    path = scenario.origin
    if cfg is None:
        raise ScenarioError(path, "calibration_scene", None, "add a [calibration_scene] section to render calibration views")
    cameras = cameras if cameras is not None else cameras_from_scenario(scenario)
    lighting = lighting if lighting is not None else Lighting(scenario.lighting)
    spec = board_spec(cfg)
    layout = board_texture_layout(spec, BOARD_TEXTURE_PX_PER_M, BOARD_MARGIN_SQUARES)
    poses = sample_board_poses(cameras, cfg, spec, layout, rng, path)
    seeds = rng.integers(0, 2**31, 2)
    truth = Calibration(tuple(c.calibration_camera() for c in cameras))
    with Rasterizer() as raster:  # one GL context for the board pictures and the wand
        images = render_board_views(scenario, cameras, lighting, spec, poses, int(seeds[0]), rasterizer=raster, progress=progress)
        scene = CalibrationScene(spec, truth, images, poses, cfg.board_thickness_m)
        if not (cfg.wand and cfg.wand_frames > 0):
            return scene
        wand = wand_spec(cfg)
        motion = WandMotion.random(cfg, rng)
        w = render_wand(scenario, cameras, lighting, motion, cfg.wand_frames, int(seeds[1]), rasterizer=raster,
                        progress=progress)
    scene.wand = wand
    scene.wand_times = w["times"]
    scene.wand_points = w["points"]
    scene.wand_blobs_px = w["blobs"]
    scene.wand_markers_px = label_collinear_wand(w["blobs"], wand)
    scene.wand_true_px = w["true_px"]
    scene.wand_blob_counts = w["counts"]
    return scene
