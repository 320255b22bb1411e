#!/usr/bin/env python
"""A stand-in for a user's own capture system, run by the bench as a scenario's command
(``[pipeline] kind = "command"``, see scenarios/external_command.toml).

It reads only what ``simbench export-inputs --format opencv`` writes (inputs.json, the OpenCV
calibration, detections_2d.csv) and triangulates each labelled marker by plain linear DLT
over every camera that saw it (undistorted with OpenCV), then writes an OpenSim TRC (mm, Y up:
``(x, z, -y)`` of the bench's Z-up world) into the output folder. No filtering, no outlier
rejection, no gap filling: a baseline a real system should beat.

``--noise-px S`` adds Gaussian noise of S px to every 2D detection first (seeded by ``--seed``):
the deliberately worse version that ``simbench check --suite external`` must catch.

Usage: python examples/external_pipeline.py INPUTS OUTPUT [--noise-px S] [--seed N]
"""

from __future__ import annotations

import argparse
import csv
import json
from pathlib import Path

import cv2
import numpy as np


def read_calibration(path: Path) -> list[dict]:
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    cams = []
    for i in range(int(fs.getNode("camera_count").real())):
        cams.append({k: fs.getNode(f"camera_{i}_{k}").mat() for k in ("K", "dist", "R", "t")})
        cams[-1]["name"] = fs.getNode(f"camera_{i}_name").string()
    fs.release()
    return cams


def triangulate(P: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Linear DLT: ``P (n, 3, 4)``, undistorted ``uv (n, 2)`` -> point (3,)."""
    A = np.concatenate([uv[:, :1] * P[:, 2] - P[:, 0], uv[:, 1:] * P[:, 2] - P[:, 1]])
    X = np.linalg.svd(A)[2][-1]
    return X[:3] / X[3]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("inputs", type=Path)
    ap.add_argument("output", type=Path)
    ap.add_argument("--noise-px", type=float, default=0.0)
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args()
    man = json.loads((a.inputs / "inputs.json").read_text())
    cams = read_calibration(a.inputs / man["calibration"][0])
    names, markers, F = [c["name"] for c in cams], man["markers"], man["n_frames"]
    uv = np.full((F, len(cams), len(markers), 2), np.nan)
    with (a.inputs / "detections_2d.csv").open() as fh:
        for row in csv.DictReader(fh):
            uv[int(row["frame"]), names.index(row["camera"]), markers.index(row["marker"])] = float(row["x_px"]), float(row["y_px"])
    if a.noise_px > 0:
        uv += np.random.default_rng(a.seed).normal(0.0, a.noise_px, uv.shape)
    und = np.full_like(uv, np.nan)
    for c, cam in enumerate(cams):
        flat = uv[:, c].reshape(-1, 2)
        ok = np.isfinite(flat).all(axis=1)
        out = np.full_like(flat, np.nan)
        if ok.any():
            out[ok] = cv2.undistortPoints(flat[ok].reshape(-1, 1, 2), cam["K"], cam["dist"], P=cam["K"]).reshape(-1, 2)
        und[:, c] = out.reshape(F, len(markers), 2)
    P = np.stack([c["K"] @ np.hstack([c["R"], c["t"].reshape(3, 1)]) for c in cams])
    xyz = np.full((F, len(markers), 3), np.nan)
    for f in range(F):
        for m in range(len(markers)):
            seen = np.isfinite(und[f, :, m, 0])
            if seen.sum() >= 2:
                xyz[f, m] = triangulate(P[seen], und[f, seen, m])
    a.output.mkdir(parents=True, exist_ok=True)
    ys = xyz[..., [0, 2, 1]] * [1.0, 1.0, -1.0] * 1000.0  # world Z up, m -> OpenSim Y up, mm
    rate = man["fps"]
    lines = ["PathFileType\t4\t(X/Y/Z)\tmarkers.trc",
             "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\tOrigDataStartFrame\tOrigNumFrames",
             f"{rate}\t{rate}\t{F}\t{len(markers)}\tmm\t{rate}\t1\t{F}",
             "Frame#\tTime\t" + "\t\t\t".join(markers),
             "\t\t" + "\t".join(f"{x}{i + 1}" for i in range(len(markers)) for x in "XYZ"), ""]
    for f in range(F):
        vals = ["" if not np.isfinite(v) else f"{v:.6f}" for v in ys[f].ravel()]
        lines.append("\t".join([str(f + 1), f"{man['times_s'][f]:.6f}", *vals]))
    (a.output / "markers.trc").write_text("\n".join(lines) + "\n")
    print(f"triangulated {np.isfinite(xyz[..., 0]).sum()} marker-frames of {F * len(markers)}")


if __name__ == "__main__":
    main()
