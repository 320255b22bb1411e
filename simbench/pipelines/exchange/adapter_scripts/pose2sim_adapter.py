"""Pose2Sim on the bench's inputs (run with .venv-pose2sim/bin/python; calls Pose2Sim's own functions).

Task:
  triangulate INPUTS OUT   the exported 2D detections (pose2sim-format inputs: calibration/Calib.toml),
                           per frame and marker through Pose2Sim.triangulation.triangulation_from_best_cameras
                           (its camera-exclusion triangulation), then its gap interpolation
                           (Pose2Sim.common.interpolate_zeros_nans) and large-gap filling as triangulate_all
                           does, then Pose2Sim.filtering.butterworth_filter_1d, with the settings of
                           Pose2Sim's demo Config.toml. Variants:
                             pose2sim           the defaults (fill_large_gaps_with = 'last_value')
                             pose2sim_gaps_nan  fill_large_gaps_with = 'nan' (documented setting)
                           OUT/<variant>.csv + OUT/timings.json. Pose2Sim's TRC axes (Y up) are not involved:
                           results stay in the calibration's Z-up world.
"""

from __future__ import annotations

import sys
from importlib import metadata
from pathlib import Path

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).parent))
from exchange_io import Timer, read_inputs, write_points_csv  # noqa: E402

from Pose2Sim.common import computeP, interpolate_zeros_nans, retrieve_calib_params  # noqa: E402
from Pose2Sim.filtering import butterworth_filter_1d  # noqa: E402
from Pose2Sim.triangulation import triangulation_from_best_cameras  # noqa: E402

# Pose2Sim's demo Config.toml ([triangulation], [filtering.butterworth])
CONFIG = {
    "triangulation": {"reproj_error_threshold_triangulation": 15, "likelihood_threshold_triangulation": 0.3,
                      "min_cameras_for_triangulation": 2, "undistort_points": False, "handle_LR_swap": False,
                      "interp_if_gap_smaller_than": 20, "interpolation": "linear", "fill_large_gaps_with": "last_value"},
    "filtering": {"type": "butterworth", "butterworth": {"order": 4, "cut_off_frequency": 6}},
}


def _triangulate(pts: np.ndarray, conf: np.ndarray, P, calib_params) -> np.ndarray:
    F, C, M, _ = pts.shape
    thr = CONFIG["triangulation"]["likelihood_threshold_triangulation"]
    out = np.full((F, M, 3), np.nan)
    for f in range(F):
        for m in range(M):
            x, y, lk = pts[f, :, m, 0].copy(), pts[f, :, m, 1].copy(), conf[f, :, m].copy()
            bad = ~(lk >= thr) | ~np.isfinite(x)  # as triangulate_all: below the likelihood threshold -> NaN
            x[bad], y[bad], lk[bad] = np.nan, np.nan, np.nan
            Q, _, _, _ = triangulation_from_best_cameras(CONFIG, (x, y, lk), (x, y, lk), P, calib_params)
            out[f, m] = Q
    return out


def _gaps_and_filter(xyz: np.ndarray, fps: float, fill: str) -> np.ndarray:
    """triangulate_all's interpolation and gap filling, then filter_all's Butterworth, on (F, M, 3)."""
    F, M, _ = xyz.shape
    q = pd.DataFrame(xyz.reshape(F, 3 * M))
    tri = CONFIG["triangulation"]
    q = q.apply(interpolate_zeros_nans, axis=0, args=[tri["interp_if_gap_smaller_than"], tri["interpolation"]])
    if fill == "last_value":
        q = q.ffill(axis=0).bfill(axis=0)
        q = q.replace([np.nan, np.inf], 0)
    q = q.apply(lambda col: butterworth_filter_1d(CONFIG, fps, col), axis=0)
    xyz = q.to_numpy(dtype=np.float64, copy=True).reshape(F, M, 3)
    if fill == "nan":
        xyz[(xyz == 0).all(axis=-1)] = np.nan
    return xyz


def triangulate(inputs: Path, out: Path) -> None:
    man, pts, conf = read_inputs(inputs)
    calib = inputs / man["calibration"][0]  # a Path: rtoml.load parses a str as TOML text
    P = computeP(calib, undistort=CONFIG["triangulation"]["undistort_points"])
    calib_params = retrieve_calib_params(calib)
    timer = Timer()
    raw = timer.run("triangulation_from_best_cameras", _triangulate, pts, conf, P, calib_params)
    for name, fill in (("pose2sim", "last_value"), ("pose2sim_gaps_nan", "nan")):
        xyz = timer.run(f"{name} gaps+filter", _gaps_and_filter, raw.copy(), float(man["fps"]), fill)
        write_points_csv(out / f"{name}.csv", man["markers"], man["times_s"], xyz)
    timer.write(out, {"frames": man["n_frames"], "version": metadata.version("pose2sim"), "config": CONFIG})


if __name__ == "__main__":
    task, inputs, out = sys.argv[1], Path(sys.argv[2]), Path(sys.argv[3])
    out.mkdir(parents=True, exist_ok=True)
    {"triangulate": triangulate}[task](inputs, out)
