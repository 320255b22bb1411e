"""2D trackers that keep marker labels from frame to frame in one camera.

All trackers share :class:`Tracker2D` (predict, gate, associate, update, vectorised over
markers) and are found by name through the registry::

    from mocap.trackers import make_tracker
    tracker = make_tracker("kalman", initial_xy, dt=1 / 30, rng=np.random.default_rng(0))
    idx = tracker.step(detections_xy)          # (M,) detection index per label, -1 for none

Built-in trackers: ``alpha_beta``, ``kalman``, ``condensation`` (seed 000) and ``imm``
(the project's own). See ``mocap/trackers/README.md`` for adding one.
"""

from mocap.trackers.base import COASTING, LOST, TRACKED, SearchArea, Tracker2D
from mocap.trackers.registry import (
    TRACKERS,
    TrackerNotFoundError,
    available_trackers,
    get_tracker,
    make_tracker,
    register_tracker,
    tracker_params,
    unregister_tracker,
)

# Imported for their registration side effect (after the registry exists).
from mocap.trackers.alpha_beta import AlphaBetaTracker  # noqa: E402
from mocap.trackers.kalman import KalmanTracker  # noqa: E402
from mocap.trackers.condensation import CondensationTracker, systematic_resample  # noqa: E402
from mocap.trackers.imm import IMMTracker  # noqa: E402

__all__ = [
    "AlphaBetaTracker",
    "COASTING",
    "CondensationTracker",
    "IMMTracker",
    "KalmanTracker",
    "LOST",
    "SearchArea",
    "TRACKED",
    "TRACKERS",
    "Tracker2D",
    "TrackerNotFoundError",
    "available_trackers",
    "get_tracker",
    "make_tracker",
    "register_tracker",
    "systematic_resample",
    "tracker_params",
    "unregister_tracker",
]
