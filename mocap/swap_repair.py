"""Repair label swaps in 3D trajectories from motion continuity.

When two nearby markers (the two wrist markers, say) trade labels in most cameras at
once, every later stage agrees with the swap: the triangulation is consistent, and a
skeleton can often be bent to fit it (a forearm turned over). What gives it away is
motion: at the frame of the swap each label jumps onto the other's predicted path.
For every pair of labels closer than ``max_pair_distance_m``, the constant-velocity
predictions of both from the previous frames are compared with the measured
positions kept as they are and exchanged; when exchanging explains the frame much
better, the two labels are exchanged from that frame on.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class SwapRepairParams:
    max_pair_distance_m: float = 0.15
    min_gain_m: float = 0.02     # the swap must explain the frame better by this much
    ratio: float = 3.0           # ... and by this factor
    jump_scale: float = 8.0      # a lone jump: deviation > jump_scale x the label's typical one
    min_jump_m: float = 0.015    # ... and at least this
    max_jump_run: int = 6        # frames flagged after a jump at most (later ones are re-labelled downstream)


def find_jumps(xyz: np.ndarray, params: SwapRepairParams | None = None) -> np.ndarray:
    """Samples ``(F, M)`` bool where a label jumps off its own path onto something else.

    A jump is a deviation from the constant-velocity prediction (from the two previous
    samples) that is both larger than ``min_jump_m`` and ``jump_scale`` times the label's
    median deviation; the flagged run lasts until the label's track breaks (NaN) or it
    jumps back. Such a run is usually a label that took over a neighbour's marker while
    that neighbour's own label was missing.
    """
    p = params or SwapRepairParams()
    x = np.asarray(xyz, dtype=np.float64)
    F, M, _ = x.shape
    pred = np.full_like(x, np.nan)
    pred[2:] = 2 * x[1:-1] - x[:-2]
    dev = np.linalg.norm(x - pred, axis=2)              # (F, M), NaN near gaps
    with warnings.catch_warnings():  # labels never measured have an all-NaN column
        warnings.simplefilter("ignore", RuntimeWarning)
        typical = np.nanmedian(dev, axis=0)
    thr = np.maximum(p.min_jump_m, p.jump_scale * np.nan_to_num(typical, nan=p.min_jump_m))
    jump = np.nan_to_num(dev, nan=0.0) > thr
    out = np.zeros((F, M), bool)
    fin = np.isfinite(x).all(axis=2)
    for m in np.nonzero(jump.any(axis=0))[0]:
        frames = np.nonzero(jump[:, m])[0]
        for f0 in frames:
            if out[f0, m]:
                continue
            f1 = f0
            # Run until the track breaks or the label returns to its pre-jump path.
            ref = x[f0 - 1, m]
            while (f1 < F and f1 - f0 < p.max_jump_run and fin[f1, m]
                   and np.linalg.norm(x[f1, m] - ref) > 0.5 * dev[f0, m]):
                out[f1, m] = True
                ref = ref + (x[f0 - 1, m] - x[f0 - 2, m])
                f1 += 1
    return out


def repair_swaps(xyz: np.ndarray, params: SwapRepairParams | None = None) -> tuple[np.ndarray, list[tuple[int, int, int]]]:
    """Return corrected ``(F, M, 3)`` positions and the swaps ``(frame, label_a, label_b)``.

    NaN samples are skipped; predictions use the last two finite frames of a label.
    """
    p = params or SwapRepairParams()
    x = np.array(xyz, dtype=np.float64, copy=True)
    F, M, _ = x.shape
    events: list[tuple[int, int, int]] = []
    last = np.full((M, 3), np.nan)   # last finite position of each label
    prev = np.full((M, 3), np.nan)   # the one before
    for f in range(F):
        cur = x[f]
        vel = np.where(np.isfinite(prev), last - prev, 0.0)
        pred = last + vel
        ok = np.isfinite(cur).all(axis=1) & np.isfinite(pred).all(axis=1)
        idx = np.nonzero(ok)[0]
        if len(idx) >= 2:
            d = np.linalg.norm(cur[idx, None] - cur[None, idx], axis=2)
            ia, ib = np.nonzero(np.triu(d < p.max_pair_distance_m, 1))
            if len(ia):
                a, b = idx[ia], idx[ib]
                keep = np.linalg.norm(cur[a] - pred[a], axis=1) + np.linalg.norm(cur[b] - pred[b], axis=1)
                swap = np.linalg.norm(cur[a] - pred[b], axis=1) + np.linalg.norm(cur[b] - pred[a], axis=1)
                better = (keep - swap > p.min_gain_m) & (swap * p.ratio < keep)
                used: set[int] = set()
                for k in np.argsort(swap - keep):
                    if not better[k] or a[k] in used or b[k] in used:
                        continue
                    used.update((a[k], b[k]))
                    x[f:, [a[k], b[k]]] = x[f:, [b[k], a[k]]]
                    events.append((f, int(a[k]), int(b[k])))
                cur = x[f]
        fin = np.isfinite(cur).all(axis=1)
        prev[fin] = last[fin]
        last[fin] = cur[fin]
    return x, events
