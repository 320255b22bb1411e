"""Score colour-shirt poses against the ground truth of a `simbench run` or `simbench render` folder.

    python scripts/score_shirt.py RUN_DIR POSES.npz [POSES.npz ...]

Input: the folder's ``ground_truth/`` and ``poses.npz`` files with the upper body's joint centres:
what `mocap shirt` writes (``joint_centres_m``), or a run's own ``shirt/poses.npz``
(``full_joint_centres_m`` and ``baseline_joint_centres_m``). Output, one line per method: the joint
RMSE (cm) over the upper-body joints and all frames, and the fraction of frames whose elbows and
wrists are all within 5 cm (eval.shirt_metrics, as `simbench run` scores them).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from eval.shirt_metrics import frames_within_cm, rmse_cm
from mocap.shirt.kinematics import UPPER_BODY_JOINTS
from simbench.stage.ground_truth import load_ground_truth

KEYS = ("joint_centres_m", "full_joint_centres_m", "baseline_joint_centres_m")


def score(run_dir: Path, poses: Path) -> list[str]:
    """One line of figures per method in ``poses`` against ``run_dir``'s ground truth."""
    gt = load_ground_truth(run_dir)
    true = gt.joint_centres[:, [gt.joint_names.index(b) for b in UPPER_BODY_JOINTS]]
    data = np.load(poses)
    lines = []
    for key in KEYS:
        if key in data:
            est = data[key]
            lines.append(f"{poses} {key}: joint RMSE {rmse_cm(est, true):.2f} cm, "
                         f"arms within 5 cm on {frames_within_cm(est, true, UPPER_BODY_JOINTS):.3f} of the frames")
    return lines or [f"{poses}: none of {', '.join(KEYS)}"]


def main(argv: list[str]) -> int:
    if len(argv) < 2:
        print(__doc__.strip().splitlines()[2].strip(), file=sys.stderr)
        return 2
    for name in argv[1:]:
        print("\n".join(score(Path(argv[0]), Path(name))))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
