"""Boundary types of the capture pipeline: detections in, labelled trajectories out.

Inside the pipeline everything is numpy; these small dataclasses carry arrays across
stage boundaries with their shapes and units stated once, here.
Units: pixels for 2D, metres for 3D, seconds for time.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np


@dataclass
class Detections:
    """Marker blobs found in one image.

    Attributes
    ----------
    xy : (n, 2) float
        Sub-pixel centroids in distorted pixel coordinates (x right, y down,
        pixel centres at integers, as OpenCV).
    area : (n,) float
        Blob area in pixels.
    intensity : (n,) float
        Mean grey level of the blob (0-255).
    limb_dir : (n, 2) float or None
        Visible-light detector: unit image direction towards the light of the image's
        markers (one direction shared by the image's blobs; see
        :func:`mocap.detection.visible.lit_limbs`). None when not measured.
    limb_dist : (n,) float or None
        Distance (px) from ``xy`` along ``limb_dir`` to the half-maximum edge of the blob's
        lit limb; NaN where not measured. Given the marker's image radius ``rho`` (px),
        ``xy + (limb_dist - rho) * limb_dir`` is a centroid free of the shading's pull
        (:func:`mocap.marker_pipeline.limb_centroids`).
    """

    xy: np.ndarray
    area: np.ndarray
    intensity: np.ndarray
    limb_dir: np.ndarray | None = None
    limb_dist: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.xy = np.asarray(self.xy, dtype=np.float64).reshape(-1, 2)
        n = len(self.xy)
        self.area = np.asarray(self.area, dtype=np.float64).reshape(n)
        self.intensity = np.asarray(self.intensity, dtype=np.float64).reshape(n)
        if self.limb_dir is not None:
            self.limb_dir = np.asarray(self.limb_dir, dtype=np.float64).reshape(n, 2)
            self.limb_dist = np.asarray(self.limb_dist, dtype=np.float64).reshape(n)

    def __len__(self) -> int:
        return len(self.xy)

    @classmethod
    def empty(cls) -> "Detections":
        return cls(np.zeros((0, 2)), np.zeros(0), np.zeros(0))

    @classmethod
    def from_points(cls, xy: np.ndarray) -> "Detections":
        """Detections from bare centroids (area and intensity unknown: NaN)."""
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        return cls(xy, np.full(len(xy), np.nan), np.full(len(xy), np.nan))


#: Status of a label in one camera's frame (:attr:`Tracks2D.status`, a 2D tracker's ``status``):
#: lost (not tracked), tracked with a detection, or coasting on its prediction.
LOST: int = 0
TRACKED: int = 1
COASTING: int = 2


@dataclass
class Tracks2D:
    """Labelled 2D marker tracks of every camera.

    Attributes
    ----------
    labels : list[str], length M
    xy : (F, C, M, 2) float
        Measured (associated detection) pixel position; NaN where the label had no
        detection in that frame (coasting, lost, or not seen).
    predicted_xy : (F, C, M, 2) float
        Tracker estimate (posterior, or prediction while coasting); NaN when lost.
    status : (F, C, M) int8
        :data:`LOST` (0, not tracked), :data:`TRACKED` (1, with a detection) or :data:`COASTING`
        (2, on its prediction).
    camera_names : list[str], length C
    """

    labels: list[str]
    xy: np.ndarray
    predicted_xy: np.ndarray
    status: np.ndarray
    camera_names: list[str]

    LOST: ClassVar[int] = LOST
    TRACKED: ClassVar[int] = TRACKED
    COASTING: ClassVar[int] = COASTING


@dataclass
class Trajectories:
    """Labelled 3D marker trajectories.

    Attributes
    ----------
    labels : list[str], length M
    xyz : (F, M, 3) float
        Positions in metres, world frame; NaN in gaps.
    times : (F,) float
        Timestamps in seconds (middle of each frame's exposure).
    filled : (F, M) bool
        True where ``xyz`` was filled by interpolation rather than triangulated.
    residual_px : (F, M) float
        Mean reprojection residual of the views used, NaN where not triangulated.
    n_views : (F, M) int
        Number of cameras used for each point (0 in gaps).
    """

    labels: list[str]
    xyz: np.ndarray
    times: np.ndarray
    filled: np.ndarray | None = None
    residual_px: np.ndarray | None = None
    n_views: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.xyz = np.asarray(self.xyz, dtype=np.float64)
        F, M = self.xyz.shape[:2]
        if self.xyz.shape != (F, M, 3) or len(self.labels) != M:
            raise ValueError(f"xyz must be (F, M, 3) with M = len(labels) = {len(self.labels)}, got {self.xyz.shape}")
        self.times = np.asarray(self.times, dtype=np.float64).reshape(F)
        if self.filled is None:
            self.filled = np.zeros((F, M), dtype=bool)
        if self.residual_px is None:
            self.residual_px = np.full((F, M), np.nan)
        if self.n_views is None:
            self.n_views = np.where(np.isfinite(self.xyz).all(axis=2), 2, 0).astype(np.int16)

    @property
    def rate_hz(self) -> float:
        if len(self.times) < 2:
            return float("nan")
        return float(1.0 / np.median(np.diff(self.times)))
