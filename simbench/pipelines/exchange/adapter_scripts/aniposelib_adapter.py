"""aniposelib on the bench's inputs (run with .venv-aniposelib/bin/python; calls aniposelib's own code).

Tasks:
  triangulate INPUTS OUT   the exported 2D detections (anipose-format inputs: calibration/calibration.toml)
                           triangulated by CameraGroup.triangulate, .triangulate_ransac and .triangulate_optim,
                           each with aniposelib's defaults; OUT/<variant>.csv + OUT/timings.json
  calibrate INPUTS OUT     CameraGroup.calibrate_videos on the board videos (calibration_board/<camera>.mp4),
                           with aniposelib's Checkerboard/CharucoBoard from calibration_board/board.json;
                           OUT/calibration.toml (CameraGroup.dump) + OUT/timings.json
"""

from __future__ import annotations

import json
import sys
from importlib import metadata
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from exchange_io import Timer, read_inputs, write_points_csv  # noqa: E402

from aniposelib.boards import Checkerboard, CharucoBoard  # noqa: E402
from aniposelib.cameras import CameraGroup  # noqa: E402


def triangulate(inputs: Path, out: Path) -> None:
    man, pts, _ = read_inputs(inputs)
    cgroup = CameraGroup.load(str(inputs / man["calibration"][0]))
    F, C, M, _ = pts.shape
    p2d = np.transpose(pts, (1, 0, 2, 3))  # (C, F, M, 2), NaN where not seen: aniposelib's layout
    flat = p2d.reshape(C, F * M, 2)
    timer = Timer()
    variants = {
        "triangulate": lambda: timer.run("triangulate", cgroup.triangulate, flat, undistort=True, progress=False),
        "triangulate_ransac": lambda: timer.run("triangulate_ransac", cgroup.triangulate_ransac, flat, undistort=True,
                                                min_cams=2, progress=False)[0],
        "triangulate_optim": lambda: timer.run("triangulate_optim", cgroup.triangulate_optim, p2d),
    }
    cgroup.triangulate(flat, undistort=True)  # jax compiles for the shape at its first call: not counted as per-frame time
    failed = {}
    for name, fn in variants.items():
        try:
            xyz = np.asarray(fn()).reshape(F, M, 3)
        except Exception as exc:  # the tool's own failure is a finding: recorded, the other variants still run
            failed[name] = f"{type(exc).__name__}: {str(exc).strip().splitlines()[0] if str(exc).strip() else ''}"
            continue
        write_points_csv(out / f"{name}.csv", man["markers"], man["times_s"], xyz)
    timer.write(out, {"frames": F, "version": metadata.version("aniposelib"), "failed": failed})


def calibrate(inputs: Path, out: Path) -> None:
    man = json.loads((inputs / "inputs.json").read_text())
    b = man["calibration_board"]
    if b["kind"] == "checkerboard":
        board = Checkerboard(b["inner_corners"][0], b["inner_corners"][1], square_length=b["square_m"])  # inner corners
    else:
        board = CharucoBoard(b["squares"][0], b["squares"][1], square_length=b["square_m"], marker_length=b["marker_m"],
                             marker_bits=int(b["dictionary"].split("_")[1][0]), dict_size=int(b["dictionary"].split("_")[2]))
    cams = man["cameras"]
    cgroup = CameraGroup.from_names(cams, fisheye=False)
    videos = [[str(inputs / "calibration_board" / f"{c}.mp4")] for c in cams]
    timer = Timer()
    error, rows = timer.run("calibrate_videos", cgroup.calibrate_videos, videos, board, verbose=False)
    cgroup.dump(str(out / "calibration.toml"))
    timer.write(out, {"reprojection_error_px": float(error), "boards_detected": [len(r) for r in rows],
                      "version": metadata.version("aniposelib")})


if __name__ == "__main__":
    task, inputs, out = sys.argv[1], Path(sys.argv[2]), Path(sys.argv[3])
    out.mkdir(parents=True, exist_ok=True)
    {"triangulate": triangulate, "calibrate": calibrate}[task](inputs, out)
