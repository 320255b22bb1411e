"""The last solution of every frame of :meth:`mocap.skeleton.SkeletonSolver.solve`, for reuse.

The marker pipeline fits the same take five or more times (the fit that guides the passes, the
model check's rounds, the fills' refits, the last fit), and between two fits most frames'
markers do not change: on the bench's 30 quickstart frames 148 of 150 frame fits had inputs
bit-identical to the fit before. A frame's forward fit is a pure function of its measured
markers, which of them are finite, and the previous frame's solution (the warm start, or a
cold start where there is none), so a frame whose three inputs are bit-identical to those of
the last fit of that frame gets that fit's results unchanged: the same bits, without the
Levenberg-Marquardt iterations.

One entry per frame index (the last fit's), so the memory is bounded by the take's length and
nothing outlives the solver.
"""

from __future__ import annotations

import numpy as np


class FrameMemo:
    """Frame index -> (inputs, results) of the last forward fit of that frame."""

    def __init__(self) -> None:
        self._slots: dict[int, tuple[tuple, tuple]] = {}

    @staticmethod
    def key(obs: np.ndarray, ok: np.ndarray, q_prev: np.ndarray | None) -> tuple:
        """The inputs as bytes: equal keys are bit-identical inputs (NaN and -0.0 included)."""
        return (obs.tobytes(), ok.tobytes(), None if q_prev is None else q_prev.tobytes())

    def get(self, f: int, key: tuple) -> tuple | None:
        """The results stored for frame ``f`` if they came from the inputs ``key``, else None."""
        entry = self._slots.get(f)
        return entry[1] if entry is not None and entry[0] == key else None

    def put(self, f: int, key: tuple, results: tuple) -> None:
        self._slots[f] = (key, results)
