"""2D trackers that keep marker labels from frame to frame in one camera.

All trackers share :class:`Tracker2D` (predict, gate, associate, update, vectorised over
markers) and are found by name through the registry::

    from mocap.trackers import make_tracker
    tracker = make_tracker("kalman", initial_xy, dt=1 / 30, rng=np.random.default_rng(0))
    idx = tracker.step(detections_xy)          # (M,) detection index per label, -1 for none

Built-in trackers: seed 000's three as OpenMoCap had them, ``alpha_beta`` (fixed search
circle), ``kalman_openmocap`` and ``condensation`` (:mod:`mocap.trackers.openmocap`), and
the bench's own, ``alpha_beta_adaptive`` (search area grows with the residuals and the
speed), ``kalman`` (the marker pipeline's default), ``condensation_drift`` and ``imm``.
A bare name is the paper's tracker, except ``kalman``: it stays the bench's tuned filter
that scenarios name by default; the paper's is ``kalman_openmocap``. See
``mocap/trackers/README.md`` for adding one.
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
from mocap.trackers.openmocap import AlphaBetaTracker, CondensationTracker, OpenMoCapKalmanTracker  # noqa: E402
from mocap.trackers.alpha_beta import AdaptiveAlphaBetaTracker  # noqa: E402
from mocap.trackers.kalman import KalmanTracker  # noqa: E402
from mocap.trackers.condensation import DriftCondensationTracker, systematic_resample  # noqa: E402
from mocap.trackers.imm import IMMTracker  # noqa: E402

__all__ = [
    "AdaptiveAlphaBetaTracker",
    "AlphaBetaTracker",
    "COASTING",
    "CondensationTracker",
    "DriftCondensationTracker",
    "IMMTracker",
    "KalmanTracker",
    "LOST",
    "OpenMoCapKalmanTracker",
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
