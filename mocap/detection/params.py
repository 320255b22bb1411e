"""Settings of the marker blob detectors (:func:`mocap.detection.detect_markers`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from mocap.errors import require, require_one_of

__all__ = ["DetectionParams"]

# Defaults that differ between the two modes (a field left at None takes these).
_MODE_DEFAULTS: dict[str, dict[str, float]] = {
    "ir": {"k_sigma": 6.0, "min_contrast": 20.0, "min_area_px": 3, "min_fill_ratio": 0.6, "max_elongation": 30.0},
    # Visible: measured on visible_office (office, tungsten, dim presets, JPEG 75/90) and
    # dim_gym_noisy with scripts/detection_eval.py; markers there are 2-4 px across and
    # 10-60 grey levels above their surroundings.
    "visible": {"k_sigma": 4.0, "min_contrast": 10.0, "min_area_px": 2, "min_fill_ratio": 0.5, "max_elongation": 3.0},
}


@dataclass(frozen=True)
class DetectionParams:
    """Settings of :func:`detect_markers`.

    Fields left at ``None`` take the mode's default (``_MODE_DEFAULTS``: IR, visible).

    Attributes
    ----------
    mode : {"ir", "visible"}
        ``"ir"``: bright markers on a dark scene, local median background.
        ``"visible"``: white/grey markers on a lit subject, local top-hat contrast.
    threshold : {"sigma", "otsu", "fixed"}
        How the signal threshold is chosen (see module doc).
    k_sigma : float or None
        ``"sigma"`` threshold in noise standard deviations (IR 6, visible 4).
    min_contrast : float or None
        Lowest threshold above the local background, grey levels (IR 20, visible 10).
    fixed_threshold : float
        Threshold above the background for ``threshold="fixed"``, grey levels.
    tophat_radius_px : int
        ``"visible"``: radius of the top-hat square; markers up to about
        ``2 * tophat_radius_px`` pixels across are kept whole, wider bright regions are
        background.
    background_cell_px, background_cells : int
        ``"ir"``: the local background is the median of ``background_cells`` x
        ``background_cells`` cells of ``background_cell_px`` pixels (blobs up to about
        half that span across are not part of it).
    min_area_px : int or None
        Smallest accepted blob (thresholded pixels; IR 3, visible 2).
    small_peak_factor : float
        A blob smaller than ``min_area_px`` (down to one pixel) is still accepted
        when its peak is at least this many times the threshold above the background. A
        14 mm marker 4-5 m from a 640x480 camera is 1-2 pixels across; noise that crosses
        the threshold barely does (on bvh_walk with 4 cameras the true 1-2 pixel blobs peak
        at 2.4x the threshold or more in 95 % of cases, median 4.2x). 0 disables.
    small_area_fraction : float
        Such a blob must also be at least this fraction of the median area of the
        image's blobs of ``min_area_px`` or more (where markers are 15-20 px, a 1-2 px blob is
        the sliver of a marker hidden behind the body, not a distant marker).
    max_area_px : int
        Largest accepted blob (thresholded pixels).
    min_fill_ratio : float or None
        Minimum blob area / area of the ellipse with the blob's second moments
        (IR 0.6, visible 0.5).
    max_elongation : float or None
        Maximum ratio of the ellipse's axes (IR 30: motion-blur streaks pass; visible 3:
        strips of background between limbs do not).
    dilate_px : int
        ``"ir"``: width of the ring of dim pixels around each blob included in the centroid.
    response : {"srgb", "linear"}
        ``"ir"``: the camera's transfer function from light to grey level. The centroid
        weighs each pixel by its *light* above the background, so sRGB-encoded frames (what
        webcams and the bench's cameras give) are decoded first; ``"linear"`` for machine
        vision cameras that output raw levels. On bvh_walk's 1-2 pixel markers the weights
        on encoded levels flatten the blob's profile and pull the centroid towards the pixel
        centres (RMS 0.197 -> 0.176 px against the true projections, the error's slope
        against the sub-pixel position 0.099 -> 0.034).
    achromatic : bool
        ``"visible"``: detect on ``min(R, G, B)`` of colour frames (white/grey markers).
    peak_fraction : float
        ``"visible"``: a blob is the pixels above this fraction of the local maximum of
        the top-hat (half maximum by default).
    ring_contrast : float
        ``"visible"``: grey levels the blob's peak must exceed the upper quartile of a
        ring just outside it by.
    shading_weight : float
        ``"visible"``: centroid weights saturate at this fraction of the blob's peak
        (1 = plain intensity weights).
    background_threshold : float
        With a static background image: pixels within this many grey levels of the
        background are ignored.
    mog2_history : int
        History (frames) of the MOG2 background model used by :func:`detect_frames`
        with ``background="mog2"``.
    mog2_var_threshold : float
        MOG2 variance threshold.
    """

    mode: Literal["ir", "visible"] = "ir"
    threshold: Literal["sigma", "otsu", "fixed"] = "sigma"
    k_sigma: float | None = None
    min_contrast: float | None = None
    fixed_threshold: float = 100.0
    tophat_radius_px: int = 3
    background_cell_px: int = 8
    background_cells: int = 5
    min_area_px: int | None = None
    small_peak_factor: float = 2.0
    small_area_fraction: float = 0.2
    max_area_px: int = 2000
    min_fill_ratio: float | None = None
    max_elongation: float | None = None
    dilate_px: int = 1
    response: Literal["srgb", "linear"] = "srgb"
    achromatic: bool = True
    peak_fraction: float = 0.5
    ring_contrast: float = 8.0
    shading_weight: float = 0.7
    background_threshold: float = 15.0
    mog2_history: int = 200
    mog2_var_threshold: float = 16.0

    def __post_init__(self) -> None:
        def opt(field: str) -> float:
            v = getattr(self, field)
            return 1.0 if v is None else v  # None is valid (the mode's default)

        require_one_of(self, "mode", ("ir", "visible"))
        require_one_of(self, "threshold", ("sigma", "otsu", "fixed"))
        require(opt("k_sigma") > 0, self, "k_sigma", "must be > 0 (or None: the mode's default)")
        require(opt("min_contrast") >= 0, self, "min_contrast", "must be >= 0 grey levels (or None)")
        require(0 < self.fixed_threshold < 255, self, "fixed_threshold", "must be in (0, 255)")
        require(self.tophat_radius_px >= 1, self, "tophat_radius_px", "must be >= 1 pixel")
        require(self.background_cell_px >= 1, self, "background_cell_px", "must be >= 1 pixel")
        require(self.background_cells >= 1 and self.background_cells % 2 == 1, self, "background_cells", "must be an odd number >= 1")
        require(1 <= opt("min_area_px") <= self.max_area_px, self, "min_area_px", f"need 1 <= min_area_px <= max_area_px ({self.max_area_px})")
        require(0 <= opt("min_fill_ratio") <= 1, self, "min_fill_ratio", "must be in [0, 1]")
        require(opt("max_elongation") >= 1, self, "max_elongation", "must be >= 1")
        require(self.dilate_px >= 0, self, "dilate_px", "must be >= 0")
        require_one_of(self, "response", {"srgb": "webcams", "linear": "raw levels"})
        require(0 <= self.peak_fraction < 1, self, "peak_fraction", "must be in [0, 1)")
        require(self.small_peak_factor >= 0, self, "small_peak_factor", "must be >= 0 (0: no blob under min_area_px)")
        require(0 <= self.small_area_fraction <= 1, self, "small_area_fraction", "must be in [0, 1]")
        require(self.ring_contrast >= 0, self, "ring_contrast", "must be >= 0 grey levels")
        require(0 < self.shading_weight <= 1, self, "shading_weight", "must be in (0, 1]")
        require(self.background_threshold >= 0, self, "background_threshold", "must be >= 0")
        require(self.mog2_history >= 1, self, "mog2_history", "must be >= 1")

    def resolved(self, field: str) -> float:
        """The value of a mode-dependent field (its mode default when left at None)."""
        v = getattr(self, field)
        return _MODE_DEFAULTS[self.mode][field] if v is None else v
