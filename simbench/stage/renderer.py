"""The one place a frame renderer and frame times are made.

Every render of the bench (a scenario's take, its calibration session's board and wand
pictures, the shirt pipeline's empty-scene frames, the tracker study's videos) goes
through :func:`build_frame_renderer` and :func:`mid_exposure_times`, so the room, the
sensor and the timing rule are the same everywhere.
"""

from __future__ import annotations

import numpy as np

from simbench.render.camera import VirtualCamera
from simbench.render.frames import FrameRenderer
from simbench.render.geometry import MovingGeometry, set_geometry
from simbench.render.lighting import Lighting
from simbench.render.rasterizer import Rasterizer
from simbench.scenario import SensorConfig, SetConfig

__all__ = ["mid_exposure_times", "build_frame_renderer", "ROOM_SEED_KEY"]

#: Key of the room's random stream (its clutter) under the scenario's seed: every render of
#: one scenario (the take, its calibration session) shows the same room.
ROOM_SEED_KEY = 0x5E7


def mid_exposure_times(n_frames: int, fps: float, exposure_ms: float) -> np.ndarray:
    """Timestamps ``(n_frames,)`` s of frames at ``fps``: the middle of each frame's exposure,
    the instant a frame's ground truth describes (the shutter opens at ``k / fps``)."""
    return np.arange(n_frames) / fps + 0.5 * exposure_ms / 1000.0


def build_frame_renderer(cameras: list[VirtualCamera], sensor: SensorConfig, fps: float, lighting: Lighting,
                         room: SetConfig, seed: int, moving: MovingGeometry, n_markers: int = 0,
                         marker_radius_m: float = 0.0, rasterizer: Rasterizer | None = None) -> FrameRenderer:
    """The frame renderer of ``cameras`` through ``sensor`` at ``fps``, lit by ``lighting``.

    Parameters
    ----------
    room : SetConfig
        Floor, walls and clutter; the clutter is drawn from ``seed`` (:data:`ROOM_SEED_KEY`).
    moving : MovingGeometry
        What moves (body surface, markers, props, a board, a wand), posed per frame.
    n_markers, marker_radius_m
        The marker spheres among ``moving`` (their visibility is measured per frame).
    rasterizer : Rasterizer, optional
        A GL rasteriser to reuse (one per process is enough); a new one otherwise.
    """
    static = set_geometry(room, np.random.default_rng(np.random.SeedSequence([seed, ROOM_SEED_KEY])))
    return FrameRenderer(cameras, sensor, fps, lighting, static, moving, n_markers, marker_radius_m, rasterizer=rasterizer)
