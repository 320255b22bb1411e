"""Step 5 of the shirt tracker: the white balance ``W*`` re-estimated under the final pose's id map
(:meth:`WhiteBalanceUpdate._update_white_balance`), for the next frame.

In: one camera's crop in linear RGB, the final pose's id map at ``wb_size`` and the current ``W``.
Out: the camera's ``W`` replaced (kept, or moved part of the way in steady light) and offered to its
reference illuminations. Seed 001's least squares are taken in each colour's Mahalanobis metric
(:func:`mocap.shirt.colour_model.solve_white_balance`), the metric the classifier thresholds.

:class:`WhiteBalanceUpdate` is a part of :class:`mocap.shirt.pipeline.ShirtTracker` (a mixin: it
uses the tracker's colour model, settings, white balances, reference illuminations and state).
"""

from __future__ import annotations

import cv2
import numpy as np

from mocap.shirt.classify import nearest_colour
from mocap.shirt.colour_model import labelled_colour_means, solve_white_balance
from mocap.shirt.settings import CameraObservation

__all__ = ["WhiteBalanceUpdate"]


class WhiteBalanceUpdate:
    """Step 5, per camera (part of ``ShirtTracker``)."""

    def _update_white_balance(self, ci: int, q: np.ndarray, o: CameraObservation, lin: np.ndarray, rend) -> None:
        """Step 5: ``W*`` from the colours under the final pose's id map ``rend`` (at ``wb_size``), kept if it
        explains those colours (``wb_min_agreement``), blended in by ``wb_smoothing`` where the light is steady."""
        p = self.params
        small = cv2.resize(lin, (p.wb_size, p.wb_size), interpolation=cv2.INTER_AREA) if p.wb_size != o.view.size else lin
        means, counts = labelled_colour_means(small, rend.colour, self.colours.n_colours, erode_px=1, min_pixels=6, robust=True)
        W = solve_white_balance(means, self.colours.means, np.sqrt(counts), min_colours=4, whiten=self.colours.whiten)
        if W is None or not np.all(np.isfinite(W)):
            return
        # keep W* only if it explains the colours under the final pose at least as well as
        # the current W (a pose that is off labels pixels wrongly, and W* would follow)
        lab = rend.colour.ravel()
        on = lab >= 0
        if on.sum() < 20:
            return
        x = small.reshape(-1, 3)[on]
        def agreement(Wm: np.ndarray) -> float:
            best, score = nearest_colour(self.colours.distances(x, Wm))
            return float(np.mean((best == lab[on]) & (score < p.assisted_threshold)))
        new = agreement(W)
        if new + 0.02 < agreement(self.W[ci]):
            return
        # ... and only if it explains a fair share of them at all: when the pose is far off (the
        # first lock-on pass of shirt_jumping_jacks seed 7) both W fail, W* fits whatever the pose
        # happens to cover (the black trousers: W* = 0.13 I, every pixel then classifies as the
        # black patch) and the next frames lock onto that
        if new < p.wb_min_agreement:
            return
        # steady light: part of the way (one frame's fit carries its pose's errors); a change of light: all of it
        a = p.wb_smoothing if not self._poor[ci] else 1.0
        W = a * W + (1.0 - a) * self.W[ci]
        self.W[ci] = W
        self.references[ci].offer(W)
