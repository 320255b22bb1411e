"""Reading the bench's inputs folder and writing results, for the adapter scripts.

These scripts run in the third-party tools' own environments (``.venv-aniposelib``,
``.venv-pose2sim``), where simbench is not installed: they use only the standard library
and numpy, and talk to the bench through files (``simbench export-inputs``' layout)."""

from __future__ import annotations

import csv
import json
import time
from pathlib import Path

import numpy as np


def read_inputs(folder: Path) -> tuple[dict, np.ndarray, np.ndarray]:
    """``inputs.json``, labelled 2D points ``(F, C, M, 2)`` px (NaN: none), confidence ``(F, C, M)``."""
    man = json.loads((folder / "inputs.json").read_text())
    F, cams, markers = man["n_frames"], man["cameras"], man["markers"]
    ci, mi = {n: i for i, n in enumerate(cams)}, {n: i for i, n in enumerate(markers)}
    pts = np.full((F, len(cams), len(markers), 2), np.nan)
    conf = np.zeros((F, len(cams), len(markers)))
    with (folder / "detections_2d.csv").open(newline="") as fh:
        for row in csv.DictReader(fh):
            f, c, m = int(row["frame"]), ci[row["camera"]], mi[row["marker"]]
            pts[f, c, m] = float(row["x_px"]), float(row["y_px"])
            conf[f, c, m] = float(row["confidence"])
    return man, pts, conf


def write_points_csv(path: Path, labels: list[str], times: list[float], xyz_m: np.ndarray) -> None:
    """The bench's CSV (``mocap.exports.write_csv``'s columns): frame, time_s, <label>_{x,y,z}_mm; world Z up."""
    with path.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["frame", "time_s"] + [f"{n}_{a}_mm" for n in labels for a in "xyz"])
        for f, row in enumerate(np.asarray(xyz_m, dtype=np.float64) * 1000.0):
            w.writerow([f, f"{times[f]:.9f}"] + ["" if not np.isfinite(v) else f"{v:.6f}" for v in row.ravel()])


class Timer:
    """Wall time of named steps, written to ``timings.json`` (seconds)."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = {}

    def run(self, name: str, fn, *args, **kwargs):
        t0 = time.perf_counter()
        out = fn(*args, **kwargs)
        self.seconds[name] = time.perf_counter() - t0
        return out

    def write(self, folder: Path, extra: dict | None = None) -> None:
        (folder / "timings.json").write_text(json.dumps({"seconds": self.seconds, **(extra or {})}, indent=1) + "\n")
