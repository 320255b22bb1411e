"""The stage of a capture scenario (``[motion] c3d`` / ``trc``): marker spheres only.

:class:`CaptureStage` is a :class:`~simbench.stage.stage.Stage` whose markers are the real
capture's (:mod:`simbench.scenes.capture_motion`) instead of a humanoid's marker sites:

* The MuJoCo scene keeps its humanoid (the simulation drives one, and props collide with
  it) but has no marker sites and no rendered surface, and the humanoid is parked
  :data:`PARK_HEIGHT_M` above the floor, out of reach of any prop. Props still work.
* :meth:`CaptureStage.states` returns the capture's marker positions (NaN where missing)
  and NaN for the humanoid's qpos and joint centres: there is no body to score.
* The renderer draws each marker at its position, and nothing where the position is NaN,
  so a missing sample is an absent marker in the frames and in the ground truth's
  visibility (its visible fraction is 0).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from simbench.stage.stage import Stage, body_params, make_props
from simbench.errors import ScenarioError
from simbench.render.camera import cameras_from_scenario
from simbench.render.frames import FrameRenderer
from simbench.render.geometry import MovingGeometry
from simbench.render.lighting import Lighting
from simbench.scenario import Scenario
from simbench.scenes.capture_motion import CaptureClip, CaptureReference, load_capture_clip
from simbench.scenes.humanoid import NQ, tpose_qpos
from simbench.scenes.motions import Motion
from simbench.scenes.scene import build_scene
from simbench.scenes.simulation import SceneStates

__all__ = ["CaptureStage", "PARK_HEIGHT_M"]

PARK_HEIGHT_M = 100.0  # the unused humanoid stands this high: no prop reaches it, no floor contact


class _AbsentMarkersGeometry(MovingGeometry):
    """Moving geometry that draws nothing for a marker whose position is not finite.

    Such a marker's sphere is collapsed onto one point, the centre of a drawn marker
    (or the world origin if none is drawn): its triangles have no area, so they cover no
    pixel, and the image region the moving geometry spans (the rasteriser bounds it by
    the vertices) stays that of the drawn geometry.
    """

    def __post_init__(self) -> None:
        super().__post_init__()
        self._marker_vertices = {i: np.arange(sl.start, sl.stop) for kind, i, sl in self.group_slices if kind == "marker"}

    def pose(self, body_pos, body_rot, marker_pos, prop_T):
        mp = np.asarray(marker_pos, dtype=np.float64).reshape(-1, 3)
        shown = np.isfinite(mp).all(axis=1)
        anchor = mp[np.argmax(shown)] if shown.any() else np.zeros(3)
        P, N = super().pose(body_pos, body_rot, np.where(shown[:, None], mp, anchor), prop_T)
        for m in np.flatnonzero(~shown):
            P[self._marker_vertices[int(m)]] = anchor
        return P, N


@dataclass
class CaptureStage(Stage):
    """A bench that replays a real capture's markers (see the module doc)."""

    clip: CaptureClip | None = None

    @classmethod
    def from_capture_scenario(cls, scenario: Scenario) -> "CaptureStage":
        where = scenario.source_dir or scenario.name
        if scenario.subject.shirt:
            raise ScenarioError(where, "subject.shirt", True, "a capture scenario renders the file's markers only; remove shirt")
        params = body_params(scenario)
        clip = load_capture_clip(scenario)
        scene = build_scene(params, marker_set=None, props=make_props(scenario))
        scene = dataclasses.replace(scene, surface_parts=())  # the humanoid is not rendered
        parked = tpose_qpos(params)
        parked[2] += PARK_HEIGHT_M
        motion = Motion(name=f"capture:{clip.path.name}", duration_s=scenario.duration_s + 0.1,
                        evaluate=lambda t: np.broadcast_to(parked, (len(t), NQ)).copy(),
                        description=f"real capture {clip.path.name}: {clip.n_markers} markers")
        cams = cameras_from_scenario(scenario)
        lighting = Lighting(scenario.lighting, scenario_path=where)
        return cls(scenario, params, scene, motion, cams, lighting, list(clip.labels), [p.name for p in scene.props],
                   clip=clip)

    def states(self, times: np.ndarray) -> SceneStates:
        """Props simulated as usual; markers from the capture (NaN where missing); no humanoid."""
        st = super().states(times)
        qpos = st.qpos.copy()
        qpos[:, :NQ] = np.nan
        return dataclasses.replace(st, marker_xpos=self.clip.positions_at(st.times), qpos=qpos,
                                   joint_centres=np.full_like(st.joint_centres, np.nan), marker_names=self.clip.labels)

    def frame_renderer(self, rasterizer=None) -> FrameRenderer:
        renderer = super().frame_renderer(rasterizer)
        # Same vertex buffers (already uploaded), posed so that absent markers are not drawn.
        renderer.moving = _AbsentMarkersGeometry(renderer.moving.buffers, renderer.moving.group_slices)
        return renderer

    def capture_reference(self) -> CaptureReference:
        """The capture's labelled trajectories at the frame times (what a user's subject
        calibration of this marker set gives): see :class:`CaptureReference`."""
        times = self.scenario.frame_times()
        return CaptureReference(self.clip.labels, self.clip.file_positions_at(times), times)
