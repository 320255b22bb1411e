"""Running a label-keeping 2D tracker over a sequence of detections, per camera.

:func:`track_camera` follows the ``M`` labels of one camera through ``F`` frames of
detections with any registered tracker (:mod:`mocap.trackers`); :func:`track_cameras`
does it for every camera of a rig and returns :class:`mocap.types.Tracks2D`.

The labels' first-frame positions come from label initialisation (e.g. a T-pose template
match, :mod:`mocap.labelling`); this module only takes them as ``initial_xy`` with NaN for
labels not visible at the start (those start lost; see :mod:`mocap.trackers.base`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Iterator, Sequence

import numpy as np

from mocap.trackers import LOST, make_tracker
from mocap.types import Detections, Tracks2D


@dataclass
class CameraTracks:
    """Tracking result of one camera.

    Unpacks as ``xy, predicted, status = track_camera(...)``.

    Attributes
    ----------
    xy : (F, M, 2) float
        The detection associated with each label, pixels; NaN where it had none.
    predicted : (F, M, 2) float
        Prior prediction of each label (centre of its search area) before the frame's
        detections were seen, pixels; frame 0 holds ``initial_xy``.
    status : (F, M) int8
        0 lost, 1 tracked, 2 coasting (:class:`mocap.types.Tracks2D` codes), after the
        frame's update.
    estimate : (F, M, 2) float
        Posterior position estimate after the frame's update, pixels (the prediction
        while coasting); NaN while lost.
    search_radius : (F, M) float
        Radius of the circle enclosing each label's gate in that frame, pixels.
    index : (F, M) int
        Index of each label's detection in that frame's detections, -1 for none.
    """

    xy: np.ndarray
    predicted: np.ndarray
    status: np.ndarray
    estimate: np.ndarray
    search_radius: np.ndarray
    index: np.ndarray

    def __iter__(self) -> Iterator[np.ndarray]:
        return iter((self.xy, self.predicted, self.status))


def _points(frame: Detections | np.ndarray, f: int) -> np.ndarray:
    xy = frame.xy if isinstance(frame, Detections) else np.asarray(frame, dtype=np.float64)
    if xy.size == 0:
        return np.zeros((0, 2))
    if xy.ndim != 2 or xy.shape[1] != 2:
        raise ValueError(f"detections of frame {f} must be Detections or an (n, 2) pixel array, got shape {xy.shape}")
    return xy


def track_camera(
    detections: Sequence[Detections | np.ndarray],
    initial_xy: np.ndarray,
    labels: Sequence[str],
    tracker: str = "kalman",
    dt: float = 1.0 / 30.0,
    rng: np.random.Generator | None = None,
    **params: Any,
) -> CameraTracks:
    """Track labelled markers through one camera's frames.

    Parameters
    ----------
    detections : sequence of F :class:`~mocap.types.Detections` (or ``(n, 2)`` px arrays)
        Detections of each frame, in any order.
    initial_xy : (M, 2) float
        Position of every label in frame 0, pixels; NaN for labels not visible then.
    labels : sequence of M str
        Label names (only their number is used here; kept for messages).
    tracker : str, default "kalman"
        Registry name or ``"module:Class"`` (see :mod:`mocap.trackers.registry`).
    dt : float, default 1/30
        Frame interval in seconds.
    rng : numpy.random.Generator
        Generator for stochastic trackers; required (pass ``np.random.default_rng(seed)``).
    **params
        Tracker parameters (see :func:`mocap.trackers.tracker_params`).

    Returns
    -------
    CameraTracks
        ``xy``, ``predicted``, ``status`` (unpackable) plus ``estimate``,
        ``search_radius`` and ``index``.

    Notes
    -----
    Frame 0 is associated to ``initial_xy`` (gated by the new tracker's search area) and
    updated without a prediction; every later frame is one ``predict, associate,
    update`` step.
    """
    if rng is None:
        raise ValueError("track_camera needs rng=np.random.default_rng(seed): trackers never use the global RNG")
    init = np.asarray(initial_xy, dtype=np.float64)
    if init.ndim != 2 or init.shape[1] != 2 or init.shape[0] != len(labels):
        raise ValueError(f"initial_xy must be (M, 2) with M = len(labels) = {len(labels)}, got shape {init.shape}")
    F, M = len(detections), len(labels)
    trk = make_tracker(tracker, init, dt, rng, **params)
    xy = np.full((F, M, 2), np.nan)
    predicted = np.full((F, M, 2), np.nan)
    estimate = np.full((F, M, 2), np.nan)
    status = np.zeros((F, M), dtype=np.int8)
    radius = np.full((F, M), np.nan)
    index = np.full((F, M), -1, dtype=np.intp)
    for f in range(F):
        det = _points(detections[f], f)
        if f > 0:
            trk.predict()
        predicted[f] = trk.x_pred
        radius[f] = trk.search_radius
        idx = trk.associate(det)
        got = idx >= 0
        z = np.full((M, 2), np.nan)
        z[got] = det[idx[got]]
        trk.update(z)
        xy[f] = z
        index[f] = idx
        status[f] = trk.status
        estimate[f] = trk.x_est
    estimate[status == LOST] = np.nan
    return CameraTracks(xy=xy, predicted=predicted, status=status, estimate=estimate, search_radius=radius, index=index)


def track_cameras(
    detections: Sequence[Sequence[Detections | np.ndarray]],
    initial_xy: np.ndarray,
    labels: Sequence[str],
    camera_names: Sequence[str],
    tracker: str = "kalman",
    dt: float = 1.0 / 30.0,
    rng: np.random.Generator | None = None,
    **params: Any,
) -> Tracks2D:
    """Track labelled markers in every camera independently.

    Parameters
    ----------
    detections : C sequences of F detections
        ``detections[c][f]``: :class:`~mocap.types.Detections` of camera ``c``, frame ``f``.
    initial_xy : (C, M, 2) float
        Frame-0 position of every label in every camera, pixels (NaN: not visible).
    labels : sequence of M str
    camera_names : sequence of C str
    tracker, dt, **params
        As :func:`track_camera`.
    rng : numpy.random.Generator
        Split into one independent child generator per camera.

    Returns
    -------
    mocap.types.Tracks2D
        ``xy`` the associated detections, ``predicted_xy`` the posterior estimates (the
        prediction while coasting, NaN while lost), ``status``; all ``(F, C, M, ...)``.
    """
    if rng is None:
        raise ValueError("track_cameras needs rng=np.random.default_rng(seed): trackers never use the global RNG")
    C = len(camera_names)
    init = np.asarray(initial_xy, dtype=np.float64)
    if init.shape != (C, len(labels), 2):
        raise ValueError(f"initial_xy must be (C, M, 2) = ({C}, {len(labels)}, 2) for {C} cameras and {len(labels)} labels, got {init.shape}")
    if len(detections) != C:
        raise ValueError(f"detections must hold one sequence per camera ({C}), got {len(detections)}")
    n_frames = {len(d) for d in detections}
    if len(n_frames) > 1:
        raise ValueError(f"every camera needs the same number of frames, got {sorted(n_frames)}")
    results = [
        track_camera(detections[c], init[c], labels, tracker=tracker, dt=dt, rng=child, **params)
        for c, child in enumerate(rng.spawn(C))
    ]
    F, M = (n_frames.pop() if n_frames else 0), len(labels)
    if C == 0:
        empty = np.zeros((F, 0, M, 2))
        return Tracks2D(list(labels), empty, empty.copy(), np.zeros((F, 0, M), np.int8), [])
    return Tracks2D(
        labels=list(labels),
        xy=np.stack([r.xy for r in results], axis=1),
        predicted_xy=np.stack([r.estimate for r in results], axis=1),
        status=np.stack([r.status for r in results], axis=1),
        camera_names=list(camera_names),
    )
