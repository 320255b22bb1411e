"""Row-time correction for rolling-shutter cameras.

A webcam's CMOS sensor reads its rows out one after the other: row ``y`` of an ``H``-row
frame stamped ``t`` is exposed at ``t + y / H * readout`` (row 0 at the timestamp). Blobs of
one frame are then seen at different instants, and a fast marker low in the image is seen up
to ``readout`` (25 ms on a typical 30 fps webcam) after one at the top; triangulating them as
if they were simultaneous puts the marker where it never was, by a different amount in each
camera.

:func:`correct_rolling_shutter` gives each blob its own time (:func:`detection_times`) and
moves it to where it was at its frame's timestamp: blobs are linked frame to frame (the same
links as :class:`mocap.synchronisation.LinkedDetections`) and each blob's track is
interpolated at the timestamp through its own times (quadratic through the blob and its
links one frame before and after, linear when only one of them exists, unchanged without a
link). The corrected frames are then what a global shutter at the timestamps would have
seen, and the rest of the pipeline runs on them as it is.

Links between blobs fail where markers cross or merge (the hand's markers on a fast sweep),
and a wrong link moves a blob by pixels. :func:`capture_rolling_shutter` therefore runs the
pipeline three times. After each pass, :func:`row_time_trajectories` solves every labelled
marker again from the raw blobs the pass used, each at its own row's instant: all its frames
at once, the marker at a view's instant being the cubic through its positions at the four
frames around it (:func:`triangulate_row_times`, linear least squares), so a point seen by
two cameras at different rows is placed with its motion between them instead of with the
motion the previous pass estimated. :func:`refine_with_trajectories` moves every raw blob
near a solved marker by that marker's own motion between its row's instant and the
timestamp (the same cubic, projected), which does not depend on 2D links; the next pass runs
on those, and the last pass's markers, solved at their views' instants once more, are the
result (at the edges of gaps, where the motion is extrapolated, the pass's own points are
kept, or dropped where the two disagree by several millimetres).

The readout is a property of the camera model (its datasheet, or measured once by filming a
flashing LED); without the correction (``mocap markers`` without ``--readout-ms``) the blobs
are triangulated as if every row were exposed at the timestamp.
"""

from __future__ import annotations

import copy
import dataclasses
import math
import time

import numpy as np

from mocap.calibration import Calibration
from mocap.errors import MocapInputError
from mocap.marker_pipeline import MarkerCapture, MarkerPipelineParams, capture_from_detections
from mocap.synchronisation import LinkedDetections, SyncParams, duplicated_frames
from mocap.triangulation import pixels_to_normalized
from mocap.types import Detections, Trajectories

__all__ = ["detection_times", "correct_rolling_shutter", "refine_with_trajectories", "row_time_trajectories",
           "triangulate_row_times", "capture_rolling_shutter"]


def detection_times(detections: Detections, frame_time_s: float, readout_s: float, height: int) -> np.ndarray:
    """Each blob's exposure instant ``(N,)`` s: its frame's timestamp + ``row / height * readout_s``
    (``row`` its centroid's y in the image as read out, i.e. distorted pixels)."""
    return frame_time_s + np.asarray(detections.xy, float).reshape(-1, 2)[:, 1] / height * readout_s


def _kept_frames(detections: list[Detections]) -> list[int]:
    """Index of the frame each frame's blobs come from: a frame repeating the previous one exactly
    (a duplicated webcam frame) maps to the earlier one (as :class:`LinkedDetections` skips it)."""
    src: list[int] = []
    for k, dup in enumerate(duplicated_frames(detections)):
        src.append(src[-1] if dup else k)
    return src


def _lagrange(ts: np.ndarray, xs: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Values at ``t (N,)`` of the polynomials through points ``(ts (N, P), xs (N, P, 2))`` (P = 2 or 3)."""
    out = np.zeros(xs.shape[0:1] + xs.shape[2:])
    P = ts.shape[1]
    for i in range(P):
        w = np.ones(len(t))
        for j in range(P):
            if j != i:
                w = w * (t - ts[:, j]) / (ts[:, i] - ts[:, j])
        out += w[:, None] * xs[:, i]
    return out


def correct_rolling_shutter(detections: list[list[Detections]], frame_times: list[np.ndarray], readout_s,
                            image_heights, gate_px: float = SyncParams.link_gate_px) -> list[list[Detections]]:
    """Every camera's blobs moved to their frames' timestamps (see the module doc).

    Parameters
    ----------
    detections : C lists of F_c :class:`Detections` (distorted pixels, as detected)
    frame_times : C arrays ``(F_c,)`` s, each frame's timestamp (row 0's instant), increasing
    readout_s : the readout time (s), one for all cameras or one per camera; 0 leaves a camera as it is
    image_heights : the image height (rows), one for all cameras or one per camera

    Returns
    -------
    C lists of F_c Detections: the same blobs in the same order, their ``xy`` at the timestamps
    """
    C = len(detections)
    readout = np.broadcast_to(np.asarray(readout_s, float), (C,))
    heights = np.broadcast_to(np.asarray(image_heights, float), (C,))
    if len(frame_times) != C:
        raise MocapInputError(f"got frame times of {len(frame_times)} cameras for detections of {C}")
    if not (np.isfinite(readout).all() and (readout >= 0).all()):
        raise MocapInputError(f"rolling-shutter readout must be finite and >= 0 s, got {readout_s!r}")
    if not (np.isfinite(heights).all() and (heights > 0).all()):
        raise MocapInputError(f"image heights must be > 0, got {image_heights!r}")
    out: list[list[Detections]] = []
    for c, (dets, times) in enumerate(zip(detections, frame_times)):
        times = np.asarray(times, float).reshape(-1)
        if len(times) != len(dets):
            raise MocapInputError(f"camera {c}: {len(times)} frame times for {len(dets)} frames of detections")
        if readout[c] == 0 or not dets:
            out.append(list(dets))
            continue
        src = _kept_frames(dets)
        kept = sorted(set(src))
        linked = LinkedDetections([dets[k] for k in kept], times[kept], gate_px)
        T = linked.times
        # each blob's own instant (NaN for padding)
        tau = T[:, None] + linked.xy[..., 1] / heights[c] * readout[c]             # (F', N)
        corrected: dict[int, Detections] = {}
        for j, k in enumerate(kept):
            d = dets[k]
            n = len(d)
            if n == 0:
                corrected[k] = d
                continue
            idx = np.arange(n)
            pv = linked.prv[j, :n]
            nx = linked.nxt[j, :n]
            have_p = pv >= 0
            have_n = nx >= 0
            x0 = linked.xy[j, :n]
            t0 = tau[j, :n]
            xp = np.where(have_p[:, None], linked.xy[max(j - 1, 0), np.maximum(pv, 0)], np.nan)
            tp = np.where(have_p, tau[max(j - 1, 0), np.maximum(pv, 0)], np.nan)
            jn = min(j + 1, len(kept) - 1)
            xn = np.where(have_n[:, None], linked.xy[jn, np.maximum(nx, 0)], np.nan)
            tn = np.where(have_n, tau[jn, np.maximum(nx, 0)], np.nan)
            target = np.full(n, T[j])
            new = x0.copy()
            both = have_p & have_n
            if both.any():
                new[both] = _lagrange(np.stack([tp, t0, tn], 1)[both], np.stack([xp, x0, xn], 1)[both], target[both])
            for one, (xo, to) in ((have_p & ~have_n, (xp, tp)), (have_n & ~have_p, (xn, tn))):
                if one.any():
                    new[one] = _lagrange(np.stack([to, t0], 1)[one], np.stack([xo, x0], 1)[one], target[one])
            bad = ~np.isfinite(new).all(axis=1)
            new[bad] = x0[bad]
            corrected[k] = Detections(new[idx], d.area, d.intensity)
        out.append([corrected[s] for s in src])
    return out


def refine_with_trajectories(raw: list[list[Detections]], first: list[list[Detections]], frame_times: np.ndarray,
                             readout_s: float, calibration: Calibration, trajectories: Trajectories,
                             gate_px: float = 6.0, reach: int = 3, degree: int = 3) -> list[list[Detections]]:
    """The raw blobs moved to the timestamps by the reconstructed markers' motion.

    For each camera and frame, every marker of ``trajectories`` (at the frames' timestamps
    ``frame_times``, the same for every camera) is placed where the row-time model shows it:
    ``uv = project(X(t + v / H * readout))``, ``X`` continued from the frame along the polynomial
    of ``degree`` through the marker's ``degree + 1`` measured frames within ``reach`` frames
    nearest to the interval after the frame (:func:`_local_polynomials`: for the default cubic,
    frames ``k - 1 .. k + 2``, so the row's instant lies in its middle interval). A raw blob within ``gate_px`` of such a point is moved by that
    marker's ``project(X(t)) - uv``: first to the markers measured in that frame, then the
    blobs left to markers missing there but measured around it. Other blobs keep their
    position in ``first`` (the link-interpolated correction)."""
    t = np.asarray(frame_times, float)
    X = np.asarray(trajectories.xyz, float)                          # (F, M, 3)
    F, M = X.shape[:2]
    if F < 3:
        return [list(cam) for cam in first]
    coef = _local_polynomials(X, t, reach, degree)                 # (F, M, degree + 1, 3)
    P = coef[:, :, 0]
    measured = np.isfinite(X).all(axis=2)
    out = []
    for c, cam in enumerate(calibration):
        H = cam.size[1]
        uv_t = cam.project(P.reshape(-1, 3)).reshape(F, M, 2)
        uv = uv_t.copy()
        for _ in range(3):
            d = (np.nan_to_num(uv[..., 1], nan=0.0) / H * readout_s)[..., None]
            Xd = sum(coef[:, :, i] * d**i for i in range(coef.shape[2]))
            uv = cam.project(Xd.reshape(-1, 3)).reshape(F, M, 2)
        shift = uv_t - uv                                            # (F, M, 2)
        ok = np.isfinite(shift).all(axis=2) & np.isfinite(uv).all(axis=2)
        frames = []
        for k in range(len(raw[c])):
            d_raw, d_first = raw[c][k], first[c][k]
            if not len(d_raw) or k >= F or not ok[k].any():
                frames.append(d_first)
                continue
            xy = d_first.xy.copy()
            free = np.ones(len(d_raw), bool)
            for which in (ok[k] & measured[k], ok[k] & ~measured[k]):
                m_ok = np.flatnonzero(which)
                if not len(m_ok) or not free.any():
                    continue
                dist = np.linalg.norm(d_raw.xy[:, None] - uv[k, m_ok][None], axis=2)   # (n, M')
                near = dist.argmin(axis=1)
                hit = free & (dist[np.arange(len(d_raw)), near] <= gate_px)
                xy[hit] = d_raw.xy[hit] + shift[k, m_ok[near[hit]]]
                free &= ~hit
            frames.append(Detections(xy, d_raw.area, d_raw.intensity))
        out.append(frames)
    return out


def _local_polynomials(X: np.ndarray, t: np.ndarray, reach: int, degree: int) -> np.ndarray:
    """Coefficients ``(F, M, degree + 1, 3)`` of each marker's motion around frame ``k`` as a
    polynomial in ``t - t[k]``: through the ``degree + 1`` measured frames within ``reach`` frames
    nearest to the interval ``[t[k], t[k + 1]]`` (a rolling shutter's rows are exposed in it:
    for a cubic, frames ``k - 1 .. k + 2`` when all are measured), NaN where there are not enough."""
    F, M = X.shape[:2]
    n = degree + 1
    coef = np.full((F, M, n, 3), np.nan)
    measured = np.isfinite(X).all(axis=2)
    offsets = np.array(sorted(range(-reach, reach + 2), key=lambda o: (abs(o - 0.5), -o if degree % 2 else o)))
    for k in range(F):
        js = k + offsets
        js = js[(js >= 0) & (js < F)]
        avail = measured[js]
        pick = avail & (np.cumsum(avail, axis=0) <= n)
        for m in np.flatnonzero(pick.sum(axis=0) == n):
            j = np.sort(js[pick[:, m]])
            ts = t[j] - t[k]
            # Newton's divided differences, then the monomial coefficients in (t - t[k])
            dd = X[j, m].copy()                                      # (n, 3)
            for lvl in range(1, n):
                dd[lvl:] = (dd[lvl:] - dd[lvl - 1:-1]) / (ts[lvl:] - ts[:-lvl])[:, None]
            poly = np.zeros((n, 3))
            basis = np.zeros(n)
            basis[0] = 1.0                                           # prod (x - ts[i]) so far, as coefficients
            for lvl in range(n):
                poly += basis[:, None] * dd[lvl]
                if lvl < n - 1:
                    basis = np.concatenate([[0.0], basis[:-1]]) - ts[lvl] * basis
            coef[k, m] = poly
    return coef


def _stencils(measured: np.ndarray, reach: int = 3, n: int = 4) -> np.ndarray:
    """For every frame ``k`` of one marker (``measured (F,)`` bool), the frames ``(F, n)`` whose
    positions carry its motion over ``[t[k], t[k + 1]]`` (where its rows are exposed): the ``n``
    measured frames within ``reach`` nearest to that interval, as :func:`_local_polynomials`
    picks them (``k - 1 .. k + 2`` for a cubic when all are measured), -1 where fewer exist."""
    F = len(measured)
    offsets = np.array(sorted(range(-reach, reach + 2), key=lambda o: (abs(o - 0.5), -o if (n - 1) % 2 else o)))
    js = np.arange(F)[:, None] + offsets[None]                              # (F, 2 reach + 2)
    avail = (js >= 0) & (js < F)
    avail[avail] = measured[js[avail]]
    pick = avail & (np.cumsum(avail, axis=1) <= n)
    out = np.full((F, n), -1)
    for k in np.flatnonzero(pick.any(axis=1)):
        j = np.sort(js[k, pick[k]])
        out[k, :len(j)] = j
    return out


def _lagrange_rows(times: np.ndarray, J: np.ndarray, tau: np.ndarray) -> np.ndarray:
    """Weights ``(N, n)`` that put instants ``tau (N,)`` s on the polynomial through the frames
    ``J (N, n)`` (-1: unused, weight 0; the degree is the number used minus one)."""
    used = J >= 0
    ts = times[np.maximum(J, 0)]
    w = used.astype(float)
    for i in range(J.shape[1]):
        for j in range(J.shape[1]):
            if j != i:
                f = (tau - ts[:, j]) / np.where(used[:, j] & used[:, i], ts[:, i] - ts[:, j], 1.0)
                w[:, i] *= np.where(used[:, j], f, 1.0)
    return w


def triangulate_row_times(J: np.ndarray, w: np.ndarray, A: np.ndarray, b: np.ndarray, prior: np.ndarray,
                          prior_weight: float = 1.0, smooth: float = 0.0) -> np.ndarray:
    """One marker's positions ``(F, 3)`` m at the frame timestamps from views at their rows' instants.

    Each view ``i`` is two linear equations ``A[i] @ X(tau_i) + b[i] = 0`` (``A (N, 2, 3)`` px/m,
    ``b (N, 2)`` px: the DLT rows of its undistorted normalised coordinates scaled by focal / depth,
    so that residuals are about pixels), where the marker at the row's instant is the polynomial
    through its frame positions ``X(tau_i) = sum_j w[i, j] X[J[i, j]]`` (``J, w (N, n)``, -1 / 0
    unused: :func:`_stencils`, :func:`_lagrange_rows`). Every view thus constrains the frames
    around it, and a marker seen by two cameras at different rows is solved with its motion
    between them, not as if both were exposed at the timestamp. ``prior (F, 3)`` m (finite rows)
    adds ``prior_weight * (X[k] - prior[k]) = 0`` (px per m: 1 mm costs 0.001 px at the default,
    nothing against the views, but it keeps a frame the views leave undetermined solvable);
    frames without a finite prior come back NaN. ``smooth`` (px per m) adds ``smooth`` times the
    fourth differences of five consecutive frames: views at about the same point of the readout
    in every frame hardly see a position alternating from frame to frame (half-way through
    the interval the cubic's weights cancel it exactly), which no body does at half the
    frame rate; the fourth difference costs that mode 16 times its size, and a 3 Hz sweep
    only 0.15 times. Linear least squares (normal equations, ``3 F`` unknowns)."""
    F = len(prior)
    ok = np.isfinite(prior).all(axis=1)
    AtA = np.einsum("nri,nrj->nij", A, A)                                     # (N, 3, 3)
    Atb = np.einsum("nri,nr->ni", A, b)                                       # (N, 3)
    G = np.zeros((F, F, 3, 3))
    h = np.zeros((F, 3))
    Jc = np.maximum(J, 0)
    pair = w[:, :, None, None, None] * w[:, None, :, None, None] * AtA[:, None, None]      # (N, n, n, 3, 3)
    np.add.at(G, (Jc[:, :, None], Jc[:, None, :]), pair)
    np.add.at(h, Jc, -w[:, :, None] * Atb[:, None])
    G[np.arange(F), np.arange(F)] += prior_weight**2 * np.eye(3)
    h += prior_weight**2 * np.where(ok[:, None], prior, 0.0)
    if smooth > 0:
        G += smooth**2 * _difference_gram(ok, 4)[:, :, None, None] * np.eye(3)
    X = _solve_banded(G.transpose(0, 2, 1, 3).reshape(3 * F, 3 * F), h.reshape(3 * F)).reshape(F, 3)
    X[~ok] = np.nan
    return X


def _solve_banded(G: np.ndarray, h: np.ndarray) -> np.ndarray:
    """``G^-1 h`` for a symmetric positive definite ``G (n, n)`` whose entries lie within ``u`` of
    the diagonal (a view couples the frames of its stencil only; ``u`` 12-23 of 360 unknowns on
    a 4 s take): Cholesky on the band, ``O(n u^2)``. Written out rather than LAPACK's: on the
    shared 2-core machine a threaded BLAS waiting for busy cores made ``solveh_banded`` take
    up to 1 s for what takes 1 ms (and a dense solve 0.1 s)."""
    n = len(G)
    i, j = np.nonzero(G)
    u = int((j - i).max()) if len(i) else 0
    L = np.zeros_like(G)
    for c in range(n):
        lo, hi = max(0, c - u), min(n, c + u + 1)
        L[c, c] = np.sqrt(G[c, c] - np.dot(L[c, lo:c], L[c, lo:c]))
        L[c + 1:hi, c] = (G[c + 1:hi, c] - L[c + 1:hi, lo:c] @ L[c, lo:c]) / L[c, c]
    y = np.zeros(n)
    for r in range(n):                                                       # L y = h
        lo = max(0, r - u)
        y[r] = (h[r] - np.dot(L[r, lo:r], y[lo:r])) / L[r, r]
    x = np.zeros(n)
    for r in range(n - 1, -1, -1):                                           # L^T x = y
        hi = min(n, r + u + 1)
        x[r] = (y[r] - np.dot(L[r + 1:hi, r], x[r + 1:hi])) / L[r, r]
    return x


def _difference_gram(ok: np.ndarray, order: int) -> np.ndarray:
    """``D.T @ D`` ``(F, F)`` of the ``order``-th differences over runs of ``order + 1`` consecutive ``ok`` frames."""
    F = len(ok)
    coef = np.array([(-1) ** (order - i) * math.comb(order, i) for i in range(order + 1)], float)
    G = np.zeros((F, F))
    for k in range(F - order):
        if ok[k:k + order + 1].all():
            G[k:k + order + 1, k:k + order + 1] += np.outer(coef, coef)
    return G


def _raw_observations(raw: list[list[Detections]], used: list[list[Detections]], xy: np.ndarray) -> np.ndarray:
    """The raw blob ``(F, C, M, 2)`` px behind each labelled observation ``xy (F, C, M, 2)``: ``xy``
    are positions of blobs of ``used`` (the blobs of ``raw``, same order, moved to the
    timestamps); NaN where there is no observation."""
    out = np.full(xy.shape, np.nan)
    F, C = xy.shape[:2]
    for c in range(C):
        for k in range(min(F, len(used[c]))):
            have = np.flatnonzero(np.isfinite(xy[k, c]).all(axis=1))
            u = used[c][k].xy
            if not len(have) or not len(u):
                continue
            gap = np.abs(xy[k, c, have][:, None] - u[None]).max(axis=2)      # (m, n) px
            j = gap.argmin(axis=1)
            ok = gap[np.arange(len(have)), j] < 1e-9
            out[k, c, have[ok]] = raw[c][k].xy[j[ok]]
    return out


def _view_rows(raw_xy: np.ndarray, used_xy: np.ndarray, start: Trajectories, times: np.ndarray, readout_s: float,
               calibration: Calibration, max_residual_px: float):
    """The views a capture triangulated, as rows for :func:`triangulate_row_times`: ``(frame (N,),
    marker (N,), tau (N,) s, A (N, 2, 3) px/m, b (N, 2) px)``. ``raw_xy``, ``used_xy`` ``(F, C, M, 2)``
    px: each labelled view's raw blob and its position the capture triangulated; a view counts
    where the capture measured the marker (finite, not filled) and reprojects within
    ``max_residual_px`` of it (the capture's triangulation drops the others). Depths (for the
    pixel scale) are the capture's points'."""
    X = np.asarray(start.xyz, float)
    F, M = X.shape[:2]
    measured = np.isfinite(X).all(axis=2)
    if start.filled is not None:
        measured &= ~np.asarray(start.filled, bool)
    parts = []
    for c, cam in enumerate(calibration):
        proj = cam.project(X.reshape(-1, 3)).reshape(F, M, 2)
        with np.errstate(invalid="ignore"):
            near = np.linalg.norm(used_xy[:, c] - proj, axis=2) <= max_residual_px
        ok = measured & np.isfinite(raw_xy[:, c]).all(axis=2) & near
        k, m = np.nonzero(ok)
        xn = pixels_to_normalized(cam, raw_xy[k, c, m])                      # (N, 2)
        scale = cam.mean_focal_px / cam.to_camera(X[k, m])[:, 2]
        R, t = cam.R, cam.t
        A = np.stack([xn[:, :1] * R[2] - R[0], xn[:, 1:] * R[2] - R[1]], axis=1) * scale[:, None, None]
        b = np.stack([xn[:, 0] * t[2] - t[0], xn[:, 1] * t[2] - t[1]], axis=1) * scale[:, None]
        tau = times[k] + raw_xy[k, c, m, 1] / cam.size[1] * readout_s
        parts.append((k, m, tau, A, b))
    return tuple(np.concatenate([p[i] for p in parts]) for i in range(5))


def _solve_marker(t: np.ndarray, k: np.ndarray, tau: np.ndarray, A: np.ndarray, b: np.ndarray, prior: np.ndarray,
                  max_residual_px: float, prior_weight: float, smooth: float, rounds: int):
    """One marker's :func:`triangulate_row_times` from its views (frame ``k (N,)``, instant ``tau (N,)``
    s, rows ``A (N, 2, 3)``, ``b (N, 2)``): views more than ``max_residual_px`` off the solution
    are left out and it is solved again, ``rounds`` times at most. Returns the positions
    ``(F, 3)`` m, the frames with views ``(F,)`` bool and the frames of the views kept ``(N',)``."""
    F = len(t)
    seen = np.isin(np.arange(F), k)
    J = _stencils(seen)[k]
    w = _lagrange_rows(t, J, tau)
    keep = np.ones(len(k), bool)
    for _ in range(max(rounds, 1)):
        P = triangulate_row_times(J[keep], w[keep], A[keep], b[keep], prior, prior_weight, smooth)
        at = np.einsum("nj,njd->nd", w, np.nan_to_num(P[np.maximum(J, 0)]))   # (N, 3) m at tau
        res = np.linalg.norm(np.einsum("nij,nj->ni", A, at) + b, axis=1)
        again = res <= max_residual_px
        if (again == keep).all() or not again.any():
            break
        keep = again
    return P, seen, np.unique(k[keep])


def row_time_trajectories(raw: list[list[Detections]], used: list[list[Detections]], tracks, frame_times: np.ndarray,
                          readout_s: float, calibration: Calibration, start: Trajectories, max_residual_px: float = 2.0,
                          prior_weight: float = 1.0, smooth: float = 10.0, rounds: int = 3,
                          edge_mm: float | None = None) -> Trajectories:
    """A capture's markers re-solved from their raw views at the views' own instants.

    ``start`` and ``tracks`` are a capture's trajectories and labelled 2D observations (positions in
    ``used``, the blobs of ``raw`` moved to the timestamps); each observation's raw blob, seen at
    ``frame_times[k] + row / H * readout_s``, enters :func:`triangulate_row_times` for its marker,
    which solves all its frames at once with its motion between the views (the capture
    triangulated the moved blobs as if simultaneous, so an error in the motion that moved them
    stays in its points). Views more than ``max_residual_px`` off the solution are left out
    and the marker solved again (``rounds`` times at most). Returns ``start`` (``(F, M, 3)`` m)
    with its points replaced by the solution where it has views; with ``edge_mm``, only inside
    runs of frames with views: at a gap's edge the solution hangs on a polynomial extrapolated
    from one side, which fast motion bends by centimetres (``zigzag_fast``: 56 mm at the 99th
    percentile one frame out), so there ``start``'s point (its blobs moved by the previous
    motion, triangulated at the frame's own rows) stays, and is dropped where the two disagree
    by more than ``edge_mm``: one of them, or the point's views, is then wrong, and a gap is
    better than a wrong point."""
    t = np.asarray(frame_times, float)
    X = np.asarray(start.xyz, float)
    F = X.shape[0]
    if F < 2 or readout_s <= 0:
        return start
    xy = np.asarray(tracks.xy, float)[:, :, [list(tracks.labels).index(n) for n in start.labels]]
    k, m, tau, A, b = _view_rows(_raw_observations(raw, used, xy), xy, start, t, readout_s, calibration, max_residual_px)
    out = X.copy()
    for mk in np.unique(m):
        sel = m == mk
        P, seen, kept = _solve_marker(t, k[sel], tau[sel], A[sel], b[sel], X[:, mk], max_residual_px, prior_weight,
                                      smooth, rounds)
        if edge_mm is None:
            out[kept, mk] = P[kept]
            continue
        inner = seen & np.r_[False, seen[:-1]] & np.r_[seen[1:], False]
        frames = np.intersect1d(kept, np.flatnonzero(inner))
        out[frames, mk] = P[frames]
        edge = np.flatnonzero(seen & ~inner)
        out[edge[np.linalg.norm(P[edge] - X[edge, mk], axis=1) > edge_mm * 1e-3], mk] = np.nan
    gone = np.isfinite(X).all(axis=2) & ~np.isfinite(out).all(axis=2)
    n_views = None if start.n_views is None else np.where(gone, 0, start.n_views)
    residual = None if start.residual_px is None else np.where(gone, np.nan, start.residual_px)
    return Trajectories(list(start.labels), out, start.times, start.filled, residual, n_views)


def capture_rolling_shutter(detections: list[list[Detections]], times: np.ndarray, readout_s: float,
                            calibration: Calibration, template, params: MarkerPipelineParams | None = None,
                            rng: np.random.Generator | None = None, subject=None, detection_ms: float = 0.0,
                            marker_model=None, refinements: int = 2, edge_mm: float = 5.0) -> MarkerCapture:
    """The marker pipeline on rolling-shutter cameras exposing their rows over ``readout_s``
    from the frame timestamps ``times (F,)`` (the same for every camera): blobs moved to the
    timestamps along their 2D links (:func:`correct_rolling_shutter`), a first capture, its
    markers solved at their views' own instants (:func:`row_time_trajectories`), the raw blobs
    moved again by that motion (:func:`refine_with_trajectories`) and the capture on those
    (``refinements`` times; its ``timings_ms`` has every pass's stages summed, with
    ``row_time``); the last capture's markers, solved at their views' instants once more (at
    gaps' edges checked against the capture's points within ``edge_mm``), are the result's
    trajectories."""
    times = np.asarray(times, float)
    C = len(detections)
    first = correct_rolling_shutter(detections, [times] * C, readout_s, [cam.size[1] for cam in calibration])
    rng2 = copy.deepcopy(rng)
    capture = capture_from_detections(first, calibration, template, times, params, rng, subject, detection_ms, marker_model)
    max_px = (params or MarkerPipelineParams()).reconstruction.max_residual_px
    used, row_ms = first, 0.0
    for k in range(refinements + 1):
        t0 = time.perf_counter()
        solved = row_time_trajectories(detections, used, capture.tracks, times, readout_s, calibration,
                                       capture.trajectories, max_px, edge_mm=None if k < refinements else edge_mm)
        row_ms += (time.perf_counter() - t0) * 1e3
        if k == refinements:
            break
        used = refine_with_trajectories(detections, first, times, readout_s, calibration, solved)
        again = capture_from_detections(used, calibration, template, times, params, copy.deepcopy(rng2), subject,
                                        detection_ms, marker_model)
        for name, v in capture.timings_ms.items():
            again.timings_ms[name] = again.timings_ms.get(name, 0.0) + v
        capture = again
    capture.timings_ms["row_time"] = row_ms
    return dataclasses.replace(capture, trajectories=solved)
