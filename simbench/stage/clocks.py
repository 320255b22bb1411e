"""Each camera's clock: when its frames are really exposed, and what timestamps it reports.

A scenario's ``[sensor.clock]`` (:class:`~simbench.scenario.ClockConfig`) gives every camera
its own clock, drawn from the scenario's seed: camera ``c``'s reading ``s`` happens at true
time ``offset_c + rate_c * s`` with ``rate_c = 1 + ppm_c * 1e-6``. Tick ``i`` of the clock
exposes (mid-exposure) at the reading ``s_i = i / fps + exposure / 2 + e_i`` (``e_i`` the
frame-interval jitter) and the camera stamps its frame with ``s_i``. A tick's frame may be
dropped (not delivered) or be a duplicate (the previous delivered frame's image again, under
the tick's timestamp). Every camera delivers the take's ``F`` frames.

Without a clock (or with every field zero) every camera's frame ``k`` is exposed at
:func:`~simbench.stage.renderer.mid_exposure_times` and stamped with it: today's bench.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from simbench.scenario import ClockConfig
from simbench.stage.renderer import mid_exposure_times

__all__ = ["CameraClocks", "camera_clocks", "CLOCK_SEED_KEY"]

#: Key of the clocks' random stream under the scenario's seed.
CLOCK_SEED_KEY = 0xC10C


@dataclass(frozen=True)
class CameraClocks:
    """The frame timing of every camera of a take (``F`` delivered frames, ``C`` cameras).

    true_times_s : (F, C) float64, true mid-exposure instant of each delivered frame (s)
    timestamps_s : (F, C) float64, the camera's own clock reading of each delivered frame (s)
    offset_s : (C,) true time at each clock's zero (s)
    rate : (C,) true seconds per clock second (1 + ppm * 1e-6)
    duplicated : (F, C) bool, the frame repeats the previous delivered frame's image
    dropped : (C,) int, ticks whose frame was dropped
    """

    true_times_s: np.ndarray
    timestamps_s: np.ndarray
    offset_s: np.ndarray
    rate: np.ndarray
    duplicated: np.ndarray
    dropped: np.ndarray

    @property
    def synchronised(self) -> bool:
        """Every camera's frame ``k`` at one instant."""
        return bool((self.true_times_s == self.true_times_s[:, :1]).all())

    def relative_to(self, ref: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """The exact map of each camera's clock onto camera ``ref``'s: ``s_ref = offset + (1 + drift) * s_c``.

        Returns ``offset_s (C,)`` (in ``ref``'s clock seconds) and ``drift (C,)`` (dimensionless;
        ``* 1e6`` for ppm): what :func:`mocap.synchronisation.estimate_sync` estimates."""
        offset = (self.offset_s - self.offset_s[ref]) / self.rate[ref]
        drift = self.rate / self.rate[ref] - 1.0
        return offset, drift


def camera_clocks(cfg: ClockConfig | None, n_cameras: int, n_frames: int, fps: float, exposure_ms: float,
                  seed: int) -> CameraClocks:
    """Draw every camera's clock and deliver ``n_frames`` frames from each (see the module doc)."""
    mid = mid_exposure_times(n_frames, fps, exposure_ms)
    if cfg is None or cfg.synchronised:
        times = np.repeat(mid[:, None], n_cameras, axis=1)
        return CameraClocks(times, times.copy(), np.zeros(n_cameras), np.ones(n_cameras),
                            np.zeros((n_frames, n_cameras), bool), np.zeros(n_cameras, int))
    rng = np.random.default_rng(np.random.SeedSequence([seed, CLOCK_SEED_KEY]))
    offset = rng.uniform(-1.0, 1.0, n_cameras) * cfg.offset_ms_max * 1e-3
    rate = 1.0 + rng.uniform(-1.0, 1.0, n_cameras) * cfg.drift_ppm_max * 1e-6
    jitter_s = cfg.jitter_ms * 1e-3
    # The earliest camera starts at 0 (the simulation begins there), after the largest jitter.
    offset = offset - offset.min() + 3.0 * jitter_s
    true = np.empty((n_frames, n_cameras))
    stamps = np.empty((n_frames, n_cameras))
    dup = np.zeros((n_frames, n_cameras), bool)
    dropped = np.zeros(n_cameras, int)
    for c in range(n_cameras):
        k, i = 0, 0
        while k < n_frames:
            e = float(np.clip(rng.normal(0.0, jitter_s), -3.0 * jitter_s, 3.0 * jitter_s)) if jitter_s > 0 else 0.0
            s = i / fps + 0.5 * exposure_ms * 1e-3 + e
            u = rng.uniform()
            i += 1
            if u < cfg.drop_probability and k > 0:
                dropped[c] += 1
                continue
            stamps[k, c] = s
            if u < cfg.drop_probability + cfg.duplicate_probability and k > 0:
                true[k, c] = true[k - 1, c]
                dup[k, c] = True
            else:
                true[k, c] = offset[c] + rate[c] * s
            k += 1
    return CameraClocks(true, stamps, offset, rate, dup, dropped)
