"""Interacting-multiple-model tracker: the project's own label keeper.

Idea
----
Seed 000 found that trackers which doubt their prediction (a search area that grows with
uncertainty) lose fewer markers than a confident one, yet a large search area is what
lets a label jump onto a neighbouring marker. This tracker gets both: a tight, velocity
consistent prediction while the motion is smooth and a wide search area as soon as it is
not, and it does not let a merged blob bend a track.

* **Three motion models per marker, mixed by an IMM** (Blom & Bar-Shalom 1988), all
  constant velocity with different process noise: *smooth* (low white acceleration:
  precise velocity on straight, steady paths), *agile* (white acceleration growing with
  speed, like the ``kalman`` tracker's: limbs that swing and accelerate all the time)
  and *manoeuvre* (a velocity jump at the start of a frame, growing with speed: a zigzag
  at speed ``v`` changes velocity by up to ``2 v``; its gain maps a position miss ``y``
  to a velocity change ``y / dt``, so a turn is absorbed in one frame). Model
  probabilities follow a Markov chain and each frame's likelihoods, so the filter
  switches within a frame when the motion changes character.
* **Search area = envelope of the models' innovation covariances** (each model's
  ``S_j = H P_j H' + R`` widened by its distance to the mixed prediction): a sudden turn
  is always inside the manoeuvre model's gate, however unlikely that model was.
* **Gated global assignment with a velocity-consistent cost**: when gates overlap, the
  Hungarian method minimises squared Mahalanobis distances under the IMM's *combined*
  prediction (the models' probability-weighted mean and covariance), a miss costing the
  gate threshold. Detections are ranked by their distance from the velocity-consistent
  prediction -- which resists swaps when two tracks come close -- while the wide gate
  still admits a turn. (The raw mixture density would be flat over the wide manoeuvre
  component and rank nothing.)
* **Merged blobs do not bend tracks**: when two markers overlap they give one blob, at
  their midpoint (or the nearer marker hides the other) -- for at least one label a
  measurement biased towards the other marker, frame after frame. A label left without
  a detection whose prediction is within ``merge_distance_px`` of another label's
  prediction and blob is *sharing* that blob; a label whose neighbouring blob (labelled
  or not, e.g. seed 000's "NULL" marker) vanished right next to it while its own blob
  jumped towards it has *merged* with it. Such labels coast on their own velocity (the
  blob does not correct them) without drifting towards loss, as long as the blob stays
  within ``merge_distance_px`` of their prediction; when the blobs separate, the
  velocity-consistent cost puts each label back on its own marker. The assignment reported stays one-to-one: a sharing
  label has no detection of its own (status coasting).
* **Occlusion coasting**: without a detection the IMM keeps predicting and its gate
  opens up (the manoeuvre model's covariance grows fastest); a label is lost after
  ``max_coast_frames`` and re-acquired as in the base class, but, unlike the seed
  trackers, it keeps moving on a slowly decaying velocity (``lost_velocity_decay``), so
  a marker hidden for long behind an obstacle is found where it comes out.

State per model ``k`` and marker, per image axis: position and velocity with a 2x2
covariance (``F``, ``Q``, ``H``, ``R`` are block-diagonal per axis, as in
:mod:`mocap.trackers.kalman`), stored as ``(K, M, 2)`` arrays so that every step is a
few dozen element-wise numpy operations for all markers and models at once.

Frame-counted parameters (``p_stay``, ``max_merge_frames``, ``max_coast_frames``) are
per frame; the defaults were chosen on 30 fps and 200 Hz test data (see
:func:`mocap.tracker_trials.run_robustness_check` and ``tests/test_trackers_*.py``).
"""

from __future__ import annotations

import numpy as np

from mocap.trackers.base import LOST, Tracker2D, check_nonnegative, check_positive
from mocap.trackers.registry import register_tracker

MODELS = ("smooth", "agile", "manoeuvre")


@register_tracker("imm")
class IMMTracker(Tracker2D):
    """Three-model (smooth / agile / manoeuvre) constant-velocity IMM for M markers.

    Parameters
    ----------
    initial_xy : (M, 2) float
        First-frame pixel positions (NaN: label starts lost).
    dt : float
        Frame interval in seconds.
    rng : numpy.random.Generator
        Unused (deterministic filter), kept for the common constructor.
    measurement_std_px : float, default 0.5
        Standard deviation of a detection's centroid, px.
    smooth_accel_std : float, default 30.0
        White-acceleration standard deviation of the smooth model, px/s**2.
    agile_accel_std : float, default 300.0
        White-acceleration standard deviation of the agile model for a still marker,
        px/s**2.
    agile_speed_gain : float, default 0.5
        Extra agile acceleration standard deviation per px/s of speed, per frame
        interval (``sigma_a = agile_accel_std + gain * |v| / dt``, as the ``kalman``
        tracker's ``speed_accel_gain``).
    manoeuvre_velocity_std : float, default 30.0
        Standard deviation of the manoeuvre model's velocity jump per frame for a still
        marker, px/s.
    manoeuvre_speed_gain : float, default 0.5
        Extra velocity-jump standard deviation per px/s of speed (dimensionless):
        ``sigma_dv = manoeuvre_velocity_std + gain * |v|``.
    p_stay : (float, float, float), default (0.95, 0.9, 0.8)
        Markov probabilities of staying in the smooth, agile and manoeuvre models from
        one frame to the next; the rest is split evenly over the other models.
    merge_distance_px : float, default 8.0
        Markers closer than this may show as one blob (sharing and merging, above).
    max_merge_frames : int, default 30
        Longest a label stays merged without a blob reappearing next to it.
    lost_velocity_decay : float, default 0.8
        Per-frame factor on a lost label's velocity. 0.8 rather than a slower fade: in the
        tracker study a lost label kept drifting on a stale velocity out of reach of the
        marker re-emerging from behind a barrier (occlusion video 10, seed 0).
    initial_position_std_px : float, default 1.0
    initial_velocity_std : float, default 300.0
        Prior of a new label (px, px/s); it starts with equal model probabilities.
    **base_params
        ``max_coast_frames``, ``gate_probability``, ``min_gate_px``, ``max_gate_px``
        (see :class:`~mocap.trackers.base.Tracker2D`).
    """

    def __init__(
        self,
        initial_xy: np.ndarray,
        dt: float,
        rng: np.random.Generator,
        *,
        measurement_std_px: float = 0.5,
        smooth_accel_std: float = 30.0,
        agile_accel_std: float = 300.0,
        agile_speed_gain: float = 0.5,
        manoeuvre_velocity_std: float = 30.0,
        manoeuvre_speed_gain: float = 0.5,
        p_stay: tuple[float, float, float] = (0.95, 0.9, 0.8),
        merge_distance_px: float = 8.0,
        max_merge_frames: int = 30,
        lost_velocity_decay: float = 0.8,
        initial_position_std_px: float = 1.0,
        initial_velocity_std: float = 300.0,
        **base_params,
    ) -> None:
        super().__init__(initial_xy, dt, rng, **base_params)
        check_positive(measurement_std_px=measurement_std_px, initial_position_std_px=initial_position_std_px,
                       initial_velocity_std=initial_velocity_std, merge_distance_px=merge_distance_px)
        check_nonnegative(smooth_accel_std=smooth_accel_std, agile_accel_std=agile_accel_std, agile_speed_gain=agile_speed_gain,
                          manoeuvre_velocity_std=manoeuvre_velocity_std, manoeuvre_speed_gain=manoeuvre_speed_gain)
        stay = np.asarray(p_stay, dtype=np.float64)
        if stay.shape != (3,) or not ((stay > 0) & (stay < 1)).all():
            raise ValueError(f"p_stay must be three probabilities in (0, 1) (smooth, agile, manoeuvre), got {p_stay!r}")
        if not 0.0 <= lost_velocity_decay <= 1.0:
            raise ValueError(f"lost_velocity_decay must be in [0, 1], got {lost_velocity_decay!r}")
        self.r = float(measurement_std_px) ** 2
        self.merge_distance_px = float(merge_distance_px)
        self.max_merge_frames = int(max_merge_frames)
        self.lost_velocity_decay = float(lost_velocity_decay)
        dt = self.dt
        K = len(MODELS)
        # Process noise per model k: Q = (std_k + gain_k |v|)**2 * [[q00, q01], [q01, q11]]_k
        # per axis. smooth and agile: piecewise white acceleration, G = [dt**2/2, dt]
        # (std in px/s**2, filterpy's Q_discrete_white_noise); manoeuvre: a velocity jump
        # at the start of the frame, G = [dt, 1] (std in px/s).
        self.noise_std = np.array([smooth_accel_std, agile_accel_std, manoeuvre_velocity_std], dtype=np.float64)
        self.speed_gain = np.array([0.0, agile_speed_gain / dt, manoeuvre_speed_gain], dtype=np.float64)
        accel = [dt**4 / 4.0, dt**3 / 2.0, dt**2]
        self._qform = np.array([accel, accel, [dt**2, dt, 1.0]]).T[:, :, None, None]  # (3 entries, K, 1, 1)
        #: (K, K) Markov transition matrix, ``trans[i, j] = P(model j now | model i before)``.
        self.trans = np.where(np.eye(K, dtype=bool), stay[:, None], ((1.0 - stay) / (K - 1))[:, None])
        self.p0 = (float(initial_position_std_px) ** 2, float(initial_velocity_std) ** 2)
        M = self.n_markers
        xy = np.array(initial_xy, dtype=np.float64)
        self.pos = np.broadcast_to(xy, (K, M, 2)).copy()  # (K, M, 2) px
        self.vel = np.zeros((K, M, 2))  # (K, M, 2) px/s
        self.p00 = np.full((K, M, 2), self.p0[0])  # per-axis 2x2 covariance blocks
        self.p01 = np.zeros((K, M, 2))
        self.p11 = np.full((K, M, 2), self.p0[1])
        self.mu = np.full((K, M), 1.0 / K)  # (K, M) model probabilities (posterior)
        self._c = self.mu.copy()  # (K, M) prior model probabilities of the current frame
        self.est = xy.copy()  # (M, 2) combined posterior position, px
        self._last_detections = np.zeros((0, 2))  # (n, 2) px, input of the last associate
        self._s_comb = self.p00[0] + self.r  # (M, 2) combined innovation variance, px**2
        self._hold: np.ndarray | None = None  # (M,) labels coasting on a shared / merged blob
        self._merged = np.zeros(M, dtype=bool)  # (M,) label's detection is a merged blob
        self._had_neighbour = np.zeros(M, dtype=bool)  # (M,) another blob was next to it last frame
        self._merge_frames = np.zeros(M, dtype=np.int64)  # (M,) frames in the current merge
        self._neighbour_xy = np.full((M, 2), np.nan)  # (M, 2) px, last frame's nearest other blob
        self._own_xy = np.full((M, 2), np.nan)  # (M, 2) px, last frame's own blob
        self._svar = self.p00[0] + self.r
        self._set_info()

    @property
    def model_probabilities(self) -> np.ndarray:
        """(M, 3) float: posterior probabilities of the smooth, agile and manoeuvre models."""
        return self.mu.T.copy()

    # ------------------------------------------------------------------ filter
    def _predict(self) -> None:
        self._hold = None
        dt = self.dt
        if self._any_lost:
            lost = self._status == LOST
            self.vel[:, lost] *= self.lost_velocity_decay
        # Mixing: c_j = sum_i trans_ij mu_i ; w_ij = trans_ij mu_i / c_j  (i, j models)
        c = self.trans.T @ self.mu  # (K, M)
        w = self.trans[:, :, None] * self.mu[:, None, :]
        w /= c  # (K_i, K_j, M)
        w = w[..., None]  # (K_i, K_j, M, 1)
        pos, vel = self.pos, self.vel
        m_pos = (w * pos[:, None]).sum(axis=0)  # (K_j, M, 2) mixed initial conditions
        m_vel = (w * vel[:, None]).sum(axis=0)
        dp = pos[:, None] - m_pos  # (K_i, K_j, M, 2) spread of the models about them
        dv = vel[:, None] - m_vel
        n00 = (w * (self.p00[:, None] + dp * dp)).sum(axis=0)
        n01 = (w * (self.p01[:, None] + dp * dv)).sum(axis=0)
        n11 = (w * (self.p11[:, None] + dv * dv)).sum(axis=0)
        # Model-matched prediction (constant velocity), Q per model, growing with speed.
        sa = np.hypot(m_vel[..., 0], m_vel[..., 1])  # (K, M) speed, px/s
        sa *= self.speed_gain[:, None]
        sa += self.noise_std[:, None]
        qv = (sa * sa)[..., None]  # (K, M, 1)
        q00, q01, q11 = self._qform  # (K, 1, 1) each
        m_pos += dt * m_vel
        n00 += dt * (n01 + n01 + dt * n11) + q00 * qv
        n01 += dt * n11 + q01 * qv
        n11 += q11 * qv
        self.pos, self.vel, self.p00, self.p01, self.p11 = m_pos, m_vel, n00, n01, n11
        self._c = c
        cw = c[..., None]  # (K, M, 1)
        centre = (cw * m_pos).sum(axis=0)
        self._centre = centre
        # Gate: envelope of the models' innovation variances about the mixed centre;
        # association cost: their probability-weighted (moment-matched) combination.
        d = m_pos - centre
        v = n00 + d * d  # (K, M, 2)
        self._svar = v.max(axis=0) + self.r
        self._s_comb = (cw * v).sum(axis=0) + self.r

    def _association_cost(self, d2: np.ndarray, inside: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        # Squared Mahalanobis distance under the combined prediction; a miss costs the
        # gate threshold, as in the base class, so a coasting label does not pull a
        # confident one off its marker along a chain of reassignments. (A per-label miss
        # cost of ln|S|/2 + g/2 with the negative log-likelihood would be the same: the
        # ln|S|/2 terms cancel out of every comparison.) Only runs when ambiguous.
        det = self._last_detections
        S = self._s_comb  # (M, 2) px**2
        dx = det[:, 0] - self._centre[:, 0:1]  # (M, n)
        dy = det[:, 1] - self._centre[:, 1:2]
        cost = dx * dx / S[:, 0:1] + dy * dy / S[:, 1:2]
        return np.where(np.isfinite(cost), cost, 1e300), np.full(self.n_markers, self.gate_threshold)

    def _associate(self, det: np.ndarray) -> np.ndarray:
        # Gated assignment (Tracker2D), then merged-blob handling (module docstring); the
        # assignment returned stays one-to-one. Both associate() and step() come here.
        self._last_detections = det
        idx = super()._associate(det)
        self._mark_merges(det, idx)
        return idx

    def _mark_merges(self, det: np.ndarray, idx: np.ndarray) -> None:
        shared = self._share_blobs(det, idx) if self._contested is not None else None  # gates overlap
        hold = self._follow_merges(det, idx, shared)
        self._hold = hold if hold.any() else None

    def _share_blobs(self, det: np.ndarray, idx: np.ndarray) -> np.ndarray | None:
        """(M,) bool labels without a detection sharing another label's blob, or None."""
        alone = (idx < 0) & (self._status != LOST)
        if not alone.any():
            return None
        c = self._centre
        m2 = self.merge_distance_px**2
        blob = np.where((idx >= 0)[:, None], det[np.maximum(idx, 0)], np.nan)  # (M, 2) each label's detection
        near = ((c[:, None, :] - c[None, :, :]) ** 2).sum(axis=2) <= m2  # (M, M) predictions close
        blob_near = ((c[:, None, :] - blob[None, :, :]) ** 2).sum(axis=2) <= m2  # (M, M) and its blob too
        partner = near & blob_near & alone[:, None]
        np.fill_diagonal(partner, False)
        rows = np.flatnonzero(partner.any(axis=1))
        if len(rows) == 0:
            return None
        dist = np.where(partner[rows], ((c[rows, None, :] - c[None, :, :]) ** 2).sum(axis=2), np.inf)
        shared_z = np.full((self.n_markers, 2), np.nan)
        shared_z[rows] = blob[dist.argmin(axis=1)]
        self._shared_z = shared_z  # the base class keeps these labels from drifting to loss
        shared = np.zeros(self.n_markers, dtype=bool)
        shared[rows] = True
        return shared

    def _follow_merges(self, det: np.ndarray, idx: np.ndarray, shared: np.ndarray | None) -> np.ndarray:
        """(M,) bool: labels whose detection is (still) a blob merged with a neighbour.

        A label merges when the blob nearest to its own in the previous frame (within two
        merge distances) is gone, and its own blob has jumped towards where that
        neighbour was (a merged blob lies between the two markers; a neighbour that was
        merely hidden or missed leaves the label's blob in place), or when it shares
        another label's blob (``shared``).
        """
        got = idx >= 0
        m2 = self.merge_distance_px**2
        M = self.n_markers
        if len(det) == 0:
            nearest2 = np.full(M, np.inf)
            nearest_xy = np.full((M, 2), np.nan)
            own = np.full((M, 2), np.nan)
            close = got
        else:
            own = np.where(got[:, None], det[np.maximum(idx, 0)], np.nan)  # (M, 2)
            d2 = ((det[None, :, :] - own[:, None, :]) ** 2).sum(axis=2)  # (M, n)
            d2[np.flatnonzero(got), idx[got]] = np.inf  # not its own detection
            j = d2.argmin(axis=1)
            nearest2 = np.where(got, d2[np.arange(M), j], np.inf)  # other blob nearest to it
            nearest_xy = det[j]
            # The blob must stay next to the label's own prediction, else it is no merge.
            close = ((own - self._centre) ** 2).sum(axis=1) <= m2
        # A neighbour within two merge distances may reach the label within a frame.
        neighbour = nearest2 <= 4.0 * m2
        gone = got & close & ~neighbour & self._had_neighbour
        entering = gone
        if gone.any():
            towards = self._neighbour_xy - self._own_xy  # last frame: label's blob -> neighbour
            sep = np.hypot(towards[:, 0], towards[:, 1])
            shift = ((own - self._centre) * towards).sum(axis=1) / np.maximum(sep, 1e-9)
            entering = gone & (shift >= np.maximum(1.0, 0.25 * sep))
        if shared is not None:
            # A label sharing another's blob is merged too, and stays so when the blob
            # comes back to it (the two labels may take turns owning it).
            entering = entering | shared
            close = close | shared
            got = got | shared
        merged = self._merged | entering
        self._merge_frames = np.where(merged, self._merge_frames + 1, 0)
        leaving = ~got | ~close | neighbour | (self._merge_frames > self.max_merge_frames)
        merged &= ~leaving
        self._merge_frames[~merged] = 0
        self._merged = merged
        self._had_neighbour = neighbour
        self._neighbour_xy = nearest_xy
        self._own_xy = own
        return merged

    def _correct(self, z: np.ndarray, has: np.ndarray | None) -> None:
        r = self.r
        p00, p01, p11 = self.p00, self.p01, self.p11
        y = z - self.pos  # (K, M, 2)
        S = p00 + r
        k0 = p00 / S
        k1 = p01 / S
        hold = self._hold
        if hold is not None:
            # Shared or merged blob: biased towards the other marker, with an error that
            # persists from frame to frame -- coast on the prior instead (K = 0; the
            # Joseph form below then keeps P = prior).
            k0 = np.where(hold[:, None], 0.0, k0)
            k1 = np.where(hold[:, None], 0.0, k1)
        a = 1.0 - k0
        n00 = a * a * p00 + r * k0 * k0  # Joseph form (the gain may be zero, i.e. sub-optimal)
        n01 = a * (p01 - k1 * p00) + r * k0 * k1
        n11 = k1 * (k1 * S - 2.0 * p01) + p11
        # Model likelihoods (log, up to a common constant), summed over both axes.
        ll = -0.5 * ((y * y / S).sum(axis=2) + np.log(S[..., 0] * S[..., 1]))  # (K, M)
        ll -= ll.max(axis=0)
        mu = self._c * np.exp(ll)
        mu /= mu.sum(axis=0)
        if hold is not None:
            mu = np.where(hold, self._c, mu)  # the blob says nothing of the label's motion
        pos = self.pos + k0 * y
        vel = self.vel + k1 * y
        if has is not None:
            m = has[:, None]
            pos = np.where(m, pos, self.pos)
            vel = np.where(m, vel, self.vel)
            n00 = np.where(m, n00, p00)
            n01 = np.where(m, n01, p01)
            n11 = np.where(m, n11, p11)
            mu = np.where(has, mu, self._c)
        self.pos, self.vel, self.p00, self.p01, self.p11, self.mu = pos, vel, n00, n01, n11, mu
        self.est = (mu[..., None] * pos).sum(axis=0)

    def _restart(self, mask: np.ndarray, xy: np.ndarray) -> None:
        self.pos[:, mask] = xy[mask]
        self.vel[:, mask] = 0.0
        self.p00[:, mask] = self.p0[0]
        self.p01[:, mask] = 0.0
        self.p11[:, mask] = self.p0[1]
        self.mu[:, mask] = 1.0 / len(MODELS)
        self._merged[mask] = False
        self._had_neighbour[mask] = False
        self.est = self.est.copy()
        self.est[mask] = xy[mask]

    def _drop_velocity(self, mask: np.ndarray) -> None:
        # Unlike the base policy, a lost label keeps moving on its velocity, which decays
        # by ``lost_velocity_decay`` per frame (see _predict).
        pass

    @property
    def x_est(self) -> np.ndarray:
        """(M, 2) float: probability-weighted position of the models, pixels."""
        return self.est
