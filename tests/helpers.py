"""What several test modules share besides fixtures (those are in ``conftest.py``): a marker's
blob centroid found through the exact id map, the settings of a tiny run for sweep files, a ring
of cameras around the subject, and marker sites by MuJoCo forward kinematics.

pytest puts ``tests/`` on ``sys.path`` (its default "prepend" import mode, no ``__init__.py``
here), so test modules import this as ``helpers``.
"""

from __future__ import annotations

import cv2
import mujoco
import numpy as np

from mocap.calibration import Calibration, calibration_from_arrays
from simbench.render import ids as idc

#: The ``[set]`` table of a tiny run of the quickstart in a sweep file: 2 cameras at 320x240,
#: 0.3 s (9 frames), no supersampling, no skeleton.
TINY_RUN_SET = """
[set]
"rig.count" = 2
"rig.width" = 320
"rig.height" = 240
duration_s = 0.3
"sensor.antialias" = 1
"markers_pipeline.solve_skeleton" = false
"""


def blob_centroid(image: np.ndarray, id_map: np.ndarray, marker: int) -> tuple[float, float] | None:
    """Intensity centroid ``(x, y)`` px of one marker's blob in a rendered frame (None: not
    drawn): its id-map pixels grown by one pixel (to take in the anti-aliased rim), minus
    pixels near other markers, weighted by the first channel above the local background
    (the median of the blob's box grown by 6 pixels)."""
    own = (id_map == idc.MARKER_BASE + marker).astype(np.uint8)
    if own.sum() == 0:
        return None
    grown = cv2.dilate(own, np.ones((3, 3), np.uint8)) > 0
    other = (id_map >= idc.MARKER_BASE) & (id_map != idc.MARKER_BASE + marker)
    mask = grown & ~cv2.dilate(other.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    grey = image[..., 0].astype(float)
    ys, xs = np.nonzero(mask)
    if len(xs) == 0:
        return None
    bg = np.median(grey[max(ys.min() - 6, 0): ys.max() + 7, max(xs.min() - 6, 0): xs.max() + 7])
    w = np.clip(grey[ys, xs] - bg, 0, None)
    if w.sum() <= 0:
        return None
    return float((w * xs).sum() / w.sum()), float((w * ys).sum() / w.sum())


def calibration_session(name: str, cameras: str, n_views: int, wand_frames: int, extra: str = "") -> str:
    """A calibration session's scenario text: no subject markers, IR frames (4 ms, no blur),
    the ``cameras`` given (a ``[rig]`` table or ``[[cameras]]`` tables), a 9x6 checkerboard of
    8 cm squares in ``n_views`` poses (12 ms exposures), then ``wand_frames`` wand frames;
    ``extra`` lines end the ``[calibration_scene]`` table."""
    return f"""
name = "{name}"
duration_s = 0.1
[subject]
markers = "none"
[sensor]
mode = "ir"
exposure_ms = 4.0
motion_blur = false
{cameras.strip()}
[calibration_scene]
board = "checkerboard"
board_cols = 9
board_rows = 6
square_m = 0.08
n_views = {n_views}
board_exposure_ms = 12.0
wand_frames = {wand_frames}
{extra}"""


def ring_calibration(n: int, radius_m: float, target_m: tuple[float, float, float], focal_px: float,
                     size: tuple[int, int], phase_rad: float) -> Calibration:
    """``n`` distortion-free cameras on a circle of ``radius_m`` at 2 m height, the first at
    ``phase_rad``, each looking at ``target_m`` with the image's x axis level."""
    Rs, ts = [], []
    target = np.asarray(target_m, float)
    for i in range(n):
        az = 2 * np.pi * i / n + phase_rad
        centre = np.array([radius_m * np.cos(az), radius_m * np.sin(az), 2.0])
        z = (target - centre) / np.linalg.norm(target - centre)
        x = np.cross(z, [0.0, 0.0, 1.0])
        x /= np.linalg.norm(x)
        R = np.stack([x, np.cross(z, x), z])
        Rs.append(R)
        ts.append(-R @ centre)
    K = np.array([[focal_px, 0, size[0] / 2], [0, focal_px, size[1] / 2], [0, 0, 1]])
    return calibration_from_arrays([f"cam{i}" for i in range(n)], size, [K] * n, [np.zeros(5)] * n, Rs, ts)


def site_positions(model: mujoco.MjModel, qpos: np.ndarray) -> np.ndarray:
    """World positions ``(F, nsite, 3)`` m of every site of ``model`` at each configuration ``qpos (F, nq)``."""
    data = mujoco.MjData(model)
    sites = np.zeros((len(qpos), model.nsite, 3))
    for f, q in enumerate(qpos):
        data.qpos[:] = q
        mujoco.mj_kinematics(model, data)
        sites[f] = data.site_xpos
    return sites
