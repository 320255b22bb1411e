"""The bench's alpha-beta tracker, ``alpha_beta_adaptive``: seed 000's filter (section
III-A) with the search area the paper proposes as future work ("the simplicity of the
Alpha-Beta filter with a variable search area, based on speed"), vectorised over markers.
Seed 000's own tracker, with OpenMoCap's fixed search circle, is ``alpha_beta``
(:mod:`mocap.trackers.openmocap`).

Each label has a position and a velocity; the prediction moves it at constant velocity
for one frame, ``x_p = x_s + dt v_s`` and ``v_p = v_s``. With a measurement ``x_m``

.. math::

    r = x_m - x_p                      \\qquad (1)
    x_s = x_p + \\alpha r              \\qquad (2)
    v_s = v_p + (\\beta / \\Delta t) r \\qquad (3)

Seed 000 uses ``alpha = 1.0`` and ``beta = 0.8``.

Search area: a circle around the prediction whose radius is learnt from the residuals
and grows with the marker's speed (the filter has no covariance of its own)::

    radius = base_radius_px + residual_gain * rms(r) + speed_gain * |v| dt

with ``rms(r)`` an exponentially weighted RMS of the residual norm; while coasting it
is multiplied by the number of frames since the last detection plus one (the
extrapolation error grows at least linearly). After ``n`` coasted frames the residual
has built up over ``n + 1`` frames, so equation (3) divides it by ``(n + 1) dt``; with
no coasting that is exactly the seed's equation.
"""

from __future__ import annotations

import numpy as np

from mocap.trackers.base import AlphaBetaFilter
from mocap.trackers.registry import register_tracker


@register_tracker("alpha_beta_adaptive")
class AdaptiveAlphaBetaTracker(AlphaBetaFilter):
    """Alpha-beta filter for M markers with a search area that adapts to its residuals
    and the speed (registered as ``alpha_beta_adaptive``).

    Parameters
    ----------
    initial_xy : (M, 2) float
        First-frame pixel positions (NaN: label starts lost).
    dt : float
        Frame interval in seconds.
    rng : numpy.random.Generator
        Unused (deterministic filter), kept for the common constructor.
    alpha : float, default 1.0
        Position smoothing gain, equation (2).
    beta : float, default 0.8
        Velocity smoothing gain, equation (3).
    base_radius_px : float, default 4.0
        Smallest search radius in pixels.
    residual_gain : float, default 3.0
        Search radius per pixel of RMS residual.
    speed_gain : float, default 1.0
        Search radius per pixel of motion per frame (1.0: a stop or a sharp turn stays
        inside the search area).
    residual_smoothing : float, default 0.2
        Weight of the newest squared residual in the running RMS.
    initial_residual_px : float, default 12.0
        Starting value of the running RMS residual: a new label's velocity is unknown,
        so its first search areas are wide and shrink as residuals come in. 12 px makes
        the first search circle ``4 + 3 * 12 = 40`` px, the fixed circle of seed 000's
        ``alpha_beta`` (5 % of a 640x480 diagonal): the two differ only in how the area
        changes afterwards.
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
        alpha: float = 1.0,
        beta: float = 0.8,
        base_radius_px: float = 4.0,
        residual_gain: float = 3.0,
        speed_gain: float = 1.0,
        residual_smoothing: float = 0.2,
        initial_residual_px: float = 12.0,
        **base_params,
    ) -> None:
        super().__init__(initial_xy, dt, rng, **base_params)
        # State, kept as two (M, 2) arrays because every frame touches both whole:
        # position x (px; the prior after predict, the posterior after update) and the
        # displacement per frame d = v dt (px/frame), so predict is a single addition.
        # Written for few array passes: at 30 markers each numpy call costs about as
        # much as the arithmetic, and this filter's budget is a few dozen calls a frame.
        self._start_filter(initial_xy, alpha, beta)
        if not 0.0 < residual_smoothing <= 1.0:
            raise ValueError(f"residual_smoothing must be in (0, 1], got {residual_smoothing!r}")
        self.base_radius_px = float(base_radius_px)
        self.residual_gain = float(residual_gain)
        self.speed_gain = float(speed_gain)
        self.residual_smoothing = float(residual_smoothing)
        self.initial_residual_px = float(initial_residual_px)
        self.res2 = np.full(self.n_markers, self.initial_residual_px**2)  # (M,) running mean squared residual norm, px**2
        self._res_radius = self._radius_from_residuals()  # (M,) px, base + residual term
        self.radius = self._res_radius.copy()  # (M,) search radius, px
        self._set_radius(self.radius)

    def _radius_from_residuals(self) -> np.ndarray:
        """(M,) px: base radius plus the residual term of the search radius."""
        t = np.sqrt(self.res2)
        t *= self.residual_gain
        t += self.base_radius_px
        return t

    def _predict(self) -> None:
        d = self._d
        # x_p = x_s + dt v_s, v_p = v_s; a new array, so it is also the search centre
        self._x = self._centre = self._x + d
        # radius = base + residual_gain * rms(r) + speed_gain * |v| dt, times the frames
        # since the last detection (plus this one) while coasting.
        r = np.hypot(d[:, 0], d[:, 1])
        if self.speed_gain != 1.0:
            r *= self.speed_gain
        r += self._res_radius
        if self._any_coasting:
            r *= self._coast + 1
        self.radius = r
        self._set_radius(r)

    def _correct(self, z: np.ndarray, has: np.ndarray | None) -> None:
        x = self._x
        r = z - x  # (1) residual, px
        if has is None and self.alpha == 1.0:
            self._x = z  # (2) with alpha = 1: x_s = x_m (z is a fresh array of this frame)
        else:
            if has is not None:
                r[~has] = 0.0  # no measurement: x_s = x_p, v_s = v_p
            # (2); a new array: x is also this frame's search centre (x_pred)
            self._x = x + (r if self.alpha == 1.0 else self.alpha * r)
        e2 = r * r
        e2 = np.add(e2[:, 0], e2[:, 1])  # squared residual norm, px**2
        if self._any_coasting:
            # The residual built up over the coasted frames plus this one.
            r /= (self._coast + 1)[:, None]
        r *= self.beta  # (3) in displacement per frame: d_s = d_p + beta r
        self._d += r
        sm = self.residual_smoothing
        if has is None:
            self.res2 *= 1.0 - sm
            e2 *= sm
            self.res2 += e2
        else:
            self.res2 += np.where(has, sm * (e2 - self.res2), 0.0)
        self._res_radius = self._radius_from_residuals()

    def _restart(self, mask: np.ndarray, xy: np.ndarray) -> None:
        self._x[mask] = xy[mask]
        self._d[mask] = 0.0
        self.res2[mask] = self.initial_residual_px**2
        self._res_radius = self._radius_from_residuals()
