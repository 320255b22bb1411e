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
(issue 18).

A change of light (a lamp switched off) changes the whole set at once, and MOG2, learning
slowly so that a still subject does not fade, would take seconds to follow: in the meantime
the whole set is foreground and step 1 classifies walls and boxes as patches (on
``shirt_tungsten_off`` seeds 2, 8 and 9, a blue box as the blue forearm).  So when most of
the frame outside the subject is foreground, :meth:`BackgroundModel.apply` re-lights the
empty scene: a smooth gain per channel, the ratio of this frame to the empty scene outside
the subject (robustly, see :func:`smooth_gain`), times the empty frames is the empty scene
under the new light.  The model is primed again with it and ``empty_match`` compares with it.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from mocap.errors import MocapInputError

__all__ = ["BackgroundParams", "BackgroundModel", "smooth_gain"]


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
    relight_fraction: float = 0.3
    """Re-light the empty scene when more than this fraction of the reduced frame outside the
    subject is foreground (0: never).  A subject and what it moves cover a few percent there."""
    match_relit: float = 6.0
    """``match_empty`` once the empty scene was re-lit: the estimated gain field is smooth and
    misses the set's small changes of shading (the subject's shadow under the old light)."""
    relight_margin: float = 0.6
    """The subject's box (the previous pose's shirt) is grown by this fraction of its size on
    every side before the pixels outside it estimate the gain (arms, head and legs)."""


class BackgroundModel:
    """Foreground masks of one camera's frames (MOG2 on reduced frames)."""

    def __init__(self, params: BackgroundParams = BackgroundParams()) -> None:
        self.params = params
        self._mog = cv2.createBackgroundSubtractorMOG2(history=500, varThreshold=params.var_threshold, detectShadows=True)
        self._kernel = cv2.getStructuringElement(cv2.MORPH_RECT, (2 * params.dilate_px + 1,) * 2) if params.dilate_px else None
        self._size: tuple[int, int] | None = None
        self.empty: np.ndarray | None = None  # (H, W, 3) float32 empty scene under the current light
        self._empty_lit: np.ndarray | None = None  # (H, W, 3) float32 mean of the empty frames as recorded
        self._empty_small: np.ndarray | None = None  # the same, reduced, float32
        self.relit = False  # the empty scene was re-lit at least once (see ``relight_fraction``)

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
            self._empty_lit = self.empty
            H, W = self.empty.shape[:2]
            r = self.params.reduce
            self._empty_small = cv2.resize(self.empty, (W // r, H // r), interpolation=cv2.INTER_AREA)
            self.relit = False

    def empty_match(self, crop: np.ndarray, empty_crop: np.ndarray) -> np.ndarray:
        """``(h, w)`` bool: pixels of a crop ``(h, w, 3)`` (8-bit values) within ``match_empty`` levels
        of the empty scene's same crop ``empty_crop`` in every channel (all False when off)."""
        if self.params.match_empty <= 0:
            return np.zeros(crop.shape[:2], bool)
        limit = self.params.match_relit if self.relit else self.params.match_empty
        d = np.abs(np.asarray(crop, np.float32) - empty_crop)
        # the largest channel difference (np.maximum of the channels: .max(axis=2) is several times slower)
        return np.maximum(np.maximum(d[..., 0], d[..., 1]), d[..., 2]) < limit

    def apply(self, image: np.ndarray, subject_box: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
        """Update with a frame and return its foreground mask ``(H / reduce, W / reduce)`` bool.

        ``subject_box``: ``(lo, hi)`` image pixels ``(u, v)`` where the subject's shirt was on the
        previous frame, if known; the set outside it decides a change of light.
        """
        small = self._small(image)
        m = self._mog.apply(small, learningRate=self.params.learning_rate)
        if self._empty_small is not None and self.params.relight_fraction > 0:
            outside = self._outside(small.shape[:2], subject_box)
            if outside.any() and np.mean(m[outside] == 255) > self.params.relight_fraction:
                m = self._relight(image, small, outside)
        fg = (m == 255).astype(np.uint8)
        if self._kernel is not None:
            fg = cv2.dilate(fg, self._kernel)
        return fg > 0

    def _outside(self, shape: tuple[int, int], subject_box: tuple[np.ndarray, np.ndarray] | None) -> np.ndarray:
        """``(h, w)`` bool: reduced pixels away from the subject's grown box (all without a box)."""
        outside = np.ones(shape, bool)
        if subject_box is not None:
            lo, hi = (np.asarray(b, float) / self.params.reduce for b in subject_box)
            grow = self.params.relight_margin * (hi - lo)
            u0, v0 = np.floor(lo - grow).astype(int)
            u1, v1 = np.ceil(hi + grow).astype(int) + 1
            outside[max(v0, 0):max(v1, 0), max(u0, 0):max(u1, 0)] = False
        return outside

    def _relight(self, image: np.ndarray, small: np.ndarray, outside: np.ndarray) -> np.ndarray:
        """The empty scene under this frame's light; MOG2 primed again with it. Returns the
        frame's MOG2 mask against it (reduced, 255 foreground)."""
        gain_small = smooth_gain(small.astype(np.float32), self._empty_small, outside)
        relit_small = np.clip(self._empty_small * gain_small, 0, 255)
        self._mog.apply(relit_small.astype(np.uint8), learningRate=1.0)
        H, W = image.shape[:2]
        gain = cv2.resize(gain_small, (W, H), interpolation=cv2.INTER_LINEAR)
        self.empty = np.clip(self._empty_lit * gain, 0, 255)
        self.relit = True
        return self._mog.apply(small, learningRate=0.0)

    @staticmethod
    def full_size(mask_small: np.ndarray, width: int, height: int) -> np.ndarray:
        """A reduced mask resized to ``(height, width)`` bool (nearest)."""
        return cv2.resize(mask_small.astype(np.uint8), (width, height), interpolation=cv2.INTER_NEAREST) > 0


def smooth_gain(frame: np.ndarray, empty: np.ndarray, weight: np.ndarray, sigma_frac: float = 0.08,
                rounds: int = 2, outlier_log: float = 0.15) -> np.ndarray:
    """A smooth per-channel gain ``(h, w, 3)`` float32 with ``frame ~ empty * gain`` where ``weight``.

    Both images ``(h, w, 3)`` 8-bit values (float32); ``weight`` ``(h, w)`` bool, the pixels
    that show the set.  The log ratio is averaged by normalised convolution (a Gaussian of
    ``sigma_frac`` of the image's width), then pixels more than ``outlier_log`` from that
    field (what moved: legs, a shadow that went) are left out and it is averaged again.

    Written here because the pieces (normalised convolution, a robust re-weighting) are a few
    lines of OpenCV and no library fits a gain field to two images with a mask.
    """
    h, w = weight.shape
    sigma = max(1.0, sigma_frac * w)
    log_ratio = np.log((frame + 1.0) / (empty + 1.0)).astype(np.float32)
    wt = weight.astype(np.float32)
    # dark pixels give no ratio worth having (their noise is most of them)
    wt *= (empty.min(axis=2) > 8).astype(np.float32)
    field = np.zeros_like(log_ratio)
    for _ in range(rounds):
        den = cv2.GaussianBlur(wt, (0, 0), sigma)
        num = cv2.GaussianBlur(log_ratio * wt[..., None], (0, 0), sigma)
        ok = den > 1e-3
        # where the set is hidden everywhere near, the frame's own mean log ratio stands in
        fallback = (log_ratio * wt[..., None]).sum(axis=(0, 1)) / max(wt.sum(), 1.0)
        field = np.where(ok[..., None], num / np.maximum(den, 1e-3)[..., None], fallback)
        wt = wt * (np.abs(log_ratio - field).max(axis=2) < outlier_log)
    return np.exp(field).astype(np.float32)
