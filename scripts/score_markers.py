"""Score a capture file against the ground truth of a `simbench run` or `simbench render` folder.

    python scripts/score_markers.py RUN_DIR CAPTURE.c3d [CAPTURE.trc ...]

Input: the folder's ``ground_truth/`` (its markers' true positions) and one or more capture files
(C3D, TRC or the pipeline's CSV) labelled with the same marker names, e.g. what `mocap markers`
wrote from the folder's videos. Output, one line per file: the fraction of all true points
reconstructed, the RMSE (mm), the points more than 20 mm off (mislabels) and the label swaps
(eval.marker_metrics). Markers the capture lacks count as not reconstructed.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from eval.marker_metrics import label_swaps, marker_errors_m
from mocap.errors import InputFileError
from simbench.pipelines.exchange.results import read_results
from simbench.stage.ground_truth import load_ground_truth


def score(run_dir: Path, capture: Path) -> str:
    """One line of figures for ``capture`` against ``run_dir``'s ground truth."""
    gt = load_ground_truth(run_dir)
    traj = read_results(capture)  # by suffix (mocap.exports.read_capture)
    if len(traj.xyz) != gt.n_frames:  # one row per frame of the folder's videos: another take is refused, not matched by time
        raise InputFileError(capture, f"{len(traj.xyz)} frames against the {gt.n_frames} of {run_dir}'s ground truth",
                             "score a capture of that folder's videos")
    xyz = traj.xyz
    est = np.full_like(gt.markers_3d, np.nan)
    for m, name in enumerate(gt.marker_names):
        if name in traj.labels:
            est[:, m] = xyz[:, list(traj.labels).index(name)]
    err_mm = marker_errors_m(est, gt.markers_3d) * 1e3
    seen = np.isfinite(err_mm)
    rmse = float(np.sqrt(np.mean(err_mm[seen] ** 2))) if seen.any() else float("nan")
    return (f"{capture}: reconstructed {seen.mean():.3f}, RMSE {rmse:.2f} mm, "
            f"{int((err_mm[seen] > 20).sum())} of {int(seen.sum())} points > 20 mm off, "
            f"{label_swaps(est, gt.markers_3d)} label swaps")


def main(argv: list[str]) -> int:
    if len(argv) < 2:
        print(__doc__.strip().splitlines()[2].strip(), file=sys.stderr)
        return 2
    run_dir = Path(argv[0])
    for name in argv[1:]:
        try:
            print(score(run_dir, Path(name)))
        except InputFileError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
