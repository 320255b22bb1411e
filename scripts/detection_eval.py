"""Score the 2D marker detector of a scenario against the renderer's ground truth.

Renders the scenario once (cached as an ``.npz`` in ``--cache``, so that detector
changes can be measured again without rendering), runs
:func:`mocap.detection.detect_markers` on every camera image and prints:

* **recall**: visible markers (ground truth ``marker_visible``) with a detection within
  ``--match-px`` (1.5 px) of their projected centre;
* **false blobs per image**: detections farther than ``--false-px`` (3 px) from every
  marker that is at least partly visible, split by what the id map shows under the
  blob (body, set, clutter, background, a hidden marker's neighbourhood);
* **centroid error** (median, p95, px) of markers at least 90 % visible, and its mean
  vector (bias: markers lit from above are biased towards the top of the image);
* **time** per image of ``detect_markers``, and of ``cv2.connectedComponentsWithStats``
  alone on the same images thresholded at a fixed level, as a reference.

``--crops DIR`` writes PNG crops (x3) around false blobs and missed markers with the
detections (green), visible truth (blue) and missed truth (red) drawn.

Examples::

    .venv/bin/python scripts/detection_eval.py scenarios/visible_office.toml
    .venv/bin/python scripts/detection_eval.py scenarios/visible_office.toml --set lighting.preset=tungsten_lamp
"""

from __future__ import annotations

import argparse
import hashlib
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import cv2
import numpy as np
from scipy.spatial import cKDTree

from mocap.detection import DetectionParams, detect_markers
from mocap.types import Detections
from simbench.stage.build import build_stage
from simbench.scenario import parse_overrides
from simbench.render.ids import BACKGROUND, BODY, CLUTTER, MARKER_BASE, SET
from simbench.stage.rendering import render_frames
from simbench.scenario import load_scenario


@dataclass(frozen=True)
class Rendered:
    """One scenario's frames and the ground truth the score needs."""

    frames: np.ndarray        # (F, C, H, W, 3) uint8 RGB
    ids: np.ndarray           # (F, C, H, W) int16 id maps at mid-exposure
    markers_2d: np.ndarray    # (F, C, M, 2) px
    visible: np.ndarray       # (F, C, M) bool, >= 75 % unoccluded
    visible_frac: np.ndarray  # (F, C, M) float
    mode: str                 # "ir" | "visible"


@dataclass(frozen=True)
class Score:
    recall: float
    n_visible: int
    false_per_image: float
    false_by_kind: dict[str, float]
    err_median_px: float
    err_p95_px: float
    bias_px: tuple[float, float]
    ms_per_image: float
    ms_cc_reference: float


def render_cached(path: Path, overrides: dict[str, object], cache: Path) -> Rendered:
    sc = load_scenario(path, overrides)
    key = hashlib.sha256(sc.content_hash().encode()).hexdigest()[:12]
    f = cache / f"{sc.name}_{key}.npz"
    if not f.is_file():
        cache.mkdir(parents=True, exist_ok=True)
        bench = build_stage(sc)
        seq = render_frames(bench, keep_frames=True, keep_ids=True)
        gt = seq.ground_truth
        ids = np.stack([gt.id_maps[n] for n in gt.camera_names], axis=1)
        np.savez(f, frames=seq.frames, ids=ids, markers_2d=gt.markers_2d, visible=gt.marker_visible,
                 visible_frac=gt.marker_visible_frac, mode=np.array(sc.sensor.mode))
    with np.load(f) as z:
        return Rendered(z["frames"], z["ids"], z["markers_2d"], z["visible"], z["visible_frac"], str(z["mode"]))


def _kind(ids: np.ndarray, x: float, y: float) -> str:
    """What the id map shows in the 5x5 pixels around a false blob."""
    h, w = ids.shape
    xi, yi = int(round(x)), int(round(y))
    patch = ids[max(yi - 2, 0):min(yi + 3, h), max(xi - 2, 0):min(xi + 3, w)]
    if (patch >= MARKER_BASE).any():
        return "marker_edge"
    vals, counts = np.unique(patch, return_counts=True)
    v = int(vals[np.argmax(counts)])
    return {BACKGROUND: "background", BODY: "body", SET: "set", CLUTTER: "clutter"}.get(v, f"id{v}")


def score(r: Rendered, detect: Callable[[np.ndarray], Detections], match_px: float = 1.5, false_px: float = 3.0,
          crops: Path | None = None, max_crops: int = 12, step: int = 1) -> Score:
    """Score ``detect`` (one RGB image -> Detections) on every ``step``-th frame of ``r``."""
    F, C = r.frames.shape[:2]
    hits = n_vis = n_false = 0
    kinds: dict[str, int] = {}
    errs: list[np.ndarray] = []
    ms = 0.0
    ms_cc = 0.0
    n_crops = 0
    frames = range(0, F, step)
    for f in frames:
        for c in range(C):
            img = r.frames[f, c]
            t0 = time.perf_counter()
            det = detect(img)
            ms += time.perf_counter() - t0
            g = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY)
            _, mask = cv2.threshold(g, 128, 1, cv2.THRESH_BINARY)
            t0 = time.perf_counter()
            cv2.connectedComponentsWithStats(mask, connectivity=8, ltype=cv2.CV_32S)
            ms_cc += time.perf_counter() - t0
            truth = r.markers_2d[f, c]
            vis = r.visible[f, c]
            part = r.visible_frac[f, c] > 0.0
            full = r.visible_frac[f, c] >= 0.9
            n_vis += int(vis.sum())
            if len(det) == 0:
                missed = vis.copy()
                false = np.zeros(0, bool)
            else:
                tree = cKDTree(det.xy)
                d, j = tree.query(truth)
                ok = d <= match_px
                hits += int((ok & vis).sum())
                missed = vis & ~ok
                sel = full & (d <= 3.0)
                errs.append(det.xy[j[sel]] - truth[sel])
                if part.any():
                    dd, _ = cKDTree(truth[part]).query(det.xy)
                    false = dd > false_px
                else:
                    false = np.ones(len(det), bool)
                n_false += int(false.sum())
                for x, y in det.xy[false]:
                    k = _kind(r.ids[f, c], x, y)
                    kinds[k] = kinds.get(k, 0) + 1
            if crops is not None and n_crops < max_crops and (false.any() or missed.any()):
                n_crops += _write_crops(crops, f, c, img, det, truth, vis, missed, false)
    e = np.concatenate(errs) if errs else np.zeros((0, 2))
    n = np.linalg.norm(e, axis=1)
    n_img = len(frames) * C
    return Score(hits / max(n_vis, 1), n_vis, n_false / n_img, {k: v / n_img for k, v in sorted(kinds.items())},
                 float(np.median(n)) if n.size else float("nan"), float(np.percentile(n, 95)) if n.size else float("nan"),
                 tuple(float(v) for v in np.round(e.mean(axis=0), 3)) if n.size else (float("nan"),) * 2,
                 1e3 * ms / n_img, 1e3 * ms_cc / n_img)


def _write_crops(out: Path, f: int, c: int, img: np.ndarray, det, truth, vis, missed, false) -> int:
    """A mosaic of 40x40 px patches (x6) around each missed marker and false blob of one
    image: detections green circles, visible truth blue crosses, missed truth red."""
    out.mkdir(parents=True, exist_ok=True)
    s, half = 6, 20
    h, w = img.shape[:2]
    pad = cv2.copyMakeBorder(img[..., ::-1] if img.ndim == 3 else cv2.cvtColor(img, cv2.COLOR_GRAY2BGR),
                             half, half, half, half, cv2.BORDER_CONSTANT)
    centres = [("miss", truth[m]) for m in np.flatnonzero(missed)] + [("false", xy) for xy in det.xy[false]]
    tiles = []
    for kind, (cx, cy) in centres[:16]:
        x0, y0 = int(round(cx)), int(round(cy))
        tile = cv2.resize(pad[y0:y0 + 2 * half, x0:x0 + 2 * half], None, fx=s, fy=s, interpolation=cv2.INTER_NEAREST)
        def at(x, y):
            return int(s * (x - x0 + half) + s / 2), int(s * (y - y0 + half) + s / 2)
        for (x, y) in det.xy:
            cv2.circle(tile, at(x, y), 9, (0, 255, 0), 1)
        for m, (x, y) in enumerate(truth):
            if np.isfinite(x) and vis[m]:
                cv2.drawMarker(tile, at(x, y), (0, 0, 255) if missed[m] else (255, 0, 0), cv2.MARKER_CROSS, 10, 1)
        cv2.putText(tile, kind, (4, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 255, 255), 1)
        tiles.append(tile)
    if not tiles:
        return 0
    while len(tiles) % 4:
        tiles.append(np.zeros_like(tiles[0]))
    rows = [np.hstack(tiles[i:i + 4]) for i in range(0, len(tiles), 4)]
    cv2.imwrite(str(out / f"f{f:03d}_c{c}.png"), np.vstack(rows))
    return 1


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scenario", type=Path)
    ap.add_argument("--set", dest="overrides", action="append", default=[], help="dotted.field=value, as simbench run")
    ap.add_argument("--cache", type=Path, default=Path("/tmp/simbench_detection_eval"))
    ap.add_argument("--match-px", type=float, default=1.5)
    ap.add_argument("--false-px", type=float, default=3.0)
    ap.add_argument("--crops", type=Path, default=None)
    ap.add_argument("--step", type=int, default=1, help="score every step-th frame")
    a = ap.parse_args()
    r = render_cached(a.scenario, parse_overrides(a.overrides), a.cache)
    params = DetectionParams(mode=r.mode)
    s = score(r, lambda img: detect_markers(img, params), a.match_px, a.false_px, a.crops, step=a.step)
    label = a.scenario.stem + ("" if not a.overrides else " " + " ".join(a.overrides))
    kinds = ", ".join(f"{k} {v:.2f}" for k, v in s.false_by_kind.items())
    print(f"{label}: recall {s.recall:.3f} of {s.n_visible} visible | false/img {s.false_per_image:.2f} "
          f"({kinds}) | err median {s.err_median_px:.3f} p95 {s.err_p95_px:.3f} px bias {s.bias_px} | "
          f"{s.ms_per_image:.2f} ms/img (cc ref {s.ms_cc_reference:.2f})")


if __name__ == "__main__":
    main()
