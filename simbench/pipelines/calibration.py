"""Calibrate the virtual rig from its rendered calibration session; score it against the exact cameras.

``simbench run`` calls :func:`run_calibration` when a scenario has a
``[calibration_scene]``: the board pictures and wand blobs of
:mod:`simbench.stage.calibration_scene` go through the calibration tool exactly as a user's
would (:func:`mocap.calibrate.detect_board_views` then
:func:`mocap.calibrate.calibrate_from_observations`, the two halves of
:func:`mocap.calibrate.calibrate_cameras`, kept apart here only so that the detected
corners are at hand for the residual plots), and the result is scored with
:func:`eval.calibration_metrics.compare_calibrations`.

World frame. The floor view defines the calibrated world (origin at the floor board's
first corner, ``z`` up). Its printed face lies ``board_thickness_m`` above the floor,
so the world is lowered by that known thickness, as a user would after measuring the
board: the estimate is then in the true world frame with **no alignment** to the
ground truth. Without a floor view the calibration is in the first camera's frame and
the estimate handed to the marker pipeline is rigidly aligned to the truth (camera
centres, Umeyama); the report says which.

Metrics (``calib.*``); per-camera errors are those of the **worst camera** (every camera
is in the report's table):

* ``focal_error_pct``, ``principal_point_error_px``, ``distortion_error_px``,
  ``projection_error_max_px``: intrinsics (no alignment involved);
* ``rotation_error_deg``, ``translation_error_mm``: extrinsics after a rigid alignment
  of the estimated camera centres onto the true ones (the rig's own geometry);
* ``floor_frame_rotation_error_deg``, ``floor_frame_translation_error_mm``: the same
  with no alignment at all (the world from the floor board; floor view only);
* ``reprojection_rms_px``: the calibration's own final RMS (board corners and wand);
* ``corner_error_rms_px``, ``wand_centroid_error_rms_px``: detected board corners and
  wand blobs against the exact projections, over all cameras (what the calibration was fed);
* ``wand_distance_rms_mm``; ``board_views_min`` (fewest views a camera used);
  ``wand_frames_labelled_fraction`` (camera-frames whose three blobs were labelled);
  ``world_aligned_to_truth`` (0: floor frame used as is; 1: rigidly aligned).
"""

from __future__ import annotations

import ctypes
import dataclasses
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

import cv2
import numpy as np

from eval.calibration_metrics import align_worlds, compare_calibrations
from mocap.calib.board_detection import DetectionSettings
from mocap.calib.boards import board_object_points
from mocap.calib.observations import BoardObservations, WandObservations
from mocap.calib.world_frame import transform_cameras, transform_points, transform_poses
from mocap.calibrate import CalibrationResult, calibrate_from_observations, detect_board_views, write_calibration
from mocap.calibration import Calibration
from simbench.stage.calibration_scene import CalibrationScene, render_calibration_scene
from simbench.scenario import Scenario


# ---------------------------------------------------------------------- calibrate
@dataclasses.dataclass
class SceneCalibration:
    """The calibration tool's answer for a rendered session.

    Attributes
    ----------
    result : CalibrationResult
        In the final world frame (see module doc).
    observations : BoardObservations
        Detected corners ``(C, V, N, 2)`` px.
    world : str
        ``"floor"`` (floor board, lowered by its thickness) or ``"camera"``.
    """

    result: CalibrationResult
    observations: BoardObservations
    world: str


def shift_world(result: CalibrationResult, R: np.ndarray, t: np.ndarray) -> CalibrationResult:
    """The same calibration re-expressed after ``x_new = R x_old + t`` (cameras, board poses, wand points)."""
    cams = result.calibration
    R_cw, t_cw = transform_cameras(np.stack([c.R for c in cams]), np.stack([c.t for c in cams]), R, t)
    new_cams = tuple(c.replace(R=R_cw[i], t=t_cw[i]) for i, c in enumerate(cams))
    P = result.board_poses_world.copy()
    ok = np.isfinite(P[:, 0, 0])
    if ok.any():
        Rb, tb = transform_poses(P[ok, :3, :3], P[ok, :3, 3], R, t)
        P[ok, :3, :3], P[ok, :3, 3] = Rb, tb
    wand = None if result.wand_points_world is None else transform_points(result.wand_points_world, R, t)
    return dataclasses.replace(result, calibration=Calibration(new_cams), board_poses_world=P, wand_points_world=wand)


@contextmanager
def single_threaded_blas() -> Iterator[None]:
    """Run the block with OpenBLAS and OpenCV on one thread each (restored afterwards); OpenBLAS
    is left alone where its thread count cannot be set.

    The bundle adjustment's LSMR solver takes thousands of norms of residual vectors;
    past 10000 residuals OpenBLAS splits each ``ddot`` over threads, and on a busy
    2-core machine every such call then waits ~2 ms for its threads instead of taking
    3 us (measured: 54 s instead of 7 s for a 4-camera board + wand adjustment).
    """
    setters = []
    try:
        with open("/proc/self/maps") as fh:
            paths = sorted({f[-1] for f in (line.split() for line in fh) if len(f) >= 6 and "openblas" in f[-1].lower()})
    except OSError:
        paths = []
    for path in paths:
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        for prefix, suffix in (("scipy_openblas", "64_"), ("scipy_openblas", ""), ("openblas", "64_"), ("openblas", "")):
            try:
                get = getattr(lib, f"{prefix}_get_num_threads{suffix}")
                put = getattr(lib, f"{prefix}_set_num_threads{suffix}")
            except AttributeError:
                continue
            get.restype = ctypes.c_int
            put.argtypes = [ctypes.c_int]
            setters.append((put, int(get())))
            break
    for put, _ in setters:
        put(1)
    # OpenCV's own threads too: its parallel solvers sum in a thread-dependent order, and the
    # calibration's figures differed by ~1e-6 relative from one run to the next.
    cv_threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        yield
    finally:
        cv2.setNumThreads(cv_threads)
        for put, n in setters:
            put(n)


def calibrate_scene(scene: CalibrationScene) -> SceneCalibration:
    """Run the calibration tool on a rendered session (floor view -> world; known floor board thickness).

    Detection runs without failure diagnosis: most pictures of a multi-camera session
    show the board from behind (it faces other cameras), and why is known.
    """
    obs, dets = detect_board_views(scene.camera_images(), scene.board, DetectionSettings(diagnose=False))
    wand_obs = None
    if scene.wand is not None:
        wand_obs = WandObservations(scene.camera_names, scene.wand_markers_px)
    floor = scene.board_poses.floor_view
    with single_threaded_blas():
        result = calibrate_from_observations(obs, wand=scene.wand, wand_observations=wand_obs, floor_view=floor,
                                             detections=dets)
    if floor is None:
        return SceneCalibration(result, obs, "camera")
    # The floor board's printed face is its thickness above the floor: lower the world by it.
    result = shift_world(result, np.eye(3), np.array([0.0, 0.0, scene.floor_height_m]))
    result.world_frame += f"; lowered by the board thickness {scene.floor_height_m * 1000:g} mm to the floor"
    return SceneCalibration(result, obs, "floor")


def aligned_to_truth(calibration: Calibration, truth: Calibration) -> Calibration:
    """``calibration`` moved rigidly onto ``truth`` (camera centres, Umeyama): for rigs without a world frame."""
    R, t, _ = align_worlds(calibration, truth, "rigid")
    R_cw, t_cw = transform_cameras(np.stack([c.R for c in calibration]), np.stack([c.t for c in calibration]), R, t)
    return Calibration(tuple(c.replace(R=R_cw[i], t=t_cw[i]) for i, c in enumerate(calibration)))


# ---------------------------------------------------------------------- residuals
def board_residuals(cal: SceneCalibration) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Per camera: detected corner positions ``(n, 2)`` px and their residuals (detected - reprojected) ``(n, 2)``, views used."""
    res, obs = cal.result, cal.observations
    obj = board_object_points(obs.board)
    out = {}
    for c, name in enumerate(obs.camera_names):
        cam = res.calibration[name]
        used = set(res.views_used.get(name, []))
        pos, err = [], []
        for v, label in enumerate(obs.view_labels[c]):
            T = res.board_poses_world[v]
            if label not in used or not np.isfinite(T).all():
                continue
            seen = np.isfinite(obs.corners_px[c, v]).all(axis=1)
            proj = cam.project(obj[seen] @ T[:3, :3].T + T[:3, 3])
            pos.append(obs.corners_px[c, v, seen])
            err.append(obs.corners_px[c, v, seen] - proj)
        out[name] = (np.concatenate(pos) if pos else np.zeros((0, 2)), np.concatenate(err) if err else np.zeros((0, 2)))
    return out


def wand_residuals(cal: SceneCalibration, scene: CalibrationScene) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Per camera: labelled wand blobs ``(n, 2)`` px and their residuals against the adjusted wand points."""
    pts = cal.result.wand_points_world
    out = {}
    for c, name in enumerate(scene.camera_names):
        if pts is None or scene.wand_markers_px is None:
            out[name] = (np.zeros((0, 2)), np.zeros((0, 2)))
            continue
        seen = scene.wand_markers_px[c].reshape(-1, 2)
        proj = cal.result.calibration[name].project(pts.reshape(-1, 3))
        ok = np.isfinite(seen).all(axis=1) & np.isfinite(proj).all(axis=1)
        out[name] = (seen[ok], seen[ok] - proj[ok])
    return out


def _rms(err: np.ndarray) -> float:
    e = np.asarray(err).reshape(-1, 2)
    e = e[np.isfinite(e).all(axis=1)]
    return float(np.sqrt(np.mean(np.sum(e ** 2, axis=1)))) if len(e) else float("nan")


# ---------------------------------------------------------------------- scoring
def score_calibration(cal: SceneCalibration, scene: CalibrationScene) -> tuple[dict[str, float], dict, dict | None]:
    """``calib.*`` metrics (module doc), the rigid-aligned scores and the unaligned (floor-frame) scores."""
    res = cal.result
    rigid = compare_calibrations(res.calibration, scene.truth, align="rigid", reprojection_rms_px=res.reprojection_rms_px)
    floor = compare_calibrations(res.calibration, scene.truth, align="none") if cal.world == "floor" else None
    s = rigid["summary"]
    m: dict[str, float] = {f"calib.{k}": s[k] for k in (
        "focal_error_pct", "principal_point_error_px", "distortion_error_px", "projection_error_max_px",
        "rotation_error_deg", "translation_error_mm", "reprojection_rms_px")}
    if floor is not None:
        m["calib.floor_frame_rotation_error_deg"] = floor["summary"]["rotation_error_deg"]
        m["calib.floor_frame_translation_error_mm"] = floor["summary"]["translation_error_mm"]
    # What the calibration was fed, against the exact projections.
    obs = cal.observations
    m["calib.corner_error_rms_px"] = _rms(obs.corners_px - scene.board_corners_true())
    if scene.wand_markers_px is not None:
        m["calib.wand_centroid_error_rms_px"] = _rms(scene.wand_markers_px - scene.wand_true_px)
        labelled = np.isfinite(scene.wand_markers_px).all(axis=(2, 3))
        m["calib.wand_frames_labelled_fraction"] = float(labelled.mean())
    if res.wand_distance_rms_mm is not None:
        m["calib.wand_distance_rms_mm"] = float(res.wand_distance_rms_mm)
    m["calib.board_views_min"] = int(min(len(v) for v in res.views_used.values()))
    # 0: the estimate is used in the floor board's world as is; 1: rigidly aligned to the truth.
    m["calib.world_aligned_to_truth"] = 0 if cal.world == "floor" else 1
    m["calib.cameras"] = len(scene.truth)
    return m, rigid, floor


# ---------------------------------------------------------------------- report
def plot_residuals(board: dict[str, tuple[np.ndarray, np.ndarray]], wand: dict[str, tuple[np.ndarray, np.ndarray]],
                   image_size: tuple[int, int], path: Path) -> None:
    """Per camera: residual vectors over the image (magnified) and the residual scatter (px)."""
    names = list(board)
    C = len(names)
    # matplotlib here, not at the top: every run imports this module, and a run that writes no
    # report (a sweep's or a check's) would pay its import (about 1 CPU-s on a busy 2-core machine)
    from matplotlib.figure import Figure

    fig = Figure(figsize=(3.6 * C, 6.4))
    axes = fig.subplots(2, C, squeeze=False)
    allerr = np.concatenate([board[n][1] for n in names] + [wand[n][1] for n in names if n in wand])
    lim = max(0.3, float(np.nanpercentile(np.abs(allerr), 99.5)) * 1.1) if len(allerr) else 1.0
    scale = 0.08 * image_size[0] / lim  # a residual of `lim` px draws 8 % of the image width
    w, h = image_size
    for i, n in enumerate(names):
        ax = axes[0, i]
        pos, err = board[n]
        if len(pos):
            ax.quiver(pos[:, 0], pos[:, 1], err[:, 0] * scale, err[:, 1] * scale, angles="xy", scale_units="xy",
                      scale=1.0, width=0.004, color="tab:blue")
        wp, we = wand.get(n, (np.zeros((0, 2)), np.zeros((0, 2))))
        if len(wp):
            ax.quiver(wp[:, 0], wp[:, 1], we[:, 0] * scale, we[:, 1] * scale, angles="xy", scale_units="xy",
                      scale=1.0, width=0.004, color="tab:orange")
        ax.set_xlim(0, w)
        ax.set_ylim(h, 0)
        ax.set_aspect("equal")
        ax.set_title(f"{n}: residuals x{scale:.0f}", fontsize=9)
        ax.tick_params(labelsize=7)
        ax = axes[1, i]
        ax.scatter(err[:, 0], err[:, 1], s=2, alpha=0.4, color="tab:blue", label=f"board corners (rms {_rms(err):.3f})")
        if len(we):
            ax.scatter(we[:, 0], we[:, 1], s=4, alpha=0.6, color="tab:orange", label=f"wand markers (rms {_rms(we):.3f})")
        ax.set_xlim(-lim, lim)
        ax.set_ylim(lim, -lim)
        ax.set_aspect("equal")
        ax.axhline(0, color="0.6", lw=0.5)
        ax.axvline(0, color="0.6", lw=0.5)
        ax.set_xlabel("dx (px)", fontsize=8)
        ax.set_ylabel("dy (px)", fontsize=8)
        ax.legend(fontsize=6, loc="upper right")
        ax.tick_params(labelsize=7)
    fig.suptitle("Calibration reprojection residuals (detected - reprojected): board corners (blue), wand (orange)", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=100)


def board_view_sheet(scene: CalibrationScene, path: Path, n_views: int = 3) -> None:
    """A few board pictures of every camera side by side (half size), floor view first."""
    V = scene.board_images.shape[0]
    views = sorted(set(np.linspace(0, V - 1, min(n_views, V)).round().astype(int)))
    rows = [np.concatenate([cv2.resize(scene.board_images[v, c], None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA)
                            for c in range(len(scene.truth))], axis=1) for v in views]
    cv2.imwrite(str(path), np.concatenate(rows, axis=0))


def per_camera_table(cal: SceneCalibration, rigid: dict, floor: dict | None,
                     board_res: dict, wand_res: dict, corner_err: dict[str, float]) -> list[str]:
    """Markdown table: one row per camera."""
    head = ("| camera | fx err % | pp err px | dist err px | rot err deg | trans err mm | "
            + ("floor-frame rot deg | floor-frame trans mm | " if floor is not None else "")
            + "reproj RMS px | board RMS px | wand RMS px | views | corner vs exact px |")
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    res = cal.result
    for n, s in rigid["per_camera"].items():
        row = (f"| {n} | {s['focal_error_pct']:.3f} | {s['principal_point_error_px']:.2f} | {s['distortion_error_px']:.2f} "
               f"| {s['rotation_error_deg']:.4f} | {s['translation_error_mm']:.2f} | ")
        if floor is not None:
            f = floor["per_camera"][n]
            row += f"{f['rotation_error_deg']:.4f} | {f['translation_error_mm']:.2f} | "
        row += (f"{s.get('reprojection_rms_px', float('nan')):.3f} | {_rms(board_res[n][1]):.3f} | {_rms(wand_res[n][1]):.3f} "
                f"| {len(res.views_used.get(n, []))} | {corner_err[n]:.3f} |")
        lines.append(row)
    return lines


def report_section(scene: CalibrationScene, cal: SceneCalibration, metrics: dict[str, float], rigid: dict,
                   floor: dict | None, plots: dict[str, str], seconds: float, board_res: dict, wand_res: dict) -> list[str]:
    obs = cal.observations
    true_corners = scene.board_corners_true()
    corner_err = {n: _rms(obs.corners_px[c] - true_corners[c]) for c, n in enumerate(obs.camera_names)}
    V = scene.board_images.shape[0]
    lines = ["## Camera calibration", "",
             f"`mocap calibrate` on the rendered calibration session: {V} board pictures per camera "
             f"({scene.board.describe()}"
             + (", view 0 lying on the floor at the world origin" if scene.board_poses.floor_view is not None else "")
             + ")"
             + (f" and {scene.wand_points.shape[0]} IR frames of a {scene.wand.distances_m[0] * 1000:g}+"
                f"{scene.wand.distances_m[1] * 1000:g} mm wand" if scene.wand is not None else "")
             + f"; {seconds:.1f} s (render, detection, calibration).", "",
             f"World frame: {cal.result.world_frame}. "
             + ("The estimate is used as is (no alignment to the truth)." if cal.world == "floor" else
                "No floor view: the estimate handed to the marker pipeline is rigidly aligned to the true cameras."), "",
             "Errors per camera. Intrinsics need no alignment; `rot`/`trans` are after a rigid alignment of the "
             "estimated camera centres onto the true ones"
             + ("; `floor-frame` columns use no alignment at all (the world from the floor board)." if floor is not None else ".")
             + " `reproj RMS` is the calibration's own final RMS; `board`/`wand RMS` split it; `corner vs exact` is "
             "the detected corners against their exact projections. The `calib.*` metrics are the worst camera.", ""]
    lines += per_camera_table(cal, rigid, floor, board_res, wand_res, corner_err)
    ba = cal.result.bundle_adjustment
    if ba:
        lines += ["", f"Bundle adjustment: {ba.get('evaluations')} evaluations, cost {ba.get('initial_cost', 0):.4g} -> "
                      f"{ba.get('cost', 0):.4g} ({ba.get('message', '')})."]
    if cal.result.wand_distance_rms_mm is not None:
        lines += ["", f"Wand distance RMS after adjustment: {cal.result.wand_distance_rms_mm:.3f} mm."]
    rejected = {n: r for n, r in cal.result.views_rejected.items() if r}
    if rejected:
        lines += ["", "Views not used (a board facing other cameras is seen from behind or edge-on): "
                  + "; ".join(f"{n} {len(r)}" for n, r in rejected.items()) + "."]
    for title, rel in plots.items():
        lines += ["", f"![{title}]({rel})"]
    return lines + [""]


def write_cli_inputs(scene: CalibrationScene, folder: Path) -> list[str]:
    """Write the pictures (``pictures/<camera>/view_NNN.png``) and wand blobs (``wand_blobs.npz``) for ``mocap calibrate``.

    Returns report lines with the command that calibrates from them (the same steps as
    :func:`calibrate_scene`, from files; without the floor board's thickness correction).
    """
    folders = scene.write_images(folder / "pictures")
    cmd = ["mocap calibrate", *[f"{n}={p.relative_to(folder.parent)}" for n, p in folders.items()],
           f"--board {scene.board.kind}",
           f"--board-size {scene.board.size[0]}x{scene.board.size[1]} --square-mm {scene.board.square_length_m * 1000:g}"]
    if scene.board.kind == "charuco":
        cmd.append(f"--marker-mm {scene.board.marker_length_m * 1000:g} --board-dictionary {scene.board.dictionary}")
    if scene.wand is not None and scene.wand_blobs_px is not None:
        np.savez(folder / "wand_blobs.npz", blobs_px=scene.wand_blobs_px, camera_names=np.array(scene.camera_names))
        d01, d12, _ = scene.wand.distances_m
        cmd.append(f"--wand-file {(folder / 'wand_blobs.npz').relative_to(folder.parent)} "
                   f"--wand-distances-mm {d01 * 1000:g},{d12 * 1000:g}")
    if scene.board_poses.floor_view is not None:
        cmd.append(f"--floor-view view_{scene.board_poses.floor_view:03d}.png")
    cmd.append("--out calibration/mocap_calibrate")
    return ["The same calibration from files, in this folder (the pictures and the wand's unlabelled blobs are saved):",
            "", "```", " \\\n    ".join(cmd), "```", ""]


# ---------------------------------------------------------------------- entry point
def run_calibration(bench_or_scenario, out_dir: str | Path | None = None,
                    rng: np.random.Generator | None = None) -> tuple[dict[str, float], list[str], Calibration]:
    """Render, calibrate and score the calibration session of a scenario.

    Parameters
    ----------
    bench_or_scenario : simbench.stage.stage.Stage or Scenario
        With a ``[calibration_scene]``. A bench lends its cameras and lights.
    out_dir : path, optional
        Writes ``calibration/estimated.{toml,yml,report.json}``, ``calibration/truth.yml``,
        ``calibration/views.png``, the pictures and wand blobs for ``mocap calibrate``
        (``calibration/pictures/<camera>/``, ``calibration/wand_blobs.npz``) and
        ``plots/calibration_residuals.png`` there (report lines link them).
    rng : numpy.random.Generator, optional
        Default: seeded from the scenario's seed.

    Returns
    -------
    metrics : dict
        ``calib.*`` (module doc).
    report_lines : list of str
        A Markdown section (per-camera table, residual plots).
    calibration : Calibration
        The estimate in the true world frame: the floor board's (no alignment), or,
        without a floor view, rigidly aligned to the truth.
    """
    t0 = time.perf_counter()
    if isinstance(bench_or_scenario, Scenario):
        scenario, cameras, lighting = bench_or_scenario, None, None
    else:
        scenario, cameras, lighting = bench_or_scenario.scenario, bench_or_scenario.cameras, bench_or_scenario.lighting
    rng = rng if rng is not None else np.random.default_rng(np.random.SeedSequence([scenario.seed, 0xCA11B]))
    scene = render_calibration_scene(scenario, rng, cameras, lighting)
    cal = calibrate_scene(scene)
    metrics, rigid, floor = score_calibration(cal, scene)
    board_res = board_residuals(cal)
    wand_res = wand_residuals(cal, scene)
    seconds = time.perf_counter() - t0
    plots: dict[str, str] = {}
    if out_dir is not None:
        out = Path(out_dir)
        (out / "calibration").mkdir(parents=True, exist_ok=True)
        (out / "plots").mkdir(parents=True, exist_ok=True)
        write_calibration(cal.result, out / "calibration" / "estimated")
        scene.truth.save_opencv_yaml(out / "calibration" / "truth.yml")
        cli_lines = write_cli_inputs(scene, out / "calibration")
        plot_residuals(board_res, wand_res, scene.truth[0].size, out / "plots" / "calibration_residuals.png")
        board_view_sheet(scene, out / "calibration" / "views.png")
        plots = {"calibration residuals": "plots/calibration_residuals.png", "board pictures": "calibration/views.png"}
    lines = report_section(scene, cal, metrics, rigid, floor, plots, seconds, board_res, wand_res)
    if out_dir is not None:
        lines += cli_lines
    estimate = cal.result.calibration if cal.world == "floor" else aligned_to_truth(cal.result.calibration, scene.truth)
    return metrics, lines, estimate
