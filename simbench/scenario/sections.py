"""The scenario's sections, one pydantic model per TOML table: body, subject, motion, sensor and
its clock, cameras and rig, lighting (:data:`LIGHTING_PRESETS`), set and props, the pipelines,
the calibration session. Names are checked against their registries here (see
:mod:`simbench.scenario`)."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from types import MappingProxyType
from typing import Annotated, Literal, Mapping, Union

import numpy as np
from pydantic import Field, StrictBool, StrictFloat, StrictInt, ValidationInfo, field_validator, model_serializer, model_validator

from mocap.calib.boards import ARUCO_DICTIONARIES
from mocap.errors import MocapInputError
from mocap.trackers import get_tracker
from simbench.scenario.fields import RGB, Distortion, FilePath, FrozenModel, Int, Length, Name, Real, Vec3, field_error, omit_defaults
from simbench.scenes.anthropometry import BODY_NAMES, BodyParams
from simbench.scenes.markers import MARKER_SETS
from simbench.scenes.motions import MOTIONS


class BodyConfig(FrozenModel):
    height_m: Real = Field(1.75, ge=1.2, le=2.2, description="standing height")
    proportions: dict[str, Real] = Field(default_factory=dict, description="overrides of anthropometric fractions of height")

    @model_validator(mode="after")
    def _proportions_are_body_parameters(self):
        allowed = [f.name for f in dataclasses.fields(BodyParams) if f.name != "height_m"]
        unknown = sorted(set(self.proportions) - set(allowed))
        if unknown:
            raise ValueError(f"proportions {unknown} are not body parameters; use: {', '.join(allowed)}")
        self.params()  # BodyParams names a value out of its range
        return self

    def params(self) -> BodyParams:
        """The subject's :class:`BodyParams`: the height and the proportions' overrides."""
        return BodyParams(height_m=self.height_m, **self.proportions)


#: Marker sets a subject can wear (:data:`simbench.scenes.markers.MARKER_SETS`), or none.
MarkerSetName = Literal[tuple([*MARKER_SETS, "none"])]


class SubjectConfig(FrozenModel):
    markers: MarkerSetName = "plugin_gait_full"
    shirt: StrictBool = False
    suit_rgb: RGB = Field((0.04, 0.04, 0.05), description="linear albedo of the suit/clothes")
    skin_rgb: RGB = (0.55, 0.38, 0.30)


class CaptureGapsConfig(FrozenModel):
    """Artificial gaps cut into a real capture (``motion.c3d`` / ``motion.trc``), seeded by ``seed``:
    ``fraction`` of the markers each lose ``runs`` runs of ``min_frames``..``max_frames``
    rendered frames (a marker in a gap is not rendered and is absent from the ground truth)."""

    fraction: Real = Field(0.2, gt=0.0, le=1.0, description="fraction of the markers that get gaps")
    min_frames: Int = Field(2, ge=1, le=100_000, description="shortest gap, in frames at the scenario's fps")
    max_frames: Int = Field(70, ge=1, le=100_000, description="longest gap, in frames at the scenario's fps")
    runs: Int = Field(1, ge=1, le=50, description="gaps per chosen marker (they never touch)")

    @model_validator(mode="after")
    def _lengths(self):
        if self.min_frames > self.max_frames:
            raise ValueError(f"min_frames = {self.min_frames} exceeds max_frames = {self.max_frames}")
        return self


_CAPTURE_FIELDS = {"c3d": None, "trc": None, "labels": None, "up_axis": "auto", "gaps": None}
_BVH_FIELDS = {"end": "error", "name_map": {}}  # omitted from the dump at their defaults, as the capture fields
#: Capture fields added after capture scenarios' content hashes were recorded: omitted at their defaults.
_LATER_CAPTURE_FIELDS = {"marker_diameter_mm": None}
#: The rendered markers' diameter a capture may ask for: from a 3 mm LED (a sub-pixel blob beyond a
#: few metres, which the IR detector still takes) to a 40 mm sphere.
CAPTURE_MARKER_DIAMETER_MM = (3.0, 40.0)


class MotionConfig(FrozenModel):
    clip: str = Field("wave_slow", description="procedural clip name, or 'bvh' to load `bvh`")
    bvh: FilePath | None = Field(None, description="BVH file (relative to the scenario file)")
    start_s: Real = Field(0.0, ge=0.0, le=36_000.0, description="offset into the clip (or the capture)")
    speed: Real = Field(1.0, gt=0.0, le=10.0)
    c3d: FilePath | None = Field(None, description="real capture (relative to the scenario file): its physical markers are "
                                              "rendered as marker spheres and are the ground truth; no humanoid")
    trc: FilePath | None = Field(None, description="as c3d, from a TRC file")
    labels: tuple[str, ...] | None = Field(None, description="c3d/trc: the markers to render (default: every physical marker)")
    up_axis: Literal["auto", "x", "y", "z"] = Field("auto", description="c3d/trc: the file's up axis (auto: from the file)")
    gaps: CaptureGapsConfig | None = Field(None, description="c3d/trc: seeded artificial gaps")
    subject_trial: Literal["take", "rest"] = Field(
        "take", description="c3d/trc: the labelled trial the marker pipeline learns the markers' rigid clusters and its "
        "label template from: 'take', the rendered window itself (a subject calibration made on the very frames "
        "captured), or 'rest', the file's samples outside the window (another trial of the same subject, as a user has)")
    marker_diameter_mm: Real | None = Field(
        None, ge=CAPTURE_MARKER_DIAMETER_MM[0], le=CAPTURE_MARKER_DIAMETER_MM[1],
        description="c3d/trc: diameter of the rendered marker spheres, the capture system's marker size "
        "(default: the bench's 14 mm spheres); the marker pipeline is given the same size")
    end: Literal["error", "hold", "loop"] = Field(
        "error", description="bvh: a clip shorter than start_s + duration_s * speed is an error, holds its last pose, "
        "or starts again from its first frame (the pose jumps there unless the clip is a cycle)")
    name_map: dict[str, str] = Field(
        default_factory=dict, description="bvh: humanoid body -> BVH joint, for joints whose names are not recognised "
        "(bodies: " + ", ".join(BODY_NAMES) + ")")

    @field_validator("clip")
    @classmethod
    def _known_clip(cls, v: str) -> str:
        if v not in MOTIONS and v not in ("bvh", "c3d", "trc"):
            raise ValueError(f"unknown clip; choose one of {', '.join(MOTIONS)}, or 'bvh' with `bvh = \"file.bvh\"` "
                             "(a capture: give `c3d` or `trc`)")
        return v

    @field_validator("name_map")
    @classmethod
    def _name_map_bodies(cls, v: dict[str, str]) -> dict[str, str]:
        unknown = sorted(set(v) - set(BODY_NAMES))
        if unknown:
            raise ValueError(f"keys {unknown} are not humanoid bodies; use: {', '.join(BODY_NAMES)}")
        empty = sorted(body for body, joint in v.items() if not joint.strip())
        if empty:
            raise ValueError(f"no joint given for {empty}")
        return v

    @model_validator(mode="after")
    def _name_map_needs_bvh(self):
        if self.name_map and not self.bvh:
            raise ValueError("name_map applies to a BVH clip only; give `bvh`")
        return self

    @model_validator(mode="after")
    def _bvh_needs_path(self):
        if self.clip == "bvh" and not self.bvh:
            raise ValueError("clip = 'bvh' needs `bvh = \"path/to/file.bvh\"`")
        sources = [k for k in ("bvh", "c3d", "trc") if getattr(self, k)]
        if len(sources) > 1:
            raise ValueError(f"give one motion source, not {' and '.join(sources)}")
        capture = "c3d" if self.c3d else "trc" if self.trc else None
        if capture:
            if "clip" in self.model_fields_set and self.clip != capture:
                raise ValueError(f"clip = {self.clip!r} conflicts with `{capture}`; leave clip out")
            object.__setattr__(self, "clip", capture)  # says what drives the scene (`simbench info`)
        else:
            extra = ([k for k in ("labels", "gaps", "marker_diameter_mm") if getattr(self, k) is not None] + (["up_axis"] if self.up_axis != "auto" else [])
                     + (["subject_trial"] if self.subject_trial != "take" else []))
            if extra:
                raise ValueError(f"{', '.join(extra)} apply to a capture file only; give `c3d` or `trc`")
        return self

    @model_serializer(mode="wrap")
    def _omit_unused_capture_fields(self, handler):
        # Scenarios without a capture serialise (and hash) as they did before these fields.
        data = handler(self)
        if not (self.c3d or self.trc):
            data = omit_defaults(data, _CAPTURE_FIELDS)
        return omit_defaults(omit_defaults(data, _BVH_FIELDS), _LATER_CAPTURE_FIELDS)


class ClockConfig(FrozenModel):
    """``[sensor.clock]``: each camera on its own clock (seeded draws per camera, from the scenario's seed).

    Camera ``c``'s clock reading ``s`` happens at true time ``offset_c + (1 + ppm_c * 1e-6) * s``;
    tick ``i`` of the clock exposes at ``s = i / fps + jitter`` (mid-exposure) and the camera
    stamps the frame with that reading. A tick's frame may be dropped (not delivered) or be a
    duplicate (the previous frame's image again, under the tick's timestamp).
    """

    offset_ms_max: Real = Field(0.0, ge=0.0, le=10_000.0, description="start offsets drawn uniformly in +-this (ms)")
    drift_ppm_max: Real = Field(0.0, ge=0.0, le=10_000.0, description="clock-rate errors drawn uniformly in +-this (ppm)")
    jitter_ms: Real = Field(0.0, ge=0.0, le=10.0, description="frame-interval jitter, RMS (ms); clipped at 3 RMS")
    drop_probability: Real = Field(0.0, ge=0.0, le=0.5, description="chance that a tick's frame is dropped")
    duplicate_probability: Real = Field(0.0, ge=0.0, le=0.5, description="chance that a tick repeats the previous frame")

    @property
    def synchronised(self) -> bool:
        """True when every field is zero: the cameras expose together, as without ``[sensor.clock]``."""
        return not (self.offset_ms_max or self.drift_ppm_max or self.jitter_ms or self.drop_probability
                    or self.duplicate_probability)


class SensorConfig(FrozenModel):
    """The webcam's sensor and image processing (shared by all cameras)."""

    mode: Literal["visible", "ir"] = "visible"
    exposure_ms: Real = Field(8.0, gt=0.0, le=200.0, description="shutter open time; must fit in 1/fps")
    gain: Real = Field(1.0, gt=0.0, le=64.0)
    full_well_e: Real = Field(8000.0, gt=100.0, le=1e7)
    read_noise_e: Real = Field(3.0, ge=0.0, le=1000.0)
    shot_noise: StrictBool = True
    white_balance: Literal["fixed", "auto"] = "fixed"
    wb_cct_k: Real = Field(5000.0, ge=1667.0, le=25000.0, description="illuminant the fixed white balance is set for")
    wb_adapt_s: Real = Field(1.0, gt=0.0, le=600.0, description="time constant of auto white balance")
    gamma: Literal["srgb", "linear"] = "srgb"
    jpeg_quality: Int = Field(0, ge=0, le=100, description="0 = no JPEG compression")
    motion_blur: StrictBool = True
    blur_step_px: Real = Field(0.75, gt=0.0, le=100.0, description="max image motion between shutter sub-frames")
    max_subframes: Int = Field(24, ge=1, le=128)
    antialias: Int = Field(2, ge=1, le=4, description="supersampling factor per axis")
    psf_sigma_px: Real = Field(0.4, ge=0.0, le=5.0, description="Gaussian optics blur")
    ring_light: Real = Field(6.0, ge=0.0, le=1000.0, description="IR ring light strength")
    electrons_per_unit: Real = Field(4.0e5, gt=0.0, le=1e10, description="sensor sensitivity: e- per radiance unit per second")
    clock: ClockConfig | None = Field(None, description="each camera's own clock (offset, drift, jitter, drops); "
                                      "none: synchronised global shutters")
    readout_ms: Real = Field(0.0, ge=0.0, le=1000.0, description="rolling shutter: row y of an H-row frame is exposed "
                             "y / H * readout later than row 0 (the frame's timestamp); 0 = global shutter; "
                             "must fit in 1/fps")
    auto_exposure: StrictBool = Field(False, description="auto exposure: the gain follows the frame's mean level "
                                      "towards ae_target with time constant ae_adapt_s")
    ae_target: Real = Field(0.18, gt=0.0, lt=1.0, description="auto exposure's target mean level (linear, of full scale)")
    ae_adapt_s: Real = Field(0.1, gt=0.0, le=600.0, description="time constant of auto exposure (s)")
    ae_max_gain: Real = Field(16.0, ge=1.0, le=64.0, description="auto exposure's largest gain (times `gain`)")
    vignetting: Real = Field(0.0, ge=0.0, le=0.95, description="relative light loss at the image corners "
                             "(radial, 1 - v * (r / r_corner)^2); 0 = none")

    @model_serializer(mode="wrap")
    def _omit_unset_clock(self, handler):
        # Sensors without a clock (and the later fields at their defaults) serialise (and hash)
        # as they did before those fields.
        return omit_defaults(handler(self), {"clock": None, **_LATER_SENSOR_FIELDS})


#: Sensor fields added after scenarios' content hashes were recorded: omitted from a sensor's
#: serialisation at their defaults, so that older scenarios hash as before.
_LATER_SENSOR_FIELDS = {"readout_ms": 0.0, "auto_exposure": False, "ae_target": 0.18, "ae_adapt_s": 0.1,
                        "ae_max_gain": 16.0, "vignetting": 0.0}


class CameraConfig(FrozenModel):
    name: Name
    position: Vec3
    look_at: Vec3 = (0.0, 0.0, 1.0)
    up: Vec3 = (0.0, 0.0, 1.0)
    width: Int = Field(640, ge=16, le=4096)
    height: Int = Field(480, ge=16, le=4096)
    hfov_deg: Real | None = Field(None, gt=5.0, lt=170.0)
    K: tuple[tuple[Real, Real, Real], tuple[Real, Real, Real], tuple[Real, Real, Real]] | None = None
    distortion: Distortion = (0.0, 0.0, 0.0, 0.0, 0.0)

    @model_validator(mode="after")
    def _one_intrinsics(self):
        if self.hfov_deg is None and self.K is None:
            object.__setattr__(self, "hfov_deg", 60.0)
        if self.hfov_deg is not None and self.K is not None:
            raise ValueError("give either hfov_deg or K, not both")
        if np.linalg.norm(np.subtract(self.look_at, self.position)) < 1e-6:
            raise field_error("look_at", self.look_at, "look_at must differ from position")
        if np.linalg.norm(self.up) < 1e-6:
            raise field_error("up", self.up, "the up vector must not be zero (e.g. [0, 0, 1])")
        if self.K is not None:
            K = np.asarray(self.K)
            if not (K[0, 0] > 0 and K[1, 1] > 0):
                raise field_error("K", self.K, "the focal lengths K[0][0] and K[1][1] must be positive (pixels)")
            if K[1, 0] != 0 or K[2, 0] != 0 or K[2, 1] != 0 or K[2, 2] != 1:
                raise field_error("K", self.K, "K must be [[fx, s, cx], [0, fy, cy], [0, 0, 1]]")
            if not (0 <= K[0, 2] <= self.width and 0 <= K[1, 2] <= self.height):
                raise field_error("K", self.K, f"the principal point (cx, cy) = ({K[0, 2]}, {K[1, 2]}) must lie in the "
                                               f"{self.width}x{self.height} image")
        return self

    def half_fov_deg(self) -> float:
        """Half the narrower of the horizontal and vertical fields of view (principal point at the centre)."""
        fx, fy = (self.K[0][0], self.K[1][1]) if self.K is not None else (0.5 * self.width / math.tan(math.radians(self.hfov_deg) / 2),) * 2
        return math.degrees(min(math.atan(0.5 * self.width / fx), math.atan(0.5 * self.height / fy)))


class RigConfig(FrozenModel):
    """Generates ``count`` cameras on a circle around ``look_at``."""

    count: Int = Field(4, ge=1, le=32, description="cameras (`simbench run`'s marker pipeline triangulates: two at least)")
    radius_m: Real = Field(3.5, gt=0.3, le=100.0)
    height_m: Real = Field(2.0, ge=0.0, le=50.0)
    look_at: Vec3 = (0.0, 0.0, 1.0)
    start_deg: Real = Field(30.0, ge=-720.0, le=720.0, description="azimuth of the first camera (0 = in front, +X)")
    span_deg: Real = Field(360.0, gt=0.0, le=360.0)
    hfov_deg: Real = Field(60.0, gt=5.0, lt=170.0)
    width: Int = Field(640, ge=16, le=4096)
    height: Int = Field(480, ge=16, le=4096)
    distortion: Distortion = (0.0, 0.0, 0.0, 0.0, 0.0)

    def camera_configs(self) -> tuple[CameraConfig, ...]:
        """``count`` cameras ``cam0``, ``cam1``, ... evenly spread over ``span_deg`` of azimuth around ``look_at``."""
        step = self.span_deg / self.count if self.span_deg >= 360.0 else self.span_deg / max(self.count - 1, 1)
        cams = []
        for i in range(self.count):
            az = np.deg2rad(self.start_deg + i * step)
            pos = np.array(self.look_at) + np.array([self.radius_m * np.cos(az), self.radius_m * np.sin(az), 0.0])
            pos[2] = self.height_m
            cams.append(CameraConfig(name=f"cam{i}", position=tuple(pos), look_at=self.look_at, width=self.width, height=self.height,
                                     hfov_deg=self.hfov_deg, distortion=self.distortion))
        return tuple(cams)
    from_calibration: str | None = Field(
        None, description="the whole rig from a calibration file (OpenCV .yml, anipose calibration.toml, Pose2Sim "
        "Calib.toml or an EasyMocap folder; relative to the scenario): its cameras replace the circle above")

    @model_serializer(mode="wrap")
    def _omit_unused_calibration_file(self, handler):
        # Rigs without a calibration file serialise (and hash) as they did before the field.
        return omit_defaults(handler(self), {"from_calibration": None})


class LightConfig(FrozenModel):
    name: Name
    kind: Literal["point", "directional"] = "point"
    position: Vec3 | None = None
    direction: Vec3 | None = None
    cct_k: Real = Field(4000.0, ge=1667.0, le=25000.0)
    tint: Real = Field(0.0, ge=-5.0, le=5.0)
    intensity: Real = Field(1.0, ge=0.0, le=10_000.0)

    @model_validator(mode="after")
    def _geometry(self):
        if self.kind == "point" and self.position is None:
            raise ValueError("a point light needs `position`")
        if self.kind == "directional" and self.direction is None:
            raise ValueError("a directional light needs `direction`")
        if self.direction is not None and np.linalg.norm(self.direction) < 1e-6:
            raise field_error("direction", self.direction, "a light's direction must not be zero")
        return self


class LightEventConfig(FrozenModel):
    t_s: Real = Field(ge=0.0, le=36_000.0)
    light: str
    intensity: Real = Field(ge=0.0, le=10_000.0, description="new intensity (0 = switched off)")


_CEILING = tuple(LightConfig(name=f"ceiling_{i}", kind="point", position=(x, y, 2.9), cct_k=4100.0, tint=1.5, intensity=5.0)
                 for i, (x, y) in enumerate(((1.5, 1.5), (1.5, -1.5), (-1.5, 1.5), (-1.5, -1.5))))
_TUNGSTEN = LightConfig(name="tungsten", kind="point", position=(1.4, 1.3, 1.7), cct_k=2800.0, intensity=7.0)

#: The lights of each lighting preset (their ambient light: :mod:`simbench.render.lighting`).
LIGHTING_PRESETS: Mapping[str, tuple[LightConfig, ...]] = MappingProxyType({
    "office_fluorescent": _CEILING,
    "tungsten_lamp": (_TUNGSTEN,),
    "daylight_outdoor": (LightConfig(name="sun", kind="directional", direction=(-0.4, 0.3, -0.85), cct_k=5600.0, intensity=7.0),),
    "dim_gym": tuple(LightConfig(name=f"gym_{i}", kind="point", position=(x, 0.0, 6.0), cct_k=4300.0, intensity=12.0)
                     for i, x in enumerate((-2.0, 2.0))),
    "mixed": _CEILING + (_TUNGSTEN,),
    "custom": (),
})


class LightingConfig(FrozenModel):
    preset: Literal[tuple(LIGHTING_PRESETS)] = "office_fluorescent"
    scale: Real = Field(1.0, gt=0.0, le=1000.0, description="multiplies every light (brighter/dimmer scene)")
    lights: tuple[LightConfig, ...] = ()
    events: tuple[LightEventConfig, ...] = ()

    @field_validator("events")
    @classmethod
    def _events_switch_lights_of_the_set(cls, events: tuple[LightEventConfig, ...], info: ValidationInfo):
        if "preset" not in info.data or "lights" not in info.data:
            return events  # the preset or the lights failed their own validation
        names = sorted({light.name for light in LIGHTING_PRESETS[info.data["preset"]]} | {light.name for light in info.data["lights"]})
        for i, ev in enumerate(events):
            if ev.light not in names:
                raise ValueError(f"event {i} switches light {ev.light!r}, which this lighting does not have; its lights are {names}")
        return events

    @model_validator(mode="after")
    def _custom_needs_lights(self):
        if self.preset == "custom" and not self.lights:
            raise ValueError("preset 'custom' needs at least one [[lighting.lights]] entry")
        return self


class SetConfig(FrozenModel):
    floor: StrictBool = True
    walls: StrictBool = True
    room_size_m: Real = Field(8.0, gt=2.0, le=200.0)
    floor_rgb: RGB = (0.35, 0.33, 0.30)
    wall_rgb: RGB = (0.55, 0.55, 0.52)
    clutter: Int = Field(0, ge=0, le=50, description="number of coloured boxes around the room")


class BallConfig(FrozenModel):
    kind: Literal["ball"] = "ball"
    name: Name = "ball"
    radius_m: Real = Field(0.11, gt=0.0, le=0.5, description="up to a 1 m ball")
    position: Vec3 = (2.0, -0.3, 1.5)
    velocity: Vec3 = (-4.0, 0.3, 1.5)
    rgb: RGB = (0.8, 0.35, 0.05)


class BarrierConfig(FrozenModel):
    kind: Literal["barrier"] = "barrier"
    name: Name = "barrier"
    size_m: tuple[Length, Length, Length] = Field((0.05, 1.0, 1.2), description="thickness (x), width (y), height (z)")
    position: Vec3 = (1.2, 0.0, 0.6)
    yaw_deg: Real = Field(0.0, ge=-360.0, le=360.0)
    rgb: RGB = (0.25, 0.3, 0.5)


class MovingConfig(FrozenModel):
    kind: Literal["moving"] = "moving"
    name: Name = "mover"
    size_m: tuple[Length, Length, Length] = (0.3, 0.3, 0.3)
    start: Vec3 = (1.0, -2.0, 1.0)
    velocity: Vec3 = (0.0, 1.5, 0.0)
    rgb: RGB = (0.2, 0.6, 0.2)


PropConfig = Annotated[Union[BallConfig, BarrierConfig, MovingConfig], Field(discriminator="kind")]


class MarkerPipelineConfig(FrozenModel):
    labelling: Literal["model", "tracker"] = Field(
        "model", description="'model': unlabelled 3D points labelled by the subject model from any frame, through gaps; "
        "'tracker': seed 000's T-pose first frame kept by the 2D `tracker` in each camera")
    tracker: str = Field("kalman", description="a registered 2D tracker (`simbench list`) or 'package.module:Class'")
    calibration: Literal["ground_truth", "estimated"] = "ground_truth"
    smoothing: Literal["none", "butterworth", "rts"] = "none"
    max_gap_frames: Int = Field(10, ge=0, le=100_000)
    solve_skeleton: StrictBool = True
    rolling_shutter_correction: StrictBool = Field(
        True, description="with a rolling shutter (sensor.readout_ms > 0): each detection's time is its frame's "
        "timestamp + row / height * readout, and the blobs are interpolated to the frame timestamps before triangulation")

    @model_serializer(mode="wrap")
    def _omit_default_correction(self, handler):
        # Serialised (and hashed) as before the field while it is at its default.
        return omit_defaults(handler(self), {"rolling_shutter_correction": True})

    @field_validator("tracker")
    @classmethod
    def _registered_tracker(cls, v: str) -> str:
        try:
            get_tracker(v)
        except MocapInputError as exc:  # names the known trackers
            raise ValueError(str(exc)) from None
        return v


class ShirtPipelineConfig(FrozenModel):
    database: FilePath | None = Field(None, description="pose database file (built by `simbench shirt build-db`)")
    database_size: Int = Field(4000, ge=100, le=1_000_000)
    baseline: StrictBool = True
    training_frames: Int = Field(60, ge=2, le=100_000, description="frames of other takes the colour model and IK covariances are trained on")
    hands: StrictBool = Field(True, description="the bare hands as two more targets of step 4, both methods (mocap/shirt/hands.py)")
    settings: dict[str, Union[StrictBool, StrictInt, StrictFloat]] = Field(
        default_factory=dict, description="the shirt tracker's settings for both methods, fields of "
        "mocap.shirt.settings.ShirtPipelineParams (an ablation: `--set shirt_pipeline.settings.pose_prior=false`)")

    # before the value types: a string (`--set ...prior_c=abc`, or `=False`, which is not TOML) failed the
    # union of bool, int and float first, in a message naming a member ("settings.prior_c.bool") and not the type
    @field_validator("settings", mode="before")
    @classmethod
    def _settings_are_tracker_settings(cls, settings: object) -> object:
        if not isinstance(settings, dict):
            return settings  # the type check names it
        owned = {"keep_classification": "simbench keeps the classification of its runs",
                 "hand_constraints": "use shirt_pipeline.hands"}
        for name, why in owned.items():
            if name in settings:
                raise ValueError(f"{name} is not set here: {why}")
        if settings:
            # (on use: the shirt package costs 0.4 s to import, and only scenarios that set these pay it)
            from mocap.shirt.settings import ShirtPipelineParams

            try:
                ShirtPipelineParams().with_settings(settings, where="shirt_pipeline.settings")
            except MocapInputError as exc:
                raise ValueError(str(exc)) from None
        return settings

    @model_serializer(mode="wrap")
    def _omit_later_defaults(self, handler):
        # scenarios written before the hands and the settings serialise (and hash) as they did
        return omit_defaults(handler(self), {"hands": True, "settings": {}})


class PipelineConfig(FrozenModel):
    """The capture system a run scores (issue 14): ``builtin`` (the project's, ``[markers_pipeline]``)
    or ``command``: a user's program run on the inputs ``simbench export-inputs`` writes (its
    ``format``), writing its 3D ``result`` into its output folder, scored like the project's.
    ``command`` is a template: ``{inputs}``, ``{output}``, ``{python}`` (this Python) and
    ``{scenario_dir}``; it runs in the scenario's folder, its output in ``command.log``."""

    kind: Literal["builtin", "command"] = "builtin"
    command: str | None = Field(None, description="e.g. '{python} ../examples/external_pipeline.py {inputs} {output}'")
    format: Literal["opencv", "anipose", "pose2sim", "easymocap"] = "opencv"
    result: str = Field("markers.trc", description="the 3D result the command writes in {output}: .c3d, .trc or .csv")
    trc_axes: Literal["opensim", "pose2sim", "world", "auto"] = Field("opensim", description="axes of a .trc result")
    timeout_s: Real = Field(600.0, gt=0.0, le=86400.0)

    @model_validator(mode="after")
    def _command_given(self):
        if self.kind == "command" and not (self.command or "").strip():
            raise ValueError("kind = 'command' needs command = '...' (e.g. '{python} my_system.py {inputs} {output}')")
        if self.kind == "builtin" and self.command is not None:
            raise ValueError("command applies to kind = 'command' only")
        if Path(self.result).suffix.lower() not in (".c3d", ".trc", ".csv") or Path(self.result).name != self.result:
            raise ValueError(f"result = {self.result!r} must be a file name ending in .c3d, .trc or .csv")
        if self.command is not None:
            try:
                self.command.format(inputs="", output="", python="", scenario_dir="")
            except (KeyError, IndexError, ValueError) as exc:
                raise ValueError(f"command template {self.command!r}: {exc!r}; use only {{inputs}} {{output}} {{python}} {{scenario_dir}}") from None
        return self


class CalibrationSceneConfig(FrozenModel):
    """Calibration pictures taken before the take (``simbench/stage/calibration_scene.py``).

    A printed board is held still in ``n_views`` poses through the volume, each facing a
    pair of cameras and tilted, plus (``floor_view``) one view of it lying on the floor
    at the world origin, its rows along world x: that view defines the calibrated world.
    Board pictures are taken in ``visible`` mode (room lights, the scenario's sensor
    otherwise). A wand of three retro-reflective markers on a thin stick, ``wand_d01_m``
    and ``wand_d12_m`` apart, is then waved through the volume for ``wand_frames`` frames
    in ``ir`` mode.
    """

    board: Literal["checkerboard", "charuco"] = "checkerboard"
    board_cols: Int = Field(9, ge=3, le=50, description="checkerboard: inner corners per row; ChArUco: squares per row")
    board_rows: Int = Field(6, ge=3, le=50, description="checkerboard: inner corners per column; ChArUco: squares per column")
    square_m: Real = Field(0.06, gt=0.0, le=0.5)
    marker_m: Real | None = Field(None, gt=0.0, le=0.5, description="ChArUco marker side (default 0.75 x square_m)")
    dictionary: str = Field("DICT_4X4_50", description="ChArUco: OpenCV predefined ArUco dictionary")
    board_thickness_m: Real = Field(0.005, gt=0.0, le=0.05,
                                     description="the floor board's printed face lies this far above the floor")
    n_views: Int = Field(40, ge=3, le=500, description="board poses in the air")
    tilt_deg: tuple[Real, Real] = Field((15.0, 45.0), description="tilt range away from facing the camera pair")
    max_view_angle_deg: Real = Field(60.0, gt=10.0, lt=85.0,
                                      description="largest angle between the board normal and a camera's line of sight")
    floor_view: StrictBool = Field(True, description="one view of the board lying on the floor at the world origin")
    board_exposure_ms: Real | None = Field(None, gt=0.0, le=200.0,
                                            description="shutter of the board pictures (default: sensor.exposure_ms)")
    wand: StrictBool = True
    wand_frames: Int = Field(120, ge=0, le=100_000)
    wand_d01_m: Real = Field(0.2, gt=0.0, le=2.0, description="wand: marker 0 to the middle marker")
    wand_d12_m: Real = Field(0.3, gt=0.0, le=2.0, description="wand: middle marker to marker 2")
    wand_marker_radius_m: Real = Field(0.0125, gt=0.001, le=0.05)
    volume_center: Vec3 = Field((0.0, 0.0, 1.0), description="centre of the volume the board and wand move through")
    volume_half_m: tuple[Length, Length, Length] = Field((0.8, 0.8, 0.6), description="half extents of that volume")

    @field_validator("dictionary")
    @classmethod
    def _aruco_dictionary(cls, v: str) -> str:
        if v not in ARUCO_DICTIONARIES:
            raise ValueError(f"not an OpenCV predefined ArUco dictionary; e.g. DICT_4X4_50, DICT_5X5_100 "
                             f"({len(ARUCO_DICTIONARIES)} names: mocap.calib.boards.ARUCO_DICTIONARIES)")
        return v

    @model_validator(mode="after")
    def _consistent(self):
        lo, hi = self.tilt_deg
        if not 0.0 <= lo <= hi <= 80.0:
            raise ValueError(f"tilt_deg must be (low, high) with 0 <= low <= high <= 80, got {self.tilt_deg}")
        if self.board == "checkerboard" and (self.board_cols + self.board_rows) % 2 == 0:
            raise ValueError(f"a {self.board_cols}x{self.board_rows}-inner-corner checkerboard looks the same turned by "
                             f"180 deg, so cameras number its corners differently; use one even and one odd count "
                             f"(e.g. 9x6) or board = 'charuco'")
        if self.board == "charuco" and self.marker_m is not None and self.marker_m >= self.square_m:
            raise ValueError(f"marker_m = {self.marker_m} must be smaller than square_m = {self.square_m}")
        ratio = self.wand_d01_m / self.wand_d12_m
        if 0.8 < ratio < 1.25:
            raise ValueError(f"wand_d01_m = {self.wand_d01_m} and wand_d12_m = {self.wand_d12_m} are too alike to tell "
                             f"the wand's ends apart; make them differ by 25 % or more (e.g. 0.2 and 0.3)")
        return self
