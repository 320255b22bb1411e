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


def repair_source_swaps(xyz: np.ndarray, max_jump_m: float = 0.02, match_m: float = 0.01
                        ) -> tuple[np.ndarray, list[tuple[int, int, int, int, float]]]:
    """Exchange a labelled capture's own label swaps: return ``(F, M, 3)`` positions and the
    exchanges ``(label_a, label_b, first, last, jump_m)`` (samples ``first..last`` inclusive).

    A file's labelling can hand a physical marker from one label to another where one of them
    has a gap: label ``a`` jumps off its own path (more than ``max_jump_m`` from its
    constant-velocity prediction) onto the place where label ``b``'s path, ending just before
    (a *handover*) or starting just there (a *takeover*), continues within ``match_m``. Then
    ``b``'s run before the handover (or from the takeover on) is the marker ``a`` carries
    elsewhere: the two labels are exchanged over that run, so each follows one physical marker.
    This is the "swap repair" a user makes before taking a capture as truth.
    """
    x = np.array(xyz, dtype=np.float64, copy=True)
    F, M, _ = x.shape
    fin = np.isfinite(x).all(axis=2)
    events: list[tuple[int, int, int, int, float]] = []

    def predict(m: int, f: int) -> np.ndarray:
        return 2.0 * x[f - 1, m] - x[f - 2, m] if f >= 2 and fin[f - 2, m] else x[f - 1, m]

    for f in range(1, F):
        for a in range(M):
            if not (fin[f, a] and fin[f - 1, a]):
                continue
            pa = predict(a, f)
            jump = float(np.linalg.norm(x[f, a] - pa))
            if jump <= max_jump_m:
                continue
            for b in range(M):
                if b == a:
                    continue
                if fin[f - 1, b] and not fin[f, b] and np.linalg.norm(x[f, a] - predict(b, f)) < match_m:
                    lo = f - 1
                    while lo > 0 and fin[lo - 1, b]:
                        lo -= 1
                    first, last = lo, f - 1                      # handover: b's run before f
                elif fin[f, b] and not fin[f - 1, b] and np.linalg.norm(x[f, b] - pa) < match_m:
                    hi = f
                    while hi + 1 < F and fin[hi + 1, b]:
                        hi += 1
                    first, last = f, hi                          # takeover: b's run from f
                else:
                    continue
                seg = slice(first, last + 1)
                x[seg, [a, b]] = x[seg, [b, a]]
                fin[seg, [a, b]] = fin[seg, [b, a]]
                events.append((a, b, first, last, jump))
                break
    return x, events
