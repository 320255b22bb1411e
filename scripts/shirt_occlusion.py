"""Where a shirt scenario's arms are hidden, and how both methods fare there (issue 18's office point).

Seed 001 says the baseline does about as well as the full method on simple sequences without
occlusions. This script measures how far a shirt scenario is from that: for every frame, from
the true pose alone, whether an arm patch (an upper arm below the shoulder, or a forearm) is
hidden from a camera by the rest of the body, and then the joint RMSE of the full method and
the baseline over the *plain* frames (no arm patch hidden within ``--margin`` frames: a tracker
that lost an arm behind the body needs some frames to find it again) and over the others.

Per seed it renders the take (frames and id maps kept: a short scenario), starts the shirt
session as ``simbench run`` does, tracks both methods and prints a row; then a summary.

A patch is *hidden* in a frame when, in some camera, at most ``--hidden`` (0.1) of the pixels
it covers drawn alone are its own in the render of the whole body (the body's z-buffer at
160 px across the image; back faces culled in both, so a patch never hides itself), among
patches covering at least 8 such pixels.

Example::

    .venv/bin/python scripts/shirt_occlusion.py scenarios/shirt_office.toml --seeds 31,38
    .venv/bin/python scripts/shirt_occlusion.py scenarios/shirt_office.toml --seeds 1-10 --set motion.clip=wave_slow
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from _one_line_errors import run_main  # noqa: E402
from mocap.shirt.kinematics import UPPER_BODY_JOINTS  # noqa: E402
from mocap.shirt.pipeline import ShirtPipelineParams  # noqa: E402
from mocap.shirt.shirt_model import CropView, ShirtModel  # noqa: E402
from mocap.shirt.zbuffer import rasterise_faces  # noqa: E402
from simbench.pipelines.shirt import start_session, track_sequence  # noqa: E402
from simbench.render.gl_context import configure_gl_environment  # noqa: E402
from simbench.scenario.loading import load_scenario, parse_overrides  # noqa: E402
from simbench.stage.build import build_stage  # noqa: E402
from simbench.stage.rendering import render_frames  # noqa: E402

ARM_PATCH_BODIES = ("upperarm_l", "upperarm_r", "forearm_l", "forearm_r")
"""The arm patches looked at: those wholly on one of these bodies (the shoulder patches also cover the thorax)."""
_WIDTH = 160  # working pixels across the image


def arm_patches(model: ShirtModel) -> list[int]:
    """The patches whose faces all lie on one of :data:`ARM_PATCH_BODIES`."""
    names = model.geometry.body_names
    out = []
    for p in range(model.n_patches):
        bodies = {names[b] for b in np.unique(model.face_body[model.face_patch == p])}
        if len(bodies) == 1 and bodies <= set(ARM_PATCH_BODIES):
            out.append(p)
    return out


def least_visible_arm_patch(model: ShirtModel, q: np.ndarray, cameras: list) -> np.ndarray:
    """``(F,)`` per frame of ``q (F, 18)``: the smallest visible share of an arm patch over the cameras."""
    patches = arm_patches(model)
    W, H = cameras[0].size
    view = CropView(0.0, (H - W) / 2.0, W / _WIDTH, _WIDTH)  # the whole image, square, 160 px across
    share = np.ones(len(q))
    for k, qk in enumerate(q):
        P = model.world_vertices(qk)
        for cam in cameras:
            uv, z = model._project(P, cam, view)
            whole = rasterise_faces(uv, z, model.faces, _WIDTH, _WIDTH)
            seen = np.where(whole >= 0, model.face_patch[np.maximum(whole, 0)], -1)
            for p in patches:
                alone = int((rasterise_faces(uv, z, model.faces[model.face_patch == p], _WIDTH, _WIDTH) >= 0).sum())
                if alone >= 8:
                    share[k] = min(share[k], float((seen == p).sum()) / alone)
    return share


def _rmse(err_cm2: np.ndarray, rows: np.ndarray) -> float:
    return float(np.sqrt(err_cm2[rows].mean())) if rows.any() else float("nan")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("scenario")
    ap.add_argument("--seeds", required=True, help="comma-separated seeds, or a range A-B")
    ap.add_argument("--hidden", type=float, default=0.1, help="visible share at or under which a patch is hidden")
    ap.add_argument("--margin", type=int, default=5, help="frames before and after a hidden one that are not plain")
    ap.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE", help="override a scenario field (TOML value)")
    a = ap.parse_args()
    if "-" in a.seeds:
        lo, hi = (int(x) for x in a.seeds.split("-"))
        seeds = list(range(lo, hi + 1))
    else:
        seeds = [int(x) for x in a.seeds.split(",")]
    overrides = parse_overrides(a.set)
    configure_gl_environment()
    print(f"{'seed':>4} {'hidden/near':>14} {'full':>6} {'base':>6} {'ratio':>6} | {'plain: full':>11} {'base':>6} {'ratio':>6} "
          f"| {'near: full':>12} {'base':>6} {'ratio':>6}")
    ratios = []
    for seed in seeds:
        stage = build_stage(load_scenario(a.scenario, {**overrides, "seed": seed}))
        seq = render_frames(stage, keep_frames=True, keep_ids=True)
        gt = seq.ground_truth
        session = start_session(stage, seq.frames, gt)
        model = ShirtModel(session.db.mjcf_text, session.db.geometry)
        hidden = least_visible_arm_patch(model, model.kin.from_full_qpos(gt.qpos), list(session.calibration)) <= a.hidden
        # frames within --margin of a hidden one (a dilation of the hidden frames along time)
        near = np.convolve(hidden.astype(float), np.ones(2 * a.margin + 1), mode="same") > 0
        true_j = gt.joint_centres[:, [gt.joint_names.index(b) for b in UPPER_BODY_JOINTS]]
        row = {}
        for name, params in (("full", ShirtPipelineParams()), ("base", ShirtPipelineParams().baseline())):
            q = track_sequence(session.tracker(params), seq.frames).q
            err_cm2 = np.sum((model.kin.joint_centres(q) - true_j) ** 2, axis=-1) * 1e4  # (F, J)
            row[name] = [_rmse(err_cm2, np.ones(len(q), bool)), _rmse(err_cm2, ~near), _rmse(err_cm2, near)]
        f, b = np.array(row["full"]), np.array(row["base"])
        ratios.append(b / f)
        print(f"{seed:>4} {int(hidden.sum()):>3}/{int(near.sum()):>3} of {len(hidden):<3} {f[0]:>6.2f} {b[0]:>6.2f} {b[0] / f[0]:>6.2f} | "
              f"{f[1]:>11.2f} {b[1]:>6.2f} {b[1] / f[1]:>6.2f} | {f[2]:>12.2f} {b[2]:>6.2f} {b[2] / f[2]:>6.2f}", flush=True)
    r = np.array(ratios)
    for i, what in enumerate(("all frames", "plain frames", "frames near a hidden arm")):
        has = np.isfinite(r[:, i])  # (a seed without such frames has no ratio there)
        if has.any():
            print(f"baseline / full over {what}: median {np.median(r[has, i]):.2f}, max {np.max(r[has, i]):.2f}, "
                  f"within 1.5x on {int((r[has, i] <= 1.5).sum())} of {int(has.sum())} seeds")
        else:
            print(f"baseline / full over {what}: no seed has such frames")


if __name__ == "__main__":
    run_main(main)
