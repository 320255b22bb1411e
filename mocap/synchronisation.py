"""Synchronise unsynchronised cameras from the markers' motion, then resample their detections.

Webcams run on their own clocks: camera ``c``'s timestamps ``s_c`` map onto the reference
camera's clock by ``s_ref = offset_c + (1 + drift_c) * s_c``, with start offsets of up to
seconds and rate errors of tens to hundreds of ppm. :func:`estimate_sync` finds
``offset_c`` and ``drift_c`` from the unlabelled marker detections alone (no ground truth,
no clapperboard): at the right clock map, camera ``c``'s detections interpolated to the
reference camera's frame instants lie on the epipolar lines of the reference camera's
detections; at a wrong one the moving markers leave them. The cost is a robust mean of each
reference detection's distance to the nearest epipolar line of camera ``c``'s interpolated
detections; a grid over the offset finds its basin, :func:`scipy.optimize.minimize`
(Nelder-Mead) refines offset and drift together.

Interpolation in time (:class:`LinkedDetections`): each camera's blobs are linked frame to
frame (optimal assignment, :func:`scipy.optimize.linear_sum_assignment`, gated), and a blob is
interpolated between a frame and the next along its link (cubic Catmull-Rom when the links
before and after exist, linear otherwise). :func:`resample_detections` then gives every camera
detections at the reference camera's frame instants, which the marker pipeline triangulates
as synchronised frames (:func:`mocap.marker_pipeline.capture_unsynchronised`).

A frame whose blobs repeat the previous frame's exactly (a webcam's duplicated frame,
:func:`duplicated_frames`) is not used: its image is the previous instant's, its timestamp a
later one. :func:`resample_detections` replaces such a frame of the reference camera, whose
instants are the output's, by its blobs interpolated to the frame's timestamp, as it does for
every frame of the other cameras.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.optimize import linear_sum_assignment, minimize

from mocap.calibration import Calibration
from mocap.errors import InputFileError, MocapInputError, require, require_finite
from mocap.types import Detections

__all__ = ["SyncParams", "ClockSync", "LinkedDetections", "duplicated_frames", "estimate_sync", "resample_detections",
           "read_timestamps_csv"]


@dataclass(frozen=True)
class SyncParams:
    """Settings of :func:`estimate_sync`.

    max_offset_s : offsets searched in +-this (s) relative to the reference camera
    max_drift_ppm : drift bound of the refinement (ppm)
    coarse_step_s : step of the offset grid (s)
    link_gate_px : a blob moves at most this far between two frames (px); 0.4 x this from where its
        velocity takes it when it was linked from the frame before
    epipolar_scale_px : scale of the robust cost of the offset grid (px): distances well beyond it count alike
    fine_scale_px : the same, for the refinement (sharper, once in the basin)
    max_frames : reference frames the cost uses (evenly spread; all if fewer)
    min_overlap : fraction of the reference frames that must map inside the other camera's take
    """

    max_offset_s: float = 1.2
    max_drift_ppm: float = 200.0
    coarse_step_s: float = 0.004
    link_gate_px: float = 40.0
    epipolar_scale_px: float = 2.0
    fine_scale_px: float = 1.0
    max_frames: int = 400
    min_overlap: float = 0.5

    def __post_init__(self) -> None:
        require_finite(self, ("max_offset_s", "coarse_step_s", "link_gate_px", "epipolar_scale_px", "fine_scale_px", "min_overlap"),
                       error=MocapInputError)
        require_finite(self, ("max_drift_ppm",), positive=False, error=MocapInputError)
        require(self.max_frames >= 10, self, "max_frames", "use 10 or more", error=MocapInputError)


@dataclass(frozen=True)
class ClockSync:
    """Each camera's clock on the reference camera's: ``s_ref = offset_s[c] + (1 + drift[c]) * s_c``.

    reference : index of the reference camera (offset 0, drift 0)
    offset_s : (C,) s; drift : (C,) dimensionless (``* 1e6`` = ppm)
    cost_px : (C,) the robust epipolar cost at the estimate (px; NaN for the reference)
    """

    reference: int
    offset_s: np.ndarray
    drift: np.ndarray
    cost_px: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def to_camera_clock(self, c: int, s_ref: np.ndarray) -> np.ndarray:
        """Reference-clock instants ``(n,)`` as camera ``c``'s clock readings."""
        return (np.asarray(s_ref, float) - self.offset_s[c]) / (1.0 + self.drift[c])


def _check_timestamps(detections: list[list[Detections]], timestamps: list[np.ndarray]) -> list[np.ndarray]:
    if len(timestamps) != len(detections):
        raise MocapInputError(f"got timestamps of {len(timestamps)} cameras for detections of {len(detections)}")
    out = []
    for c, (d, t) in enumerate(zip(detections, timestamps)):
        t = np.asarray(t, float).reshape(-1)
        if len(t) != len(d):
            raise MocapInputError(f"camera {c}: {len(t)} timestamps for {len(d)} frames of detections")
        if not np.isfinite(t).all() or (len(t) > 1 and not (np.diff(t) > 0).all()):
            raise MocapInputError(f"camera {c}: timestamps must be finite and strictly increasing")
        out.append(t)
    return out


def duplicated_frames(detections: list[Detections]) -> np.ndarray:
    """``(F,)`` bool: the frame's blobs repeat the previous frame's exactly (same count, same
    centroids, bit for bit), as a webcam's duplicated frame does (the same image again under a
    later timestamp). Real blobs of a new exposure never repeat to the last bit: sensor noise
    moves every centroid. A frame without blobs is never a duplicate."""
    dup = np.zeros(len(detections), bool)
    for k in range(1, len(detections)):
        a, b = detections[k], detections[k - 1]
        dup[k] = bool(len(a)) and len(a) == len(b) and np.array_equal(a.xy, b.xy)
    return dup


class LinkedDetections:
    """One camera's blobs linked frame to frame, interpolated at any instant of its clock.

    times : (F,) s; xy : (F, N, 2) px, NaN-padded (N = most blobs in a frame); nxt : (F, N)
    index of each blob's link in the next frame (-1: none); prv : (F, N) in the previous frame.
    """

    def __init__(self, detections: list[Detections], times: np.ndarray, gate_px: float,
                 undistort=None) -> None:
        keep = np.flatnonzero(~duplicated_frames(detections))
        dets = [detections[k] for k in keep]  # duplicated frames are not used
        self.times = np.asarray(times, float)[keep]
        F = len(dets)
        N = max((len(d) for d in dets), default=0)
        self.xy = np.full((F, max(N, 1), 2), np.nan)
        self.area = np.full((F, max(N, 1)), np.nan)
        self.intensity = np.full((F, max(N, 1)), np.nan)
        for k, d in enumerate(dets):
            xy = d.xy if undistort is None or not len(d) else undistort(d.xy)
            self.xy[k, : len(d)] = xy
            self.area[k, : len(d)] = d.area
            self.intensity[k, : len(d)] = d.intensity
        self.nxt = np.full(self.xy.shape[:2], -1)
        self.prv = np.full(self.xy.shape[:2], -1)
        for k in range(F - 1):
            a, b = self.xy[k], self.xy[k + 1]
            ia, ib = np.flatnonzero(np.isfinite(a[:, 0])), np.flatnonzero(np.isfinite(b[:, 0]))
            if not len(ia) or not len(ib):
                continue
            # A blob linked from the frame before is expected where its velocity takes it (a fast
            # hand moves tens of pixels a frame; over the frames' own intervals, which a skipped
            # duplicate doubles); the others where they are, within the gate.
            pa = self.prv[k, ia]
            back = np.where((pa >= 0)[:, None], self.xy[max(k - 1, 0), np.maximum(pa, 0)], a[ia])
            ratio = (self.times[k + 1] - self.times[k]) / (self.times[k] - self.times[k - 1]) if k > 0 else 1.0
            pred = a[ia] + ratio * (a[ia] - back)
            d = np.linalg.norm(pred[:, None] - b[None, ib], axis=2)
            gate = np.where(pa >= 0, 0.4 * gate_px, gate_px)[:, None]
            r, c = linear_sum_assignment(np.where(d <= gate, d, 10.0 * gate_px + d))
            ok = d[r, c] <= gate[r, 0]
            self.nxt[k, ia[r[ok]]] = ib[c[ok]]
            self.prv[k + 1, ib[c[ok]]] = ia[r[ok]]

    def at(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Blobs at clock instants ``s (Q,)``: ``xy (Q, N, 2)`` (NaN where a blob has no link
        across the instant or ``s`` is outside the take), ``area`` and ``intensity`` ``(Q, N)``."""
        s = np.asarray(s, float)
        F = len(self.times)
        j = np.clip(np.searchsorted(self.times, s, side="right") - 1, 0, max(F - 2, 0))
        inside = (s >= self.times[0]) & (s <= self.times[-1]) & (F >= 2)
        if F < 2:
            nan = np.full((len(s),) + self.xy.shape[1:], np.nan)
            return nan, nan[..., 0], nan[..., 0]
        u = ((s - self.times[j]) / (self.times[j + 1] - self.times[j]))[:, None]
        nx = self.nxt[j]                                                    # (Q, N)
        rows = j[:, None]
        p1 = self.xy[j]                                                     # (Q, N, 2)
        p2 = np.where((nx >= 0)[..., None], self.xy[rows + 1, np.maximum(nx, 0)], np.nan)
        out = (1.0 - u)[..., None] * p1 + u[..., None] * p2
        # A cubic Hermite where the blob is linked one frame before and one after, its tangents those
        # of the parabolas through three consecutive frames at their own instants (Catmull-Rom when
        # the frames are evenly spaced; exact for a parabola when they are not: jitter, a skipped
        # duplicate).
        pv = self.prv[j]
        p0 = np.where((pv >= 0)[..., None], self.xy[np.maximum(rows - 1, 0), np.maximum(pv, 0)], np.nan)
        j2 = np.minimum(j + 2, F - 1)[:, None]
        nn = np.where(nx >= 0, self.nxt[np.minimum(j + 1, F - 1)[:, None], np.maximum(nx, 0)], -1)
        p3 = np.where(((nn >= 0) & (j2 == rows + 2))[..., None], self.xy[j2, np.maximum(nn, 0)], np.nan)
        T = self.times
        h0 = (T[j] - T[np.maximum(j - 1, 0)])[:, None, None]
        h1 = (T[j + 1] - T[j])[:, None, None]
        h2 = (T[np.minimum(j + 2, F - 1)] - T[j + 1])[:, None, None]
        with np.errstate(invalid="ignore", divide="ignore"):  # h0 or h2 of 0 at the take's ends: p0/p3 NaN there
            m1 = ((p1 - p0) / h0 * h1 + (p2 - p1) / h1 * h0) / (h0 + h1) * h1   # tangents, per unit of u
            m2 = ((p2 - p1) / h1 * h2 + (p3 - p2) / h2 * h1) / (h1 + h2) * h1
        uu = u[..., None]
        cr = ((2 * uu**3 - 3 * uu**2 + 1) * p1 + (uu**3 - 2 * uu**2 + uu) * m1
              + (-2 * uu**3 + 3 * uu**2) * p2 + (uu**3 - uu**2) * m2)
        full = np.isfinite(cr).all(axis=2, keepdims=True)
        out = np.where(full, cr, out)
        out[~inside] = np.nan
        w = u
        area = np.where(nx >= 0, (1 - w) * self.area[j] + w * self.area[rows + 1, np.maximum(nx, 0)], np.nan)
        inten = np.where(nx >= 0, (1 - w) * self.intensity[j] + w * self.intensity[rows + 1, np.maximum(nx, 0)], np.nan)
        return out, area, inten


def _fundamental(calibration: Calibration, a: int, b: int) -> np.ndarray:
    """``F`` with ``x_a^T F x_b = 0`` for undistorted pixels of cameras ``a`` and ``b``."""
    ca, cb = calibration[a], calibration[b]
    R = ca.R @ cb.R.T
    t = ca.t - R @ cb.t
    tx = np.array([[0.0, -t[2], t[1]], [t[2], 0.0, -t[0]], [-t[1], t[0], 0.0]])
    return np.linalg.inv(ca.K).T @ tx @ R @ np.linalg.inv(cb.K)


class _PairCost:
    """Robust epipolar cost of camera ``c`` against the reference, as a function of offset and drift."""

    def __init__(self, ref: LinkedDetections, other: LinkedDetections, Fm: np.ndarray, frames: np.ndarray,
                 scale_px: float, min_overlap: float) -> None:
        self.other, self.F, self.scale, self.min_overlap = other, Fm, scale_px, min_overlap
        self.s_ref = ref.times[frames]
        x = ref.xy[frames]                                                       # (J, N0, 2)
        self.x_ref = np.concatenate([x, np.ones(x.shape[:2] + (1,))], axis=2)    # homogeneous, NaN padded
        self.ok_ref = np.isfinite(x[..., 0])

    def with_scale(self, scale_px: float) -> "_PairCost":
        """The same cost with another robust scale."""
        sub = _PairCost.__new__(_PairCost)
        sub.__dict__.update(self.__dict__)
        sub.scale = scale_px
        return sub

    def subset(self, n: int) -> "_PairCost":
        """The same cost on ``n`` of its frames (evenly spread): cheaper, for a coarse search."""
        pick = np.unique(np.linspace(0, len(self.s_ref) - 1, n).round().astype(int))
        sub = _PairCost.__new__(_PairCost)
        sub.other, sub.F, sub.scale, sub.min_overlap = self.other, self.F, self.scale, self.min_overlap
        sub.s_ref, sub.x_ref, sub.ok_ref = self.s_ref[pick], self.x_ref[pick], self.ok_ref[pick]
        return sub

    def __call__(self, offset_s: float, drift: float) -> float:
        s_c = (self.s_ref - offset_s) / (1.0 + drift)
        xc, _, _ = self.other.at(s_c)                                            # (J, Nc, 2)
        has = np.isfinite(xc[..., 0]).any(axis=1)
        if has.mean() < self.min_overlap:
            return float("inf")
        xh = np.concatenate([np.nan_to_num(xc, nan=1e9), np.ones(xc.shape[:2] + (1,))], axis=2)
        lines = xh @ self.F.T                                                     # (J, Nc, 3) lines in the reference image
        norm = np.linalg.norm(lines[..., :2], axis=2)
        num = np.einsum("jnk,jmk->jnm", np.nan_to_num(self.x_ref), lines)         # (J, N0, Nc)
        dist = np.abs(num) / np.maximum(norm, 1e-12)[:, None, :]
        dist = np.where(np.isfinite(xc[..., 0])[:, None, :], dist, np.inf)
        dmin = dist.min(axis=2)                                                   # (J, N0)
        use = self.ok_ref & has[:, None]
        rho = 1.0 - np.exp(-(np.minimum(dmin[use], 1e6) / self.scale) ** 2)     # robust: Welsch
        return float(rho.mean()) if rho.size else float("inf")


def estimate_sync(detections: list[list[Detections]], timestamps: list[np.ndarray], calibration: Calibration,
                  reference: int = 0, params: SyncParams | None = None) -> ClockSync:
    """Each camera's clock offset and drift relative to ``reference`` from the marker motion.

    Parameters
    ----------
    detections : C lists of F_c :class:`Detections` (each camera its own frame count)
    timestamps : C arrays ``(F_c,)`` s, each camera's own clock (strictly increasing)
    calibration : the cameras, in the order of ``detections``

    Raises
    ------
    MocapInputError
        Mismatched inputs, or a camera whose detections never agree with the reference's
        within the searched offsets (too little overlap or no moving marker).
    """
    params = params or SyncParams()
    C = len(calibration)
    if len(detections) != C:
        raise MocapInputError(f"got detections of {len(detections)} cameras for a calibration of {C}")
    times = _check_timestamps(detections, timestamps)
    linked = [LinkedDetections(d, t, params.link_gate_px, undistort=calibration[c].undistort_pixels)
              for c, (d, t) in enumerate(zip(detections, times))]
    ref = linked[reference]
    frames = np.unique(np.linspace(0, len(ref.times) - 1, min(params.max_frames, len(ref.times))).round().astype(int))
    offset, drift, cost = np.zeros(C), np.zeros(C), np.full(C, np.nan)
    for c in range(C):
        if c == reference:
            continue
        f = _PairCost(ref, linked[c], _fundamental(calibration, reference, c), frames, params.epipolar_scale_px,
                      params.min_overlap)
        # Coarse: an offset grid (drift 0) on fewer frames, centred on the clocks' nominal start
        # difference; then a finer grid around its best.
        centre = float(ref.times[0] - linked[c].times[0])
        step = params.coarse_step_s
        grid = centre + np.arange(-params.max_offset_s, params.max_offset_s + 1e-12, 4 * step)
        coarse = f.subset(min(len(frames), 150))
        costs = np.array([coarse(o, 0.0) for o in grid])
        if not np.isfinite(costs).any():
            raise MocapInputError(f"camera {calibration.names[c]}: its frames never overlap the reference's "
                                  f"within +-{params.max_offset_s} s")
        grid = grid[int(np.argmin(costs))] + np.arange(-6 * step, 6 * step + 1e-12, 0.5 * step)
        o0 = float(grid[int(np.argmin([f(o, 0.0) for o in grid]))])
        # Fine: offset (at the middle of the take, where it does not trade off against the drift)
        # and drift together, in ms and ppm so that both are of order one.
        s_c = f.s_ref - o0
        s_mid = float(np.mean(s_c[(s_c >= linked[c].times[0]) & (s_c <= linked[c].times[-1])]))
        f = f.with_scale(params.fine_scale_px)
        lim = params.max_drift_ppm

        def cost_of(p: np.ndarray) -> float:
            d = p[1] * 1e-6
            return f(o0 + p[0] * 1e-3 - d * s_mid, d)  # the offset at s_mid is o0 + p[0] ms

        if lim > 0:
            res = minimize(cost_of, x0=np.zeros(2), method="Nelder-Mead", bounds=[(-4e3 * step, 4e3 * step), (-lim, lim)],
                           options={"initial_simplex": np.array([[0.0, 0.0], [1.0, 0.0], [0.0, min(lim, 50.0)]]),
                                    "xatol": 1e-3, "fatol": 1e-9, "maxiter": 400})
            x, fun = res.x, res.fun
        else:  # the clocks are known to run at one rate: the offset alone
            res = minimize(lambda p: cost_of(np.array([p[0], 0.0])), x0=np.zeros(1), method="Nelder-Mead",
                           bounds=[(-4e3 * step, 4e3 * step)],
                           options={"initial_simplex": np.array([[0.0], [1.0]]), "xatol": 1e-3, "fatol": 1e-9})
            x, fun = np.array([res.x[0], 0.0]), res.fun
        d = x[1] * 1e-6
        offset[c] = o0 + x[0] * 1e-3 - d * s_mid
        drift[c] = d
        cost[c] = float(fun)
    return ClockSync(reference, offset, drift, cost)


def read_timestamps_csv(path: str | Path) -> np.ndarray:
    """A camera's timestamps ``(F,)`` s from ``<video>.timestamps.csv`` (a ``frame,timestamp_s``
    header, then one row per frame: what ``simbench render`` writes beside each video).

    Raises
    ------
    InputFileError
        The file is missing, unreadable, or its timestamps are not finite and strictly increasing.
    """
    path = Path(path)
    fix = "give one row 'frame,timestamp_s' per video frame, timestamps in seconds, strictly increasing"
    if not path.is_file():
        raise InputFileError(path, "missing (--timestamps reads <video name>.timestamps.csv beside each video)", fix)
    try:
        data = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    except (ValueError, UnicodeDecodeError) as exc:
        raise InputFileError(path, f"cannot be read as numbers ({str(exc).splitlines()[0]})", fix) from None
    if data.shape[0] == 0 or data.shape[1] != 2:
        raise InputFileError(path, f"holds {data.shape[0]} rows of {data.shape[1]} columns", fix)
    t = data[:, 1]
    if not np.isfinite(t).all() or (len(t) > 1 and not (np.diff(t) > 0).all()):
        raise InputFileError(path, "has timestamps that are not finite or not strictly increasing", fix)
    return t


def resample_detections(detections: list[list[Detections]], timestamps: list[np.ndarray], sync: ClockSync,
                        gate_px: float = SyncParams.link_gate_px) -> list[list[Detections]]:
    """Every camera's detections at the reference camera's frame instants (``F_ref`` frames each).

    The reference camera's detections are returned as they are, but for its duplicated frames
    (:func:`duplicated_frames`: the previous instant's image under a later timestamp), whose
    blobs are interpolated to their timestamps between the frames around them. Another camera's
    are its blobs interpolated along their frame-to-frame links (:class:`LinkedDetections`) to
    the reference instants mapped onto its clock; a blob not linked across an instant, or an
    instant outside the camera's take, gives no detection.
    """
    times = _check_timestamps(detections, timestamps)
    s_ref = times[sync.reference]
    out: list[list[Detections]] = []
    for c, (d, t) in enumerate(zip(detections, times)):
        if c == sync.reference:
            cam = list(d)
            dup = np.flatnonzero(duplicated_frames(d))
            if len(dup):
                xy, area, inten = LinkedDetections(d, t, gate_px).at(t[dup])
                for i, k in enumerate(dup):
                    ok = np.isfinite(xy[i, :, 0])
                    cam[k] = Detections(xy[i, ok], area[i, ok], inten[i, ok])
            out.append(cam)
            continue
        xy, area, inten = LinkedDetections(d, t, gate_px).at(sync.to_camera_clock(c, s_ref))
        cam = []
        for k in range(len(s_ref)):
            ok = np.isfinite(xy[k, :, 0])
            cam.append(Detections(xy[k, ok], area[k, ok], inten[k, ok]))
        out.append(cam)
    return out
