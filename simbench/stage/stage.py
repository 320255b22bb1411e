"""A scenario assembled into a stage: scene, motion, cameras, lights and renderer.

This is the layer between the validated :class:`~simbench.scenario.Scenario` and
the per-frame loop: it builds the MuJoCo scene (humanoid with marker sites, props),
the motion clip, the virtual cameras, the lights, the triangle geometry for the
rasteriser, and a ``pose_at(times)`` function that simulates the scene at any set of
(sub-frame) instants. :func:`simbench.stage.build.build_stage` picks this stage or,
for a real capture's markers, :class:`~simbench.stage.capture.CaptureStage`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from simbench.errors import ScenarioError
from simbench.render import ids as idc
from simbench.render.camera import VirtualCamera, cameras_from_scenario
from simbench.render.frames import FrameRenderer, Pose
from simbench.render.geometry import moving_geometry
from simbench.render.lighting import Lighting
from simbench.render.rasterizer import Rasterizer
from simbench.scenario import BallConfig, BarrierConfig, MovingConfig, Scenario
from simbench.scenes.anthropometry import BodyParams
from simbench.scenes.humanoid import BODY_NAMES, HINGE_NAMES
from simbench.scenes.markers import MARKER_RADIUS_M
from simbench.scenes.bvh import retarget_bvh_keys
from simbench.scenes.bvh_file import load_bvh
from simbench.scenes.motions import Motion, make_motion
from simbench.scenes.props import BallProp, BarrierProp, MovingProp
from simbench.scenes.scene import Scene, build_scene
from simbench.scenes.simulation import SceneStates, simulate
from simbench.stage.clocks import CameraClocks, camera_clocks
from simbench.stage.renderer import build_frame_renderer, mid_exposure_times


def body_params(scenario: Scenario) -> BodyParams:
    """The subject's body (height and proportions)."""
    return scenario.body.params()


def make_props(scenario: Scenario) -> list:
    props = []
    for p in scenario.props:
        if isinstance(p, BallConfig):
            props.append(BallProp(name=p.name, radius_m=p.radius_m, position=tuple(p.position), velocity=tuple(p.velocity), rgb=tuple(p.rgb)))
        elif isinstance(p, BarrierConfig):
            props.append(BarrierProp(name=p.name, size_m=tuple(p.size_m), position=tuple(p.position), yaw_deg=p.yaw_deg, rgb=tuple(p.rgb)))
        elif isinstance(p, MovingConfig):
            props.append(MovingProp(name=p.name, size_m=tuple(p.size_m), start=tuple(p.start), velocity=tuple(p.velocity), rgb=tuple(p.rgb)))
    return props


def make_scenario_motion(scenario: Scenario, params: BodyParams, rng: np.random.Generator) -> Motion:
    """The scenario's motion: scenario time ``t`` plays clip time ``start_s + speed * t``.

    A BVH clip must last ``start_s + duration_s * speed`` seconds (counted from its first
    frame after the converter's lead-in) unless ``motion.end`` says what to do past its end:
    ``"hold"`` its last pose or ``"loop"`` back to its first frame.

    Raises
    ------
    ScenarioError
        A BVH clip too short for the window with ``end = "error"``, a window that starts
        after the clip's end, or a ``name_map`` joint the file does not have.
    """
    m = scenario.motion
    needed = m.start_s + scenario.duration_s * m.speed
    if m.clip == "bvh":
        clip = _bvh_motion(scenario, params, needed)
    else:  # a procedural clip (the scenario checked the name)
        clip = make_motion(m.clip, params, needed + 0.1, rng=None)
    if m.start_s == 0.0 and m.speed == 1.0 and m.end != "loop":
        return clip
    if m.end == "loop":
        def evaluate(t: np.ndarray) -> np.ndarray:
            return clip.qpos(np.mod(m.start_s + m.speed * np.asarray(t), clip.duration_s))
    else:
        def evaluate(t: np.ndarray) -> np.ndarray:
            return clip.qpos(m.start_s + m.speed * np.asarray(t))
    return Motion(name=clip.name, duration_s=scenario.duration_s + 0.1, evaluate=evaluate, description=clip.description)


def _bvh_motion(scenario: Scenario, params: BodyParams, needed_s: float) -> Motion:
    """Load and retarget the scenario's BVH clip; check that it covers ``needed_s`` seconds."""
    m = scenario.motion
    where = scenario.origin
    path = scenario.resolve_path(m.bvh)
    bvh = load_bvh(path)
    for body, joint in m.name_map.items():
        if joint not in bvh.joint_names:
            raise ScenarioError(where, f"motion.name_map.{body}", joint,
                                f"{path} has no such joint; its joints: {', '.join(bvh.joint_names)}")
    keys = retarget_bvh_keys(bvh, params, name_map=m.name_map or None)
    clip = keys.motion()
    frames = f"frames {keys.frames[0]}-{keys.frames[-1]} at {1.0 / bvh.frame_time_s:.4g} Hz"
    if keys.frames[0]:
        frames += f", after the converter's {keys.frames[0]} lead-in frame(s)"
    if needed_s > clip.duration_s + 1e-9 and m.end == "error":
        raise ScenarioError(
            where, "motion", f"start_s + duration_s * speed = {m.start_s:g} + {scenario.duration_s:g} * {m.speed:g} "
            f"= {needed_s:.3f} s",
            f"the BVH clip {path} lasts {clip.duration_s:.3f} s ({frames}); shorten duration_s, start earlier, "
            "or set motion.end = \"hold\" (keep the last pose) or \"loop\"")
    if m.start_s >= clip.duration_s and m.end == "hold":
        raise ScenarioError(where, "motion.start_s", m.start_s,
                            f"the BVH clip {path} lasts {clip.duration_s:.3f} s ({frames}); start inside it")
    return clip


@dataclass
class Stage:
    scenario: Scenario
    params: BodyParams
    scene: Scene
    motion: Motion
    cameras: list[VirtualCamera]
    lighting: Lighting
    marker_names: list[str]
    prop_names: list[str]

    @classmethod
    def from_scenario(cls, scenario: Scenario) -> "Stage":
        """The humanoid's stage (a capture scenario's is :class:`~simbench.stage.capture.CaptureStage`;
        :func:`simbench.stage.build.build_stage` picks the right one)."""
        params = body_params(scenario)
        rng = np.random.default_rng(np.random.SeedSequence([scenario.seed, 0xB0D7]))
        marker_set = None if scenario.subject.markers == "none" else scenario.subject.markers
        scene = build_scene(params, marker_set=marker_set, shirt=scenario.subject.shirt, props=make_props(scenario),
                            skin_rgb=tuple(scenario.subject.skin_rgb), clothes_rgb=tuple(scenario.subject.suit_rgb))
        motion = make_scenario_motion(scenario, params, rng)
        cams = cameras_from_scenario(scenario)
        lighting = Lighting(scenario.lighting)
        return cls(scenario, params, scene, motion, cams, lighting,
                   [m.name for m in scene.marker_specs], [p.name for p in scene.props])

    # ------------------------------------------------------------------ states
    def states(self, times: np.ndarray) -> SceneStates:
        """Simulate the scene at increasing ``times`` (s)."""
        return simulate(self.scene, self.motion.qpos, np.asarray(times, float))

    def pose_at(self, times: np.ndarray) -> list[Pose]:
        st = self.states(times)
        out = []
        P = len(self.prop_names)
        for i in range(len(times)):
            prop_T = np.stack([st.prop_poses[n][i] for n in self.prop_names]) if P else np.zeros((0, 4, 4))
            probe = np.concatenate([st.joint_centres[i], st.marker_xpos[i]]) if st.marker_xpos.size else st.joint_centres[i]
            out.append(Pose(st.body_xpos[i], st.body_xmat[i].reshape(-1, 3, 3), st.marker_xpos[i], prop_T, probe))
        return out

    # ------------------------------------------------------------------ render
    def frame_times(self) -> np.ndarray:
        """Timestamps ``(F,)`` s of the take's frames: the middle of each exposure."""
        sc = self.scenario
        return mid_exposure_times(sc.n_frames, sc.fps, sc.sensor.exposure_ms)

    def clocks(self) -> CameraClocks:
        """Every camera's frame timing (:mod:`simbench.stage.clocks`; synchronised without ``[sensor.clock]``)."""
        sc = self.scenario
        return camera_clocks(sc.sensor.clock, len(self.cameras), sc.n_frames, sc.fps, sc.sensor.exposure_ms, sc.seed)

    def frame_renderer(self, rasterizer: Rasterizer | None = None) -> FrameRenderer:
        """The take's renderer: the scenario's room, sensor and lights; the body surface, markers and props moving."""
        sc = self.scenario
        prop_meshes = [(p.mesh(), np.asarray(p.rgb, float), idc.PROP_BASE + k) for k, p in enumerate(self.scene.props)]
        body_index = {name: self.scene.body_id(name) for name in BODY_NAMES}
        moving = moving_geometry(self.scene.surface_parts, body_index, len(self.marker_names), prop_meshes,
                                 self.marker_radius_m)
        return build_frame_renderer(self.cameras, sc.sensor, sc.fps, self.lighting, sc.set, sc.seed, moving,
                                    len(self.marker_names), self.marker_radius_m, rasterizer=rasterizer)

    @property
    def marker_radius_m(self) -> float:
        """The rendered marker spheres' radius: the bench's 14 mm spheres (a capture scenario may
        give its system's size, :class:`~simbench.stage.capture.CaptureStage`)."""
        return MARKER_RADIUS_M

    @property
    def hinge_names(self) -> list[str]:
        return list(HINGE_NAMES)

    def capture_reference(self):
        """A capture scenario's labelled reference trajectories
        (:class:`~simbench.scenes.capture_motion.CaptureReference`); None for a humanoid scenario."""
        return None
