"""What the cameras saw during calibration, as dense arrays.

Views are synchronised by index: view ``v`` of every camera is the same moment (the
``v``-th image of each camera's list, or frame ``v`` of each video).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from mocap.calib.boards import BoardSpec, board_object_points
from mocap.calib.errors import CalibrationError


@dataclass
class BoardObservations:
    """Board corners seen by every camera in every synchronised view.

    Attributes
    ----------
    board : BoardSpec
    camera_names : list[str], length C
    image_sizes : list[(int, int)], length C
        ``(width, height)`` per camera.
    corners_px : (C, V, N, 2) float
        Distorted pixel positions of board corner ``n`` in view ``v`` of camera ``c``;
        NaN where not seen. ``N = board.n_corners``.
    view_labels : list[list[str]], C x V
        File name or ``video#frame`` of each view, for messages.
    """

    board: BoardSpec
    camera_names: list[str]
    image_sizes: list[tuple[int, int]]
    corners_px: np.ndarray
    view_labels: list[list[str]] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.corners_px = np.asarray(self.corners_px, dtype=np.float64)
        C = len(self.camera_names)
        if self.corners_px.ndim != 4 or self.corners_px.shape[0] != C or self.corners_px.shape[2:] != (self.board.n_corners, 2):
            raise ValueError(
                f"corners_px must be (C={C}, V, N={self.board.n_corners}, 2) for a {self.board.describe()}, "
                f"got {self.corners_px.shape}"
            )
        if len(self.image_sizes) != C:
            raise ValueError(f"image_sizes needs one (width, height) per camera ({C}), got {len(self.image_sizes)}")
        self.image_sizes = [(int(w), int(h)) for w, h in self.image_sizes]
        V = self.corners_px.shape[1]
        if not self.view_labels:
            self.view_labels = [[f"view {v}" for v in range(V)] for _ in range(C)]
        if len(self.view_labels) != C or any(len(lab) != V for lab in self.view_labels):
            raise ValueError(f"view_labels must be {C} lists of {V} labels")

    @property
    def n_cameras(self) -> int:
        return self.corners_px.shape[0]

    @property
    def n_views(self) -> int:
        return self.corners_px.shape[1]

    @property
    def object_points(self) -> np.ndarray:
        """Board corners in the board frame, ``(N, 3)`` metres."""
        return board_object_points(self.board)

    @property
    def seen(self) -> np.ndarray:
        """``(C, V, N)`` bool: corner observed."""
        return np.isfinite(self.corners_px).all(axis=3)

    def usable(self, min_corners: int = 6) -> np.ndarray:
        """``(C, V)`` bool: view has at least ``min_corners`` corners (all, for a checkerboard)."""
        n = self.seen.sum(axis=2)
        need = self.board.n_corners if self.board.kind == "checkerboard" else max(4, int(min_corners))
        return n >= need

    def camera_index(self, name: str) -> int:
        """Index of camera ``name``; :class:`CalibrationError` naming the cameras if unknown."""
        if name not in self.camera_names:
            raise CalibrationError(f"no camera named {name!r}; the cameras are {', '.join(self.camera_names)} "
                                   f"(check --reference / --world-camera)")
        return self.camera_names.index(name)


@dataclass
class WandObservations:
    """The three wand markers seen by every camera in every synchronised frame.

    Attributes
    ----------
    camera_names : list[str], length C
    markers_px : (C, F, 3, 2) float
        Distorted pixel centroid of wand marker ``m`` (0, 1, 2, labelled as in
        :class:`mocap.calib.wand.WandSpec`) in frame ``f`` of camera ``c``; NaN where
        not seen.
    """

    camera_names: list[str]
    markers_px: np.ndarray

    def __post_init__(self) -> None:
        self.markers_px = np.asarray(self.markers_px, dtype=np.float64)
        C = len(self.camera_names)
        if self.markers_px.ndim != 4 or self.markers_px.shape[0] != C or self.markers_px.shape[2:] != (3, 2):
            raise ValueError(f"wand markers_px must be (C={C}, F, 3, 2) pixels, got {self.markers_px.shape}")

    @property
    def n_frames(self) -> int:
        return self.markers_px.shape[1]

    @property
    def complete(self) -> np.ndarray:
        """``(C, F)`` bool: all three markers seen."""
        return np.isfinite(self.markers_px).all(axis=(2, 3))

    def reordered(self, camera_names: Sequence[str]) -> "WandObservations":
        """The same observations with cameras in the order ``camera_names``."""
        missing = [n for n in camera_names if n not in self.camera_names]
        if missing:
            raise CalibrationError(f"the wand observations have no camera {', '.join(map(repr, missing))}; they have "
                                   f"{', '.join(map(repr, self.camera_names))} (give camera_names in the wand file)")
        idx = [self.camera_names.index(n) for n in camera_names]
        return WandObservations(list(camera_names), self.markers_px[idx])
