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
pipeline three times: the first pass on the link-corrected blobs gives labelled 3D
trajectories, and :func:`refine_with_trajectories` moves every raw blob near a reconstructed
marker by the marker's own motion between its row's instant and the timestamp (the cubic
through the marker's positions at the four frames around that interval, projected), which
does not depend on 2D links; the second pass runs on those, and its trajectories, better at
the fast reversals, refine the raw blobs once more for the third. The readout is a property of the camera model (its datasheet, or measured once
by filming a flashing LED); without the correction (``mocap markers`` without
``--readout-ms``) the blobs are triangulated as if every row were exposed at the timestamp.
"""

from __future__ import annotations

import copy

import numpy as np

from mocap.calibration import Calibration
from mocap.errors import MocapInputError
from mocap.marker_pipeline import MarkerCapture, MarkerPipelineParams, capture_from_detections
from mocap.synchronisation import LinkedDetections, SyncParams, duplicated_frames
from mocap.types import Detections, Trajectories

__all__ = ["detection_times", "correct_rolling_shutter", "refine_with_trajectories", "capture_rolling_shutter"]


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


def capture_rolling_shutter(detections: list[list[Detections]], times: np.ndarray, readout_s: float,
                            calibration: Calibration, template, params: MarkerPipelineParams | None = None,
                            rng: np.random.Generator | None = None, subject=None, detection_ms: float = 0.0,
                            marker_model=None, refinements: int = 2) -> MarkerCapture:
    """The marker pipeline on rolling-shutter cameras exposing their rows over ``readout_s``
    from the frame timestamps ``times (F,)`` (the same for every camera): blobs moved to the
    timestamps along their 2D links (:func:`correct_rolling_shutter`), a first capture, the raw
    blobs moved again by the reconstructed markers' motion (:func:`refine_with_trajectories`),
    and the capture on those (``refinements`` times; its ``timings_ms`` has every pass's stages summed)."""
    times = np.asarray(times, float)
    C = len(detections)
    first = correct_rolling_shutter(detections, [times] * C, readout_s, [cam.size[1] for cam in calibration])
    rng2 = copy.deepcopy(rng)
    capture = capture_from_detections(first, calibration, template, times, params, rng, subject, detection_ms, marker_model)
    for _ in range(refinements):
        refined = refine_with_trajectories(detections, first, times, readout_s, calibration, capture.trajectories)
        again = capture_from_detections(refined, calibration, template, times, params, copy.deepcopy(rng2), subject,
                                        detection_ms, marker_model)
        for k, v in capture.timings_ms.items():
            again.timings_ms[k] = again.timings_ms.get(k, 0.0) + v
        capture = again
    return capture
