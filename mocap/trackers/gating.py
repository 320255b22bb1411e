"""The common case of gated association, compiled: each label's gate holds at most one
detection and each detection lies in at most one gate.

Why compiled (numba) rather than numpy: at the sizes of a capture (tens of markers per
camera) the numpy form of this check -- an ``(M, n)`` distance matrix, a comparison, a
``nonzero`` and a uniqueness test -- costs a few microseconds per call in interpreter and
dispatch overhead, not in arithmetic, and was half of a tracker's per-frame budget
(seed 000 Tables V-VII measure exactly this per-frame cost). One compiled double loop
with early exit does the same work in well under a microsecond of arithmetic. Anything
else (contested gates, the Hungarian method) stays in numpy/scipy in
:mod:`mocap.trackers.base`, which also holds the numpy reference of this check used by
the tests.
"""

from __future__ import annotations

import numba
import numpy as np


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
