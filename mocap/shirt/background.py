"""Coarse background subtraction for the shirt pipeline (seed 001 uses Stauffer & Grimson's mixture model).

OpenCV's ``BackgroundSubtractorMOG2`` (the adaptive Gaussian-mixture model of
Stauffer & Grimson, as improved by Zivkovic) runs on a quarter-size frame: the mask
only has to be coarse (it suppresses false positives, the pipeline does not rely on
it), and a 160 x 120 model costs a fraction of a millisecond.  Pixels the model
labels *shadow* (darker with the same chromaticity) count as background, which also
absorbs most of a global dimming of the light.  The model can be primed with frames
of the empty scene, which a user records before stepping in.

The mask is coarse: a reduced pixel is 4 x 4 image pixels and the mask is dilated, so a
ring of the set several pixels wide around the subject passes as foreground, and step 1
classifies a grey wall as the light-grey patch or a yellow ribbon on a box as the yellow
forearm.  With the empty scene at hand, :meth:`BackgroundModel.empty_match` finds, at the
classifier's working resolution, the pixels of a crop that still look as in the empty
scene (within ``match_empty`` 8-bit levels in every channel): they are background
(issue 18).  Only the light of the empty frames is known, so after a change of light
nothing matches and the coarse mask is all there is.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from mocap.errors import MocapInputError

__all__ = ["BackgroundParams", "BackgroundModel"]


@dataclass(frozen=True)
class BackgroundParams:
    """Settings of the background model.

    Attributes
    ----------
    reduce : int
        The model runs on frames shrunk by this factor per axis.
    learning_rate : float
        Per-frame update rate while tracking (small: a subject that stands still must
        not fade into the background within a take).
    var_threshold : float
        MOG2's squared Mahalanobis threshold.
    dilate_px : int
        The foreground mask is dilated by this many reduced pixels.
    """

    reduce: int = 4
    learning_rate: float = 0.002
    var_threshold: float = 16.0
    dilate_px: int = 1
    match_empty: float = 3.0
    """A crop pixel within this many 8-bit levels of the empty scene in every channel is
    background (0: off).  On frames of shirt_office seed 3 (10 frames, 2 cameras) 3 levels
    removed 71 % of the step-1 pixels that were the set, and 0.4 % of the correct ones."""


class BackgroundModel:
    """Foreground masks of one camera's frames (MOG2 on reduced frames)."""

    def __init__(self, params: BackgroundParams = BackgroundParams()) -> None:
        self.params = params
        self._mog = cv2.createBackgroundSubtractorMOG2(history=500, varThreshold=params.var_threshold, detectShadows=True)
        self._kernel = cv2.getStructuringElement(cv2.MORPH_RECT, (2 * params.dilate_px + 1,) * 2) if params.dilate_px else None
        self._size: tuple[int, int] | None = None
        self.empty: np.ndarray | None = None  # (H, W, 3) float32 mean of the empty frames

    def _small(self, image: np.ndarray) -> np.ndarray:
        img = np.asarray(image)
        if img.ndim != 3 or img.dtype != np.uint8:
            raise MocapInputError(f"background model: expected (H, W, 3) uint8 frames, got {img.shape} {img.dtype}")
        H, W = img.shape[:2]
        if self._size is None:
            self._size = (W, H)
        elif self._size != (W, H):
            raise MocapInputError(f"background model: frame size {W}x{H} differs from the first frame's {self._size[0]}x{self._size[1]}")
        r = self.params.reduce
        return cv2.resize(img, (W // r, H // r), interpolation=cv2.INTER_AREA)

    def learn_empty(self, frames: list[np.ndarray]) -> None:
        """Prime the model with frames of the empty scene (fully learnt)."""
        for i, f in enumerate(frames):
            self._mog.apply(self._small(f), learningRate=1.0 if i == 0 else 1.0 / (i + 1))
        if len(frames):
            self.empty = np.mean(np.stack([np.asarray(f, np.float32) for f in frames]), axis=0)

    def empty_match(self, crop: np.ndarray, empty_crop: np.ndarray) -> np.ndarray:
        """``(h, w)`` bool: pixels of a crop ``(h, w, 3)`` (8-bit values) within ``match_empty`` levels
        of the empty scene's same crop ``empty_crop`` in every channel (all False when off)."""
        if self.params.match_empty <= 0:
            return np.zeros(crop.shape[:2], bool)
        return np.abs(np.asarray(crop, np.float32) - empty_crop).max(axis=2) < self.params.match_empty

    def apply(self, image: np.ndarray) -> np.ndarray:
        """Update with a frame and return its foreground mask ``(H / reduce, W / reduce)`` bool."""
        m = self._mog.apply(self._small(image), learningRate=self.params.learning_rate)
        fg = (m == 255).astype(np.uint8)
        if self._kernel is not None:
            fg = cv2.dilate(fg, self._kernel)
        return fg > 0

    @staticmethod
    def full_size(mask_small: np.ndarray, width: int, height: int) -> np.ndarray:
        """A reduced mask resized to ``(height, width)`` bool (nearest)."""
        return cv2.resize(mask_small.astype(np.uint8), (width, height), interpolation=cv2.INTER_NEAREST) > 0
