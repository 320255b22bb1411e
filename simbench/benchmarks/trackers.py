"""``simbench bench trackers``: the 2D trackers' per-frame cost (seed 000 Tables V-VII),
with a per-marker filterpy loop as the reference measured in the same run.

:func:`run_tracker_benchmark` times the whole per-frame tracking call (predict +
associate + update, :meth:`~mocap.trackers.Tracker2D.step`) of every tracker for 1..30
markers moving on simple smooth paths in a 640x480 image (detections = true positions +
0.1 px noise, shuffled), with ``time.perf_counter_ns``, and reports the 5th percentile,
median, 95th percentile and maximum in ms. In the same run it times a *reference*: one
``filterpy.kalman.KalmanFilter`` per marker, predicted and updated in a Python loop,
with the same gated Hungarian association (:func:`mocap.trackers.gating.gated_assignment`),
and reports how many times faster the vectorised Kalman tracker is. The contenders take
turns by blocks of 10 frames, so changes in the machine's load affect them alike.
``simbench bench trackers`` prints :func:`format_benchmark_table` of it.

The quick 2D robustness check of seed 000's failure categories is :mod:`mocap.tracker_trials`.
"""

from __future__ import annotations

import gc
import time
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
from filterpy.common import Q_discrete_white_noise
from filterpy.kalman import KalmanFilter
from scipy.linalg import block_diag

from mocap.tracker_trials import IMAGE_SIZE
from mocap.trackers import KalmanTracker, available_trackers, make_tracker, tracker_params
from mocap.trackers.gating import gated_assignment

REFERENCE_NAME = "filterpy_loop"


# ----------------------------------------------------------------------------- cost
@dataclass(frozen=True)
class BenchmarkRow:
    """Per-frame tracking cost of one tracker for one marker count, in milliseconds."""

    tracker: str
    n_markers: int
    p5_ms: float
    median_ms: float
    p95_ms: float
    max_ms: float


@dataclass
class BenchmarkTable:
    """Result of :func:`run_tracker_benchmark`.

    Attributes
    ----------
    rows : list of BenchmarkRow
        One per tracker (including :data:`REFERENCE_NAME`) and marker count.
    speedup : dict int -> float
        Median cost of the filterpy loop over that of the vectorised ``kalman``, per
        marker count.
    n_frames : int
    """

    rows: list[BenchmarkRow]
    speedup: dict[int, float] = field(default_factory=dict)
    n_frames: int = 0

    def row(self, tracker: str, n_markers: int) -> BenchmarkRow:
        for r in self.rows:
            if r.tracker == tracker and r.n_markers == n_markers:
                return r
        raise KeyError(f"no benchmark row for tracker {tracker!r} with {n_markers} markers")


def smooth_paths(n_markers: int, n_frames: int, rng: np.random.Generator, dt: float = 1.0 / 30.0) -> np.ndarray:
    """Simple smooth 2D trajectories: markers on a jittered grid, each circling slowly.

    Returns
    -------
    (F, M, 2) float
        Pixel positions inside a 640x480 image.
    """
    W, H = IMAGE_SIZE
    cols = int(np.ceil(np.sqrt(n_markers * W / H)))
    rows = int(np.ceil(n_markers / cols))
    gx, gy = np.meshgrid((np.arange(cols) + 0.5) * W / cols, (np.arange(rows) + 0.5) * H / rows)
    centres = np.stack([gx.ravel(), gy.ravel()], axis=1)[:n_markers]
    centres += rng.uniform(-5, 5, centres.shape)
    radius = rng.uniform(8.0, 20.0, n_markers)  # px
    omega = rng.choice([-1.0, 1.0], n_markers) * 2 * np.pi / rng.uniform(2.0, 4.0, n_markers)  # rad/s
    phase = rng.uniform(0, 2 * np.pi, n_markers)
    t = np.arange(n_frames)[:, None] * dt
    ang = phase + omega * t
    return np.stack([centres[:, 0] + radius * np.cos(ang), centres[:, 1] + radius * np.sin(ang)], axis=-1)


def _noisy_shuffled(true_xy: np.ndarray, noise_px: float, rng: np.random.Generator) -> list[np.ndarray]:
    F, M, _ = true_xy.shape
    noisy = true_xy + rng.normal(0.0, noise_px, true_xy.shape)
    return [noisy[f, rng.permutation(M)] for f in range(F)]


def _percentiles(ns: np.ndarray) -> tuple[float, float, float, float]:
    ms = np.asarray(ns, dtype=np.float64) * 1e-6
    p5, p50, p95 = np.percentile(ms, [5, 50, 95])
    return float(p5), float(p50), float(p95), float(ms.max())


def _tracker_step(name: str, true_xy: np.ndarray, dets: list[np.ndarray], dt: float, rng: np.random.Generator):
    """The per-frame call of a registered tracker, started on frame 0."""
    trk = make_tracker(name, true_xy[0], dt, rng)
    trk.update(dets[0][trk.associate(dets[0])])
    return trk.step


def _filterpy_loop_step(true_xy: np.ndarray, dets: list[np.ndarray], dt: float):
    """Reference per-frame call: one filterpy KalmanFilter per marker in a Python loop.

    Same model as the ``kalman`` tracker's defaults (constant velocity, R, initial P),
    with a constant ``Q`` (``accel_std`` of a still marker: less work than the speed
    dependent Q of the vectorised tracker, so the speed-up reported is conservative),
    and the same gated association (:func:`~mocap.trackers.gating.gated_assignment` on
    the predicted positions and ``diag(S)``).
    """
    defaults = tracker_params("kalman")
    r = defaults["measurement_std_px"] ** 2
    threshold = float(-2.0 * np.log1p(-defaults["gate_probability"]))
    proto = KalmanTracker(true_xy[0], dt, np.random.default_rng(0))
    q = Q_discrete_white_noise(dim=2, dt=dt, var=defaults["accel_std"] ** 2)
    M = true_xy.shape[1]
    filters = []
    for m in range(M):
        kf = KalmanFilter(dim_x=4, dim_z=2)
        kf.x = np.array([[true_xy[0, m, 0]], [0.0], [true_xy[0, m, 1]], [0.0]])
        kf.F = proto.F
        kf.H = proto.H
        kf.R = proto.R
        kf.Q = block_diag(q, q)
        kf.P = proto.P[m].copy()
        filters.append(kf)
    centre = np.empty((M, 2))
    svar = np.empty((M, 2))

    def step(d: np.ndarray) -> np.ndarray:
        for m, kf in enumerate(filters):  # the per-marker loop being measured
            kf.predict()
            centre[m, 0] = kf.x[0, 0]
            centre[m, 1] = kf.x[2, 0]
            svar[m, 0] = kf.P[0, 0] + r
            svar[m, 1] = kf.P[2, 2] + r
        idx = gated_assignment(centre, svar, d, threshold)
        for m, kf in enumerate(filters):
            kf.update(d[idx[m]] if idx[m] >= 0 else None)
        return idx

    return step


def _time_interleaved(steps: list, dets: list[np.ndarray], block: int = 10) -> np.ndarray:
    """(len(steps), F - 1) ns: every contender's per-frame call on frames 1..F-1.

    Contenders take turns by blocks of ``block`` frames, so a change in the machine's
    load during the run affects them alike (their ratios stay fair) while each keeps
    its own data in cache within a block, as a tracker would in a capture loop.
    """
    clock = time.perf_counter_ns
    F = len(dets)
    out = np.empty((len(steps), F - 1), dtype=np.int64)
    for start in range(1, F, block):
        for k, step in enumerate(steps):
            row = out[k]
            for f in range(start, min(start + block, F)):
                d = dets[f]
                t0 = clock()
                step(d)
                row[f - 1] = clock() - t0
    return out


def run_tracker_benchmark(
    marker_counts: Sequence[int] = (1, 5, 10, 15, 20, 25, 30),
    n_frames: int = 200,
    seed: int = 0,
    trackers: Sequence[str] | None = None,
    dt: float = 1.0 / 30.0,
    noise_px: float = 0.1,
    include_reference: bool = True,
) -> BenchmarkTable:
    """Time the per-frame tracking call of each tracker against the number of markers.

    Parameters
    ----------
    marker_counts : sequence of int, default (1, 5, 10, 15, 20, 25, 30)
    n_frames : int, default 200
        Frames per run (the first one initialises; the others are timed).
    seed : int, default 0
        Seed of the trajectories, the detection noise and the stochastic trackers.
    trackers : sequence of str, optional
        Registry names; default every registered tracker.
    dt : float, default 1/30
        Frame interval, s.
    noise_px : float, default 0.1
        Detection noise standard deviation, px.
    include_reference : bool, default True
        Also time the per-marker filterpy loop (:data:`REFERENCE_NAME`).

    Returns
    -------
    BenchmarkTable
    """
    if n_frames < 2:
        raise ValueError(f"n_frames must be >= 2 (one initial frame, at least one timed), got {n_frames}")
    names = list(trackers) if trackers is not None else available_trackers()
    rng = np.random.default_rng(seed)
    rows: list[BenchmarkRow] = []
    speedup: dict[int, float] = {}
    gc_was_enabled = gc.isenabled()
    try:
        for M in marker_counts:
            true_xy = smooth_paths(int(M), n_frames, rng, dt)
            dets = _noisy_shuffled(true_xy, noise_px, rng)
            contenders = [(name, _tracker_step(name, true_xy, dets, dt, np.random.default_rng([seed, M]))) for name in names]
            if include_reference:
                contenders.append((REFERENCE_NAME, _filterpy_loop_step(true_xy, dets, dt)))
            gc.collect()
            gc.disable()  # no collector pauses inside the timed calls
            ns = _time_interleaved([step for _, step in contenders], dets)
            if gc_was_enabled:
                gc.enable()
            medians = {}
            for (name, _), t in zip(contenders, ns):
                rows.append(BenchmarkRow(name, int(M), *_percentiles(t)))
                medians[name] = rows[-1].median_ms
            if include_reference and "kalman" in medians:
                speedup[int(M)] = medians[REFERENCE_NAME] / medians["kalman"]
    finally:
        if gc_was_enabled:
            gc.enable()
    return BenchmarkTable(rows=rows, speedup=speedup, n_frames=n_frames)


def format_benchmark_table(table: BenchmarkTable) -> str:
    """Seed 000 Tables V-VII layout: one block per tracker, one line per marker count."""
    lines: list[str] = []
    names = list(dict.fromkeys(r.tracker for r in table.rows))
    for name in names:
        title = f"{name} (per-marker filterpy KalmanFilter loop, reference)" if name == REFERENCE_NAME else name
        lines.append(f"{title}: per-frame tracking cost over {table.n_frames} frames (predict + associate + update), ms")
        lines.append(f"{'Markers':>8} {'5th pct':>9} {'Median':>9} {'95th pct':>9} {'Maximum':>9}")
        for r in table.rows:
            if r.tracker == name:
                lines.append(f"{r.n_markers:>8d} {r.p5_ms:>9.4f} {r.median_ms:>9.4f} {r.p95_ms:>9.4f} {r.max_ms:>9.4f}")
        lines.append("")
    if table.speedup:
        lines.append("Vectorised kalman vs per-marker filterpy loop (ratio of medians):")
        lines.append("  " + "  ".join(f"{m}: {s:.1f}x" for m, s in table.speedup.items()))
    return "\n".join(lines).rstrip() + "\n"
