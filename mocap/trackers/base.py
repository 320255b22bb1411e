"""The one interface of every 2D label-keeping tracker (the gated association they share
is in :mod:`mocap.trackers.gating`).

A tracker follows ``M`` labelled markers in ONE camera. Each frame it runs

1. :meth:`Tracker2D.predict` -- advance every label's state to the new frame;
2. :meth:`Tracker2D.gate` -- the search area of every label, from the tracker's own
   uncertainty: centre ``(M, 2)`` px and a diagonal gate covariance ``(M, 2, 2)`` px**2
   (per image axis, or circular), gated at a chi-square quantile;
3. :meth:`Tracker2D.associate` -- detections ``(n, 2)`` px to labels, ``(M,)`` index or -1,
   by the Hungarian method (``scipy.optimize.linear_sum_assignment``) on a cost of
   squared Mahalanobis distances; pairs outside a gate are forbidden;
4. :meth:`Tracker2D.update` -- correct with ``z (M, 2)`` px, NaN where a label got nothing.

:meth:`Tracker2D.step` does the three calls of one frame. Everything is vectorised over
markers: there is no per-marker Python loop on the hot path.

Loss handling (shared by all trackers)
--------------------------------------
A label with no detection *coasts* on its prediction (status :data:`COASTING`); its gate
keeps growing with the tracker's uncertainty. After more than ``max_coast_frames``
consecutive frames without a detection it is *lost* (:data:`LOST`): by default its
velocity is dropped (the motion model is no longer trusted; a tracker may keep it, as
``imm`` does) and its gate keeps growing up to ``max_gate_px``. A lost label is *re-acquired* by a detection inside its grown gate that
no tracked or coasting label claims (lost labels are associated in a second round, with
the left-over detections only); the filter then restarts at that detection.
Labels whose initial position is NaN start lost and have no gate: nothing can be
associated to them safely, so they stay lost until :meth:`Tracker2D.reset_labels` gives
them a position (e.g. from the labelling step).

Status codes are those of :class:`mocap.types.Tracks2D`: 0 lost, 1 tracked, 2 coasting.

Writing a tracker
-----------------
Subclass :class:`Tracker2D`, give it a ``name`` and implement four hooks, all on arrays of
every label at once:

``_predict()``
    advance the state; set ``self._centre`` ``(M, 2)`` px (the prior position, centre of
    the search area) and ``self._svar`` px**2, the prior variance of the predicted
    measurement (e.g. the diagonal of ``S = H P H' + R``): ``(M, 2)`` per image axis, or
    ``(M, 1)`` for a circular gate (faster).
``_correct(z, has)``
    measurement update of the labels where ``has`` ``(M,)`` is True, ``z`` ``(M, 2)`` px
    (NaN rows where ``has`` is False: those labels keep their prior); ``has`` is None
    when every label has a measurement (the common case, kept cheap).
``_restart(mask, xy)``
    re-initialise the labels in ``mask`` at ``xy`` ``(M, 2)`` px with no velocity.
``x_est`` (property)
    ``(M, 2)`` px posterior position estimate.

Optionally override ``_drop_velocity(mask)`` (called when labels become lost) and
``_association_cost(d2, inside)`` (the cost used when the assignment is ambiguous).
After an ambiguous association ``self._contested`` ``(M,)`` marks labels whose gate held
several detections or whose detection lay in several gates (``None`` otherwise); a
tracker may use it in ``_correct``. A tracker's ``_associate`` (the one association path
of both ``associate`` and ``step``) may also set ``self._shared_z`` ``(M, 2)`` px (NaN
rows elsewhere): a blob that a label without a
detection of its own shares with another label (two markers merged into one blob). The
filter is then corrected with it and the label does not count towards loss, but it
stays ``COASTING`` with no detection (``associate`` stays one-to-one).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from scipy.spatial.distance import cdist

from mocap.trackers.gating import gated_hungarian, mahalanobis_sq, unique_gated_pairs
from mocap.types import COASTING, LOST, TRACKED  # a label's status (defined with Tracks2D)



@dataclass(frozen=True)
class SearchArea:
    """Where each label expects its marker in the current frame.

    Attributes
    ----------
    centre : (M, 2) float
        Predicted marker positions in pixels (NaN for labels without a position).
    covariance : (M, 2, 2) float
        Gate covariance in px**2; a detection ``d`` is inside label ``m``'s gate when
        ``(d - centre[m])' inv(covariance[m]) (d - centre[m]) <= threshold``.
    threshold : float
        Squared-Mahalanobis gate threshold (chi-square, 2 degrees of freedom).
    """

    centre: np.ndarray
    covariance: np.ndarray
    threshold: float

    @property
    def radius(self) -> np.ndarray:
        """(M,) float: radius in pixels of the circle enclosing each gate ellipse."""
        largest = np.linalg.eigvalsh(self.covariance)[:, -1]
        return np.sqrt(self.threshold * largest)

    def contains(self, xy: np.ndarray) -> np.ndarray:
        """(M, n) bool: which of the points ``xy`` ``(n, 2)`` px lie inside which gate."""
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        r = xy[None, :, :] - self.centre[:, None, :]
        info = np.linalg.inv(self.covariance)
        d2 = np.einsum("mni,mij,mnj->mn", r, info, r)
        return d2 <= self.threshold


def _as_positions(initial_xy: np.ndarray) -> np.ndarray:
    xy = np.array(initial_xy, dtype=np.float64)
    if xy.ndim != 2 or xy.shape[1] != 2:
        raise ValueError(f"initial_xy must be an (M, 2) array of pixel positions, got shape {xy.shape}")
    return xy


def check_positive(**values: float) -> None:
    """Refuse a tracker parameter that is not > 0 (NaN included): ``ValueError`` naming the
    first such keyword and its value."""
    _check_each(values, lambda v: v > 0, "positive")


def check_nonnegative(**values: float) -> None:
    """Refuse a tracker parameter that is not >= 0 (NaN included), as :func:`check_positive`."""
    _check_each(values, lambda v: v >= 0, ">= 0")


def _check_each(values: dict[str, float], ok: Callable[[float], bool], what: str) -> None:
    for key, val in values.items():
        if not ok(val):
            raise ValueError(f"{key} must be {what}, got {val!r}")


class Tracker2D:
    """Base class of the label-keeping 2D trackers of one camera.

    Parameters
    ----------
    initial_xy : (M, 2) float
        Pixel position of every label in the first frame; NaN for labels not visible
        (those start lost).
    dt : float
        Frame interval in seconds (e.g. ``1/30``).
    rng : numpy.random.Generator
        Random generator (used by stochastic trackers; kept by all for a uniform API).
    max_coast_frames : int, default 15
        Frames a label may coast on its prediction without a detection before it is
        marked lost.
    gate_probability : float, default 0.999
        Probability mass of the predicted-measurement distribution inside the gate;
        the squared-Mahalanobis threshold is the chi-square (2 dof) quantile,
        ``-2 ln(1 - p)``.
    min_gate_px, max_gate_px : float, default 2.0 and 120.0
        Bounds of the gate radius along each axis, in pixels.
    """

    #: Registry name, e.g. ``"kalman"``.
    name: ClassVar[str] = ""
    #: True for trackers whose ``_predict`` sets the gates itself with
    #: :meth:`_set_radius` (then ``predict`` skips :meth:`_set_info`).
    _sets_own_gate: ClassVar[bool] = False

    def __init__(
        self,
        initial_xy: np.ndarray,
        dt: float,
        rng: np.random.Generator,
        *,
        max_coast_frames: int = 15,
        gate_probability: float = 0.999,
        min_gate_px: float = 2.0,
        max_gate_px: float = 120.0,
    ) -> None:
        xy = _as_positions(initial_xy)
        if not (np.isfinite(dt) and dt > 0):
            raise ValueError(f"dt must be a positive frame interval in seconds, got {dt!r}")
        if not isinstance(rng, np.random.Generator):
            raise TypeError(f"rng must be a numpy.random.Generator (np.random.default_rng(seed)), got {type(rng).__name__}")
        if int(max_coast_frames) != max_coast_frames or max_coast_frames < 0:
            raise ValueError(f"max_coast_frames must be a non-negative integer, got {max_coast_frames!r}")
        if not 0.0 < gate_probability < 1.0:
            raise ValueError(f"gate_probability must be in (0, 1), got {gate_probability!r}")
        if not 0.0 < min_gate_px <= max_gate_px:
            raise ValueError(f"need 0 < min_gate_px <= max_gate_px, got {min_gate_px!r} and {max_gate_px!r}")
        self.dt = float(dt)
        self.rng = rng
        self.n_markers = len(xy)
        self.max_coast_frames = int(max_coast_frames)
        self.gate_threshold = float(-2.0 * np.log1p(-gate_probability))
        self.min_gate_px = float(min_gate_px)
        self.max_gate_px = float(max_gate_px)
        # Bounds on the per-axis gate variance that give those radii.
        self._var_min = self.min_gate_px**2 / self.gate_threshold
        self._var_max = self.max_gate_px**2 / self.gate_threshold

        known = np.isfinite(xy).all(axis=1)
        self._status = np.where(known, TRACKED, LOST).astype(np.int8)
        # Frames since the last detection; labels that never had a position count as lost.
        self._coast = np.where(known, 0, self.max_coast_frames + 1).astype(np.int64)
        self._any_lost = not known.all()  # a Python bool keeps the common case cheap
        self._any_coasting = False
        self._rows = np.arange(self.n_markers)
        self._centre = xy.copy()  # prior position (centre of the search area), set by _predict
        # Prior measurement variance: (M, 1) for a circular gate, (M, 2) per image axis.
        self._svar = np.full((self.n_markers, 1), self._var_min)
        self._gvar = self._svar.copy()  # gate variance (clipped _svar), set by predict
        self._thr = self._gvar * self.gate_threshold  # circular gates: squared radius, px**2
        # (M,) bool set by associate when the assignment was ambiguous, else None.
        self._contested: np.ndarray | None = None
        # (M, 2) px set by associate of trackers that let a label without a detection of
        # its own follow a blob it shares with another label (merged markers), else None.
        self._shared_z: np.ndarray | None = None
        self._n_assigned = 0  # labels given a detection by the last association
        self._set_info()

    # ---------------------------------------------------------------- hooks
    def _predict(self) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    def _correct(self, z: np.ndarray, has: np.ndarray | None) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    def _restart(self, mask: np.ndarray, xy: np.ndarray) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    def _drop_velocity(self, mask: np.ndarray) -> None:
        """Forget the velocity of the labels in ``mask`` (they just became lost)."""

    def _association_cost(self, d2: np.ndarray, inside: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Cost of pairing labels and detections when the gated assignment is ambiguous.

        Parameters
        ----------
        d2 : (M, n) float
            Squared Mahalanobis distance of every detection from every label's centre.
        inside : (M, n) bool
            Pairs inside the gate.

        Returns
        -------
        pair_cost : (M, n) float
            Cost of each pair (only pairs inside a gate are ever used).
        miss_cost : (M,) float
            Cost of leaving a label without a detection this frame; the gate threshold,
            so that a single in-gate pair is never worse than a miss.
        """
        return d2, np.full(self.n_markers, self.gate_threshold)

    @property
    def x_est(self) -> np.ndarray:  # pragma: no cover - abstract
        """(M, 2) float: posterior position estimate in pixels."""
        raise NotImplementedError

    # ---------------------------------------------------------------- public API
    @property
    def status(self) -> np.ndarray:
        """(M,) int8: :data:`TRACKED`, :data:`COASTING` or :data:`LOST` per label.

        Updated in place by :meth:`update`; copy it to keep a frame's value."""
        return self._status

    @property
    def x_pred(self) -> np.ndarray:
        """(M, 2) float: prior (predicted) position of the current frame in pixels."""
        return self._centre

    @property
    def search_radius(self) -> np.ndarray:
        """(M,) float: radius in pixels of the circle enclosing each label's gate."""
        return np.sqrt(self.gate_threshold * self._gvar.max(axis=1))

    @property
    def frames_since_detection(self) -> np.ndarray:
        """(M,) int: consecutive frames each label has gone without a detection."""
        return self._coast

    def _set_info(self) -> None:
        # Gate variance clipped to [min_gate_px, max_gate_px] radii, and the squared radius
        # of circular gates (a detection at squared distance d2 is inside when d2 <= thr).
        # (np.maximum/np.minimum: ufuncs, cheaper than np.clip's wrapper on small arrays)
        gvar = np.maximum(self._svar, self._var_min)
        np.minimum(gvar, self._var_max, out=gvar)
        self._gvar = gvar
        self._thr = gvar * self.gate_threshold

    def _set_radius(self, radius: np.ndarray) -> None:
        """Circular gates straight from radii ``(M,)`` px (for trackers that think in
        radii, e.g. alpha-beta): clipped to [min_gate_px, max_gate_px]; sets ``_svar``,
        ``_gvar`` and ``_thr`` as :meth:`_set_info` would from the equivalent variance."""
        r = np.maximum(radius, self.min_gate_px)
        np.minimum(r, self.max_gate_px, out=r)
        r *= r
        self._thr = r[:, None]
        self._gvar = self._svar = self._thr * (1.0 / self.gate_threshold)

    def predict(self) -> None:
        """Advance every label to the next frame (prior state and search area)."""
        self._predict()
        if not self._sets_own_gate:
            self._set_info()
        self._contested = None
        self._shared_z = None

    def gate(self) -> SearchArea:
        """The search area of every label for the current frame."""
        var = np.broadcast_to(self._gvar, (self.n_markers, 2))
        cov = np.zeros((self.n_markers, 2, 2))
        cov[:, 0, 0] = var[:, 0]
        cov[:, 1, 1] = var[:, 1]
        return SearchArea(centre=self._centre.copy(), covariance=cov, threshold=self.gate_threshold)

    def associate(self, detections_xy: np.ndarray) -> np.ndarray:
        """Assign detections to labels inside their gates.

        Parameters
        ----------
        detections_xy : (n, 2) float
            Detected marker centroids in pixels, in any order.

        Returns
        -------
        (M,) int
            Index into ``detections_xy`` of each label's detection, -1 for none.

        Notes
        -----
        When every detection lies in at most one gate and every gate holds at most one
        detection the assignment is unambiguous and taken directly; otherwise tracked
        and coasting labels are assigned first (Hungarian method with a per-label miss
        cost), then lost labels compete for the detections left over.
        """
        det = np.asarray(detections_xy, dtype=np.float64)
        if det.ndim != 2 or det.shape[0] == 0:
            det = det.reshape(-1, 2)
            if len(det) == 0:
                self._contested = None
                return np.full(self.n_markers, -1, dtype=np.intp)
        return self._associate(det)

    def _associate(self, det: np.ndarray) -> np.ndarray:
        # Common case first, compiled: the gated pairs form a partial permutation (each
        # label at most one in-gate detection and vice versa); then they are the
        # assignment, whatever the costs, and the Hungarian method is not needed.
        idx = np.empty(self.n_markers, dtype=np.intp)
        K = unique_gated_pairs(self._centre, self._gvar, self._thr, self.gate_threshold, det, idx)
        if K >= 0:
            self._contested = None
            self._n_assigned = K
            return idx
        if self._gvar.shape[1] == 1:
            # Circular gates: compare plain squared distances with each label's squared
            # radius (the same test as the compiled check).
            d2 = cdist(self._centre, det, "sqeuclidean")  # (M, n) px**2, one C loop
            inside = d2 <= self._thr  # NaN centres compare False
            d2 /= self._gvar
        else:
            d2 = mahalanobis_sq(self._centre, self._gvar, det)
            inside = d2 <= self.gate_threshold
        per_label = inside.sum(axis=1)
        per_detection = inside.sum(axis=0)
        idx = self._assign_ambiguous(d2, inside, per_label > 0)
        # A label is contested when its gate held several detections or its detection
        # lay in several gates (markers crossing, merged blobs): trackers may trust such
        # a measurement less.
        self._contested = (per_label > 1) | ((idx >= 0) & (per_detection[idx] > 1))
        self._n_assigned = int(np.count_nonzero(idx >= 0))
        return idx

    def _assign_ambiguous(self, d2: np.ndarray, inside: np.ndarray, has_candidate: np.ndarray) -> np.ndarray:
        pair_cost, miss_cost = self._association_cost(d2, inside)
        idx = np.full(self.n_markers, -1, dtype=np.intp)
        free = np.ones(inside.shape[1], dtype=bool)
        active = self._status != LOST
        for rows_mask in (active & has_candidate, ~active & has_candidate):
            rows = np.flatnonzero(rows_mask)
            cols = np.flatnonzero(free & inside[rows].any(axis=0)) if len(rows) else rows
            if len(rows) == 0 or len(cols) == 0:
                continue
            r, c = gated_hungarian(pair_cost[np.ix_(rows, cols)], inside[np.ix_(rows, cols)], miss_cost[rows])
            idx[rows[r]] = cols[c]
            free[cols[c]] = False
        return idx

    def update(self, z: np.ndarray) -> None:
        """Measurement update.

        Parameters
        ----------
        z : (M, 2) float
            Each label's associated detection in pixels, NaN rows for labels without one.
        """
        z = np.array(z, dtype=np.float64)  # a copy: a tracker may keep it as its state
        if z.shape != (self.n_markers, 2):
            raise ValueError(f"z must have shape ({self.n_markers}, 2) (one row per label, NaN for none), got {z.shape}")
        has = z[:, 0] == z[:, 0]  # not NaN
        self._update(z, None if has.all() else has)

    def _update(self, z: np.ndarray, has: np.ndarray | None) -> None:
        # has: (M,) bool labels with a measurement, None when all have one.
        if has is None and self._shared_z is None and not self._any_lost:
            # Common case: every label measured, none lost.
            self._correct(z, None)
            if self._any_coasting:
                self._coast.fill(0)
                self._status.fill(TRACKED)
                self._any_coasting = False
            return
        self._update_general(z, np.ones(self.n_markers, dtype=bool) if has is None else has)

    def _update_general(self, z: np.ndarray, has: np.ndarray) -> None:
        observed = has
        if self._shared_z is not None:
            # Labels following a blob shared with another label: the filter uses the
            # blob and the label does not drift towards loss, but it has no detection of
            # its own (status coasting, no xy).
            shared = ~has & (self._shared_z[:, 0] == self._shared_z[:, 0])
            if shared.any():
                z = np.where(shared[:, None], self._shared_z, z)
                observed = has | shared
        reacquired = has & (self._status == LOST)
        if reacquired.any():
            self._correct(z, observed & ~reacquired)
            self._restart(reacquired, z)
        else:
            self._correct(z, None if observed.all() else observed)
        coast = self._coast
        coast += 1
        coast[observed] = 0
        newly_lost = coast == self.max_coast_frames + 1
        self._status[:] = np.where(has, TRACKED, np.where(coast > self.max_coast_frames, LOST, COASTING))
        self._any_lost = bool((coast > self.max_coast_frames).any())
        self._any_coasting = bool((self._status != TRACKED).any())
        if newly_lost.any():
            self._drop_velocity(newly_lost)

    def step(self, detections_xy: np.ndarray) -> np.ndarray:
        """One frame: predict, associate and update.

        Parameters
        ----------
        detections_xy : (n, 2) float
            Detected centroids in pixels.

        Returns
        -------
        (M,) int
            Index of each label's detection, -1 for none.
        """
        self.predict()
        det = np.asarray(detections_xy, dtype=np.float64)
        if det.ndim != 2 or det.shape[0] == 0:
            idx = self.associate(det)
            self.update(np.full((self.n_markers, 2), np.nan))
            return idx
        idx = self._associate(det)
        z = det[idx]
        if self._n_assigned < self.n_markers:
            missing = idx < 0
            z[missing] = np.nan
            self._update(z, ~missing)
        else:
            self._update(z, None)
        return idx

    def reset_labels(self, mask: np.ndarray, xy: np.ndarray) -> None:
        """(Re)start labels at given positions, e.g. when the labelling step finds them.

        Parameters
        ----------
        mask : (M,) bool
            Labels to restart.
        xy : (M, 2) float
            Their positions in pixels (rows outside ``mask`` are ignored).
        """
        mask = np.asarray(mask, dtype=bool).reshape(self.n_markers)
        xy = np.asarray(xy, dtype=np.float64).reshape(self.n_markers, 2)
        if not np.isfinite(xy[mask]).all():
            raise ValueError("reset_labels: every label in mask needs a finite (x, y) position in pixels")
        self._restart(mask, xy)
        self._centre = self._centre.copy()
        self._centre[mask] = xy[mask]
        self._coast[mask] = 0
        self._status[mask] = TRACKED
        self._any_lost = bool((self._status == LOST).any())
        self._any_coasting = bool((self._status != TRACKED).any())
        self._set_info()


class AlphaBetaFilter(Tracker2D):
    """What both alpha-beta trackers keep (``alpha_beta_adaptive`` and seed 000's
    fixed-circle ``alpha_beta``): the gains, a position ``_x`` and a displacement per frame
    ``_d`` ``(M, 2)`` px, and circular gates set from a radius (:meth:`_set_radius`).

    Not a tracker of its own: a subclass calls :meth:`_start_filter` in its constructor
    and implements the hooks (its search radius, residuals, coasting)."""

    _sets_own_gate = True

    def _start_filter(self, initial_xy: np.ndarray, alpha: float, beta: float) -> None:
        """Check the gains for stability; start every label at ``initial_xy``, not moving."""
        if not (0.0 < alpha <= 2.0 and 0.0 <= beta <= 4.0):
            raise ValueError(f"alpha-beta gains out of the stable range: alpha={alpha!r} (0, 2], beta={beta!r} [0, 4]")
        self.alpha = float(alpha)
        self.beta = float(beta)
        self._x = np.array(initial_xy, dtype=np.float64)  # (M, 2) position, px
        self._d = np.zeros_like(self._x)  # (M, 2) displacement per frame d = v dt, px/frame

    @property
    def x(self) -> np.ndarray:
        """(M, 2) float: position in pixels (smoothed ``x_s`` after an update)."""
        return self._x

    @property
    def v(self) -> np.ndarray:
        """(M, 2) float: smoothed velocity ``v_s`` in px/s."""
        return self._d / self.dt

    def _drop_velocity(self, mask: np.ndarray) -> None:
        self._d[mask] = 0.0

    @property
    def x_est(self) -> np.ndarray:
        """(M, 2) float: smoothed position ``x_s`` in pixels."""
        return self._x
