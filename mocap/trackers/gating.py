"""Gated association of detections to labels, shared by every tracker of
:mod:`mocap.trackers.base` (and by the tracker benchmark's filters that keep their own state).

* :func:`unique_gated_pairs`: the common case, compiled: each label's gate holds at most one
  detection and each detection lies in at most one gate.
* :func:`mahalanobis_sq` and :func:`gated_hungarian`: the ambiguous case in numpy/scipy (the
  Hungarian method with forbidden pairs and a miss option per label).
* :func:`gated_assignment`: the two in one stand-alone call (no loss handling).

Why the common case is compiled (numba) rather than numpy: at the sizes of a capture (tens of
markers per camera) the numpy form of this check -- an ``(M, n)`` distance matrix, a
comparison, a ``nonzero`` and a uniqueness test -- costs a few microseconds per call in
interpreter and dispatch overhead, not in arithmetic, and was half of a tracker's per-frame
budget (seed 000 Tables V-VII measure exactly this per-frame cost). One compiled double loop
with early exit does the same work in well under a microsecond of arithmetic. Anything else
(contested gates, the Hungarian method) stays in numpy/scipy; :func:`gated_assignment` is
the numpy reference of the compiled check used by the tests.
"""

from __future__ import annotations

import numba
import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.spatial.distance import cdist


@numba.njit(cache=True, nogil=True)
def unique_gated_pairs(
    centre: np.ndarray, gate_var: np.ndarray, radius_sq: np.ndarray, threshold: float, detections_xy: np.ndarray,
    idx: np.ndarray,
) -> int:
    """Assignment of detections to labels when the gated pairs form a partial permutation.

    Parameters
    ----------
    centre : (M, 2) float
        Gate centres (predicted positions), px; NaN rows have no gate.
    gate_var : (M, 1) or (M, 2) float
        Gate variance per label (circular gates) or per label and image axis, px**2.
    radius_sq : (M, 1) float
        Squared gate radius of circular gates, px**2 (``gate_var * threshold``; used
        when ``gate_var`` has one column, so the test is the numpy path's to the bit).
    threshold : float
        Squared-Mahalanobis gate: a detection ``d`` is inside label ``m``'s gate when
        ``sum_k (d_k - centre_mk)**2 / gate_var_mk <= threshold``; for circular gates
        ``|d - centre|**2 <= radius_sq_m``.
    detections_xy : (n, 2) float
        Detections, px.
    idx : (M,) int, output
        Detection index of each label, -1 for none (valid only when the return value
        is not -1).

    Returns
    -------
    int
        The number K of in-gate pairs when every label has at most one detection in
        its gate and every detection lies in at most one gate; -1 otherwise (the
        assignment is ambiguous and needs the full method).
    """
    M = centre.shape[0]
    n = detections_xy.shape[0]
    circular = gate_var.shape[1] == 1
    taken = np.zeros(n, dtype=np.bool_)
    K = 0
    for m in range(M):
        idx[m] = -1
        cx = centre[m, 0]
        cy = centre[m, 1]
        if circular:
            r2 = radius_sq[m, 0]
        else:
            vx = gate_var[m, 0]
            vy = gate_var[m, 1]
        for j in range(n):
            dx = detections_xy[j, 0] - cx
            dy = detections_xy[j, 1] - cy
            if circular:
                inside = dx * dx + dy * dy <= r2
            else:
                inside = dx * dx / vx + dy * dy / vy <= threshold
            if inside:  # NaN centres compare False: no gate
                if idx[m] >= 0 or taken[j]:
                    return -1
                idx[m] = j
                taken[j] = True
                K += 1
    return K


def mahalanobis_sq(centre: np.ndarray, var: np.ndarray, det: np.ndarray) -> np.ndarray:
    """(M, n) squared Mahalanobis distances of detections ``det`` (n, 2) px from centres
    ``centre`` (M, 2) px under diagonal gate covariances ``var``: (M, 1) for circular
    gates, (M, 2) per image axis (px**2)."""
    if var.shape[1] == 1:
        d2 = cdist(centre, det, "sqeuclidean")  # one C loop for the (M, n) distances
        d2 /= var
        return d2
    dx = det[:, 0] - centre[:, 0:1]  # (M, n) px
    dy = det[:, 1] - centre[:, 1:2]
    dx *= dx
    dy *= dy
    dx /= var[:, 0:1]
    dy /= var[:, 1:2]
    dx += dy
    return dx


def gated_assignment(centre: np.ndarray, gate_var: np.ndarray, detections_xy: np.ndarray, threshold: float) -> np.ndarray:
    """Gated assignment of detections to labels, as
    :meth:`mocap.trackers.base.Tracker2D.associate` does it.

    A stand-alone form (no loss handling: every label competes) for filters that keep
    their own state, e.g. the per-marker filterpy loop of the benchmark.

    Parameters
    ----------
    centre : (M, 2) float
        Predicted positions, px.
    gate_var : (M, 2) or (M, 1) float
        Per-axis gate variances (diagonal of ``S``), or one per label for circular
        gates, px**2.
    detections_xy : (n, 2) float
        Detections, px.
    threshold : float
        Squared-Mahalanobis gate.

    Returns
    -------
    (M,) int
        Detection index per label, -1 for none.
    """
    det = np.asarray(detections_xy, dtype=np.float64).reshape(-1, 2)
    M = len(centre)
    if len(det) == 0:
        return np.full(M, -1, dtype=np.intp)
    d2 = mahalanobis_sq(centre, np.asarray(gate_var, dtype=np.float64), det)
    inside = d2 <= threshold
    rows, cols = np.divmod(np.flatnonzero(inside), len(det))
    if len(rows) <= 1 or (np.bincount(rows).max() <= 1 and np.bincount(cols).max() <= 1):
        idx = np.full(M, -1, dtype=np.intp)
        idx[rows] = cols
        return idx
    per_label = inside.sum(axis=1)
    idx = np.full(M, -1, dtype=np.intp)
    rows = np.flatnonzero(per_label > 0)
    cols = np.flatnonzero(inside[rows].any(axis=0))
    r, c = gated_hungarian(d2[np.ix_(rows, cols)], inside[np.ix_(rows, cols)], np.full(len(rows), float(threshold)))
    idx[rows[r]] = cols[c]
    return idx


def gated_hungarian(cost: np.ndarray, inside: np.ndarray, miss_cost: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Minimum-cost assignment with forbidden pairs and a per-row miss option.

    Parameters
    ----------
    cost : (R, C) float
        Pair costs (only entries where ``inside`` is True are allowed).
    inside : (R, C) bool
    miss_cost : (R,) float
        Cost of leaving each row unassigned.

    Returns
    -------
    rows, cols : (k,) int
        The assigned pairs, all inside their gates.
    """
    R, C = cost.shape
    allowed = np.where(inside, cost, 0.0)
    big = 4.0 * (np.abs(allowed).sum() + np.abs(miss_cost).sum() + 1.0)
    # Columns C..C+R-1 are per-row "miss" dummies (the standard augmented GNN matrix).
    full = np.full((R, C + R), big)
    full[:, :C] = np.where(inside, cost, big)
    full[np.arange(R), C + np.arange(R)] = miss_cost
    r, c = linear_sum_assignment(full)
    keep = c < C
    r, c = r[keep], c[keep]
    ok = inside[r, c]
    return r[ok], c[ok]
