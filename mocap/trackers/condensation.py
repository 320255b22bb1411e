"""The bench's CONDENSATION particle tracker, ``condensation_drift`` (seed 000, section
III-C; Isard & Blake 1998), batched. Seed 000's own, as OpenMoCap had it (identity
dynamics, uniform diffusion), is ``condensation`` (:mod:`mocap.trackers.openmocap`).

Each label carries ``N`` position particles (seed 000: 100) and, unlike seed 000's
position-only state, a drift velocity. One frame is CONDENSATION's three phases, for all markers at once:

1. **selection** -- systematic resampling of every label's particles by their weights
   (:func:`systematic_resample`, filterpy's ``systematic_resample`` batched over rows);
2. **prediction** -- a deterministic *drift* (the label's velocity times ``dt``: identical
   particles drift identically) then a *diffusion*, Gaussian noise whose standard
   deviation grows with the marker's speed;
3. **observation** -- weights ``exp(-|s - z|**2 / (2 sigma_obs**2))`` from the associated
   detection ``z``; the estimate is the weighted mean.

The search area comes from the particle spread: per-axis variance of the predicted
particles plus the observation variance. A label without a detection keeps uniform
weights, so its cloud keeps diffusing and its gate grows (the diffusion widens with the
frames since the last detection, so the cloud's spread grows linearly with time, like
an extrapolation error). The drift velocity is
smoothed like an alpha-beta filter's, ``v += beta_v (x_est - x_pred) / dt``.
"""

from __future__ import annotations

import numpy as np

from mocap.trackers.base import Tracker2D, check_positive
from mocap.trackers.registry import register_tracker


def systematic_resample(weights: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Systematic resampling of many particle sets at once.

    Row ``m`` gives the same indexes as ``filterpy.monte_carlo.systematic_resample``
    with weights ``weights[m]`` and the uniform draw ``u[m]`` (filterpy draws it from
    the global RNG; here the caller passes it, from its own generator).

    Parameters
    ----------
    weights : (M, N) float
        Non-negative particle weights per row (normalised here).
    u : (M,) float
        One uniform draw in [0, 1) per row.

    Returns
    -------
    (M, N) int
        Per row, indexes of the selected particles, ascending.
    """
    weights = np.asarray(weights, dtype=np.float64)
    M, N = weights.shape
    flat = _systematic_flat(weights, np.asarray(u, dtype=np.float64).reshape(M))
    return flat.reshape(M, N) - (N * np.arange(M))[:, None]


def _systematic_flat(weights: np.ndarray, u: np.ndarray) -> np.ndarray:
    """(M * N,) flat indexes of the systematic resample of every row of ``weights``.

    Position ``i`` of row ``m``, ``(u[m] + i) / N``, selects the first particle ``j`` whose
    cumulative weight exceeds it (filterpy's loop). Particle ``j`` is therefore selected
    ``K_j - K_{j-1}`` times with ``K_j = #{i : i < N cum_j - u} = ceil(N cum_j - u)``;
    ``np.repeat`` of those counts is the resample without a per-row search. (Hand-written
    because filterpy's function takes one row and draws from the global RNG.)
    """
    M, N = weights.shape
    cum = np.cumsum(weights, axis=1)
    cum *= N / cum[:, -1:]  # last column exactly N
    cum -= u[:, None]
    np.ceil(cum, out=cum)  # K_j in [0, N]
    # Row offsets m N make the flattened K increasing across rows, so one diff gives the
    # counts of every row (the first of row m is K_0 of that row).
    cum += (N * np.arange(M, dtype=np.float64))[:, None]
    k = cum.astype(np.intp).ravel()
    counts = np.empty_like(k)  # np.diff(k, prepend=0) without its concatenation
    counts[0] = k[0]
    np.subtract(k[1:], k[:-1], out=counts[1:])
    return np.repeat(np.arange(M * N), counts)


def _particle_count(n_particles: int) -> int:
    """The particles per label of a CONDENSATION tracker (this one and seed 000's), checked."""
    if int(n_particles) != n_particles or n_particles < 2:
        raise ValueError(f"n_particles must be an integer >= 2, got {n_particles!r}")
    return int(n_particles)


@register_tracker("condensation_drift")
class DriftCondensationTracker(Tracker2D):
    """CONDENSATION particle filter for M markers with a drift velocity and a diffusion
    that grows with the speed (registered as ``condensation_drift``).

    Parameters
    ----------
    initial_xy : (M, 2) float
        First-frame pixel positions (NaN: label starts lost).
    dt : float
        Frame interval in seconds.
    rng : numpy.random.Generator
        Source of the resampling draws and the diffusion noise.
    n_particles : int, default 100
        Particles per marker (seed 000: 100).
    diffusion_std_px : float, default 1.5
        Diffusion standard deviation of a still marker, px per frame.
    speed_diffusion_gain : float, default 1.0
        Extra diffusion standard deviation per pixel of motion per frame (1.0: the cloud
        spreads by the marker's own displacement, so a sharp turn stays inside it).
    observation_std_px : float, default 3.0
        Width of the observation likelihood, px.
    velocity_gain : float, default 0.8
        Smoothing gain of the drift velocity (as alpha-beta's beta).
    initial_spread_px : float, default 10.0
        Standard deviation of a new label's particle cloud, px: its velocity is unknown,
        so the first search area must hold a marker moving ~10 px per frame.
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
        n_particles: int = 100,
        diffusion_std_px: float = 1.5,
        speed_diffusion_gain: float = 1.0,
        observation_std_px: float = 3.0,
        velocity_gain: float = 0.8,
        initial_spread_px: float = 10.0,
        **base_params,
    ) -> None:
        super().__init__(initial_xy, dt, rng, **base_params)
        N = _particle_count(n_particles)
        check_positive(diffusion_std_px=diffusion_std_px, observation_std_px=observation_std_px, initial_spread_px=initial_spread_px)
        self.n_particles = N
        self.diffusion_std_px = float(diffusion_std_px)
        self.speed_diffusion_gain = float(speed_diffusion_gain)
        self.observation_std_px = float(observation_std_px)
        self.velocity_gain = float(velocity_gain)
        self.initial_spread_px = float(initial_spread_px)
        M = self.n_markers
        xy = np.array(initial_xy, dtype=np.float64)
        # Particles as one (2, M, N) array (axis, marker, particle): one numpy call handles
        # both image axes, and each axis's (M, N) block is contiguous for the resampling
        # gather.
        self.p = xy.T[:, :, None] + rng.standard_normal((2, M, N)) * self.initial_spread_px
        self.weights = np.full((M, N), 1.0 / N)  # (M, N)
        self._uniform = True  # weights all equal: resampling is the identity
        self.vel = np.zeros((M, 2))  # (M, 2) drift velocity, px/s
        self.est = xy.copy()  # (M, 2) weighted mean, px
        self._obs_var = self.observation_std_px**2
        self._set_spread()
        self._set_info()

    @property
    def particles(self) -> np.ndarray:
        """(M, N, 2) float: particle positions in pixels."""
        return np.moveaxis(self.p, 0, -1).copy()

    def _set_spread(self) -> None:
        p = self.p
        inv_n = 1.0 / self.n_particles
        mean = np.add.reduce(p, axis=2)  # (2, M)
        mean *= inv_n
        var = np.add.reduce(p * p, axis=2)
        var *= inv_n
        var -= mean * mean  # per-axis particle variance
        np.maximum(var, 0.0, out=var)  # rounding
        var += self._obs_var
        self._centre = mean.T.copy()
        self._svar = var.T

    def _predict(self) -> None:
        _, M, N = self.p.shape
        dt = self.dt
        # Selection
        if self._uniform:
            p = self.p
        else:
            flat = _systematic_flat(self.weights, self.rng.random(M))
            p = self.p.reshape(2, M * N).take(flat, axis=1).reshape(2, M, N)
        # Drift (deterministic, the same for identical particles) then diffusion
        v = self.vel
        sigma = np.hypot(v[:, 0], v[:, 1])
        sigma *= self.speed_diffusion_gain * dt
        sigma += self.diffusion_std_px
        if self._any_coasting:
            # Without observations the cloud must spread like an extrapolation error,
            # linearly in time: after n frames its std is n sigma (sum of (2k - 1) sigma^2).
            sigma *= np.sqrt(2.0 * self._coast + 1.0)
        noise = self.rng.standard_normal((2, M, N))
        noise *= sigma[:, None]
        noise += (v.T * dt)[:, :, None]
        p += noise  # (p is new after a resampling; otherwise the old cloud is replaced)
        self.p = p
        self.weights = np.full((M, N), 1.0 / N)
        self._uniform = True
        self._set_spread()
        self.est = self._centre

    def _correct(self, z: np.ndarray, has: np.ndarray | None) -> None:
        # Observation: Gaussian likelihood of the associated detection per particle.
        d = self.p - z.T[:, :, None]  # (2, M, N)
        d *= d
        d2 = d[0]
        d2 += d[1]  # (M, N) squared distances
        d2 -= d2.min(axis=1, keepdims=True)  # best particle gets exp(0): no underflow
        d2 *= -0.5 / self._obs_var
        w = np.exp(d2, out=d2)
        w /= np.add.reduce(w, axis=1, keepdims=True)
        if has is not None:
            w[~has] = 1.0 / self.n_particles
        self.weights = w
        self._uniform = False
        est = np.add.reduce(self.p * w, axis=2).T  # (M, 2) weighted mean
        step = est - self._centre
        if has is not None:
            step[~has] = 0.0
        step *= self.velocity_gain / self.dt
        self.vel += step
        self.est = est

    def _restart(self, mask: np.ndarray, xy: np.ndarray) -> None:
        k = int(mask.sum())
        spread = self.rng.standard_normal((2, k, self.n_particles)) * self.initial_spread_px
        self.p[:, mask] = xy[mask].T[:, :, None] + spread
        self.weights[mask] = 1.0 / self.n_particles
        self.vel[mask] = 0.0
        self.est = self.est.copy()
        self.est[mask] = xy[mask]

    def _drop_velocity(self, mask: np.ndarray) -> None:
        self.vel[mask] = 0.0

    @property
    def x_est(self) -> np.ndarray:
        """(M, 2) float: weighted mean of the particles in pixels."""
        return self.est
