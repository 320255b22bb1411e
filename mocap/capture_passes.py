"""The marker pipeline's reconstruction passes: re-associate the detections with the 3D
points, reconstruct from them, repair label swaps, as often as the pipeline asks.

:func:`first_reconstruction` triangulates the labelled 2D tracks once and gives the passes'
state (:class:`CapturePasses`); :mod:`mocap.marker_pipeline` then runs
:meth:`CapturePasses.run` (guided by the trajectories or by the fitted skeleton's markers) and
:meth:`CapturePasses.recentre` on it.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from mocap.calibration import Calibration
from mocap.reassociation import ReassociationParams, reassociate
from mocap.reconstruction import ReconstructionParams, reconstruct
from mocap.swap_repair import SwapRepairParams, find_jumps, repair_swaps
from mocap.types import Detections, Tracks2D, Trajectories


@dataclass
class CapturePasses:
    """The state the reassociate -> reconstruct -> repair passes hand on: the measurements
    (``measured``), the trajectories triangulated from them, the repaired swaps and jumps
    (``swaps``) and the re-association counts (``stats``)."""

    detections: list[list[Detections]]
    calibration: Calibration
    times: np.ndarray
    reconstruction: ReconstructionParams
    reassociation: ReassociationParams | None
    swap_repair: SwapRepairParams | None
    measured: Tracks2D
    traj: Trajectories
    swaps: list = field(default_factory=list)
    stats: dict[str, int] = field(default_factory=dict)
    # The passes often hand a step the inputs it had before (on the bench's quickstart frames
    # three of the five reconstructions triangulate exactly the tracks of the one before, and the
    # last re-association repeats the second); both steps are pure functions of their inputs, so
    # a bit-identical repeat takes a copy of the earlier result.
    _reconstructed: _LastCalls = field(default_factory=lambda: _LastCalls(1), repr=False, compare=False)
    _reassociated: _LastCalls = field(default_factory=lambda: _LastCalls(2), repr=False, compare=False)

    def _reconstruct(self) -> Trajectories:
        """``reconstruct`` of the measurements (a copy of the last result for the same inputs)."""
        m = self.measured
        key = (list(m.labels), list(m.camera_names), dataclasses.replace(self.reconstruction), id(self.calibration))
        arrays = (m.xy, m.predicted_xy, m.status, self.times)
        hit = self._reconstructed.get(key, arrays)
        if hit is not None:
            return _copied(hit[0])
        traj = reconstruct(m, self.calibration, self.reconstruction, times=self.times)
        self._reconstructed.put(key, arrays, (_copied(traj), self.calibration))
        return traj

    def _reassociate(self, points: np.ndarray | None, gate_px: np.ndarray | None) -> tuple[Tracks2D, dict[str, int]]:
        """``reassociate`` of the measurements with the detections (a copy of an earlier result
        for the same inputs)."""
        m, p = self.measured, self.reassociation
        key = (list(m.labels), list(m.camera_names), None if p is None else dataclasses.replace(p),
               id(self.calibration), id(self.detections), points is None, gate_px is None)
        arrays = (m.xy, self.traj.xyz, self.traj.filled, points, gate_px)
        hit = self._reassociated.get(key, arrays)
        if hit is None:
            # The detections and calibration ride along so that their ids cannot be reused.
            hit = reassociate(m, self.detections, self.traj, self.calibration, p, points=points, gate_px=gate_px)
            hit = (hit[0], dict(hit[1]), self.detections, self.calibration)
            self._reassociated.put(key, arrays, hit)
        # As reassociate builds it: new measurements, the trackers' estimates and status kept.
        return Tracks2D(list(m.labels), hit[0].xy.copy(), m.predicted_xy, m.status, list(m.camera_names)), dict(hit[1])

    def add_stats(self, stats: dict[str, int], prefix: str = "") -> None:
        for k, v in stats.items():
            self.stats[prefix + k] = self.stats.get(prefix + k, 0) + v

    def repair(self, jumps: bool = True) -> None:
        """Undo label swaps (and, with ``jumps``, drop label jumps) in ``traj`` and ``measured``."""
        self.traj, self.measured = _repair_swaps(self.traj, self.measured, self.swap_repair, self.swaps, jumps=jumps)

    def recentre(self, refined: list[list[Detections]]) -> None:
        """Move every measurement to the centroid ``refined`` gives its blob (the same blobs,
        in the same order, as ``detections``), take ``refined`` as the detections, and
        triangulate again: the labels stay as they are."""
        xy = self.measured.xy.copy()
        for c, (old_cam, new_cam) in enumerate(zip(self.detections, refined)):
            for f, (old, new) in enumerate(zip(old_cam, new_cam)):
                if old is new or len(old) == 0:
                    continue
                m = xy[f, c]
                ok = np.flatnonzero(np.isfinite(m).all(axis=1))
                if len(ok) == 0:
                    continue
                gap = np.abs(m[ok, None, :] - old.xy[None, :, :]).max(axis=2)
                j = np.argmin(gap, axis=1)
                same = gap[np.arange(len(ok)), j] < 1e-9  # a measurement is one of the blobs
                m[ok[same]] = new.xy[j[same]]
        self.measured = Tracks2D(self.measured.labels, xy, self.measured.predicted_xy, self.measured.status,
                                 self.measured.camera_names)
        self.detections = refined
        self.traj = self._reconstruct()
        self.repair()

    def run(self, points: np.ndarray | None = None, gate_px: np.ndarray | None = None, prefix: str = "",
            jumps: bool = True) -> None:
        """One pass: re-associate the detections with the 3D points (the trajectories, or
        ``points`` within ``gate_px``), reconstruct from them, repair swaps."""
        self.measured, stats = self._reassociate(points, gate_px)
        self.add_stats(stats, prefix)
        self.traj = self._reconstruct()
        self.repair(jumps)


def first_reconstruction(tracks: Tracks2D, detections: list[list[Detections]], calibration: Calibration,
                         times: np.ndarray, reconstruction: ReconstructionParams,
                         reassociation: ReassociationParams | None, swap_repair: SwapRepairParams | None,
                         use_model: bool) -> CapturePasses:
    """Triangulate the labelled tracks once and repair swaps: the passes' starting state
    (``reconstruction``, ``reassociation`` and ``swap_repair`` are the pipeline's settings;
    ``use_model``: the labels came from the subject's model, not from 2D trackers)."""
    # Labels from the model are already consistent across cameras: no cross-camera re-labelling
    # (it exists to mend 2D trackers' label mistakes).
    first = dataclasses.replace(reconstruction, relabel_gate_px=0) if use_model else reconstruction
    traj = reconstruct(tracks, calibration, first, times=np.asarray(times, float), detections=None if use_model else detections)
    # The first reconstruction re-labels views across cameras and re-acquires lost
    # labels from the raw detections; later ones triangulate exactly the measurements
    # the re-association kept (it may drop partly hidden blobs on purpose).
    later = dataclasses.replace(reconstruction, relabel_gate_px=0)
    # Swap and jump repair undo what 2D trackers do to labels; labels from the model cannot swap
    # (one point per label, checked against the model every frame), and on real motion the
    # repair's motion-continuity test removed good samples (bvh_walk: 0.994 -> 0.980 reconstructed).
    swap_params = None if use_model else swap_repair
    passes = CapturePasses(detections, calibration, np.asarray(times, float), later, reassociation, swap_params,
                           tracks, traj)
    passes.repair()
    return passes


class _LastCalls:
    """The inputs (settings ``key``, copies of ``arrays``) and results of the last ``n`` calls."""

    def __init__(self, n: int) -> None:
        self.n = n
        self.calls: list[tuple] = []

    def get(self, key: tuple, arrays: tuple) -> tuple | None:
        for k, a, result in self.calls:
            if k == key and all(_same_bits(x, y) for x, y in zip(a, arrays)):
                return result
        return None

    def put(self, key: tuple, arrays: tuple, result: tuple) -> None:
        copies = tuple(None if x is None else np.array(x, copy=True) for x in arrays)
        self.calls = [(key, copies, result)] + self.calls[: self.n - 1]


def _same_bits(a: np.ndarray | None, b: np.ndarray | None) -> bool:
    """``a`` and ``b`` hold the same bits (NaN payloads and the sign of zero included)."""
    if a is None or b is None:
        return a is None and b is None
    a, b = np.asarray(a), np.asarray(b)
    return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()


def _copied(traj: Trajectories) -> Trajectories:
    """``traj`` with its own arrays (the memo's copy stays as reconstructed)."""
    return Trajectories(list(traj.labels), traj.xyz.copy(), traj.times.copy(), traj.filled.copy(),
                        traj.residual_px.copy(), traj.n_views.copy())


def _repair_swaps(traj: Trajectories, measured: Tracks2D, params: SwapRepairParams | None,
                  events_log: list, jumps: bool = True) -> tuple[Trajectories, Tracks2D]:
    """Undo 3D label swaps in the trajectories and in the 2D measurements behind them."""
    if params is None:
        return traj, measured
    xyz, events = repair_swaps(traj.xyz, params)
    jumps = find_jumps(xyz, params) if jumps else np.zeros(xyz.shape[:2], bool)
    if not events and not jumps.any():
        return traj, measured
    xy = measured.xy.copy()
    filled, res, nv = traj.filled.copy(), traj.residual_px.copy(), traj.n_views.copy()
    for f, a, b in events:
        xy[f:, :, [a, b]] = xy[f:, :, [b, a]]
        for arr in (filled, res, nv):
            arr[f:, [a, b]] = arr[f:, [b, a]]
    # A label that jumped onto another marker loses those samples (and their views).
    xyz[jumps] = np.nan
    xy[jumps[:, None, :].repeat(xy.shape[1], axis=1)] = np.nan
    nv = np.where(jumps, 0, nv)
    events_log.extend(("swap", f, a, b) for f, a, b in events)
    events_log.extend(("jump", int(f), int(m)) for f, m in zip(*np.nonzero(jumps)))
    return (Trajectories(list(traj.labels), xyz, traj.times, filled, res, nv),
            Tracks2D(measured.labels, xy, measured.predicted_xy, measured.status, measured.camera_names))
