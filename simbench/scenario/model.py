"""The :class:`Scenario`: the sections together, the checks across them (cameras see the subject,
exposure and readout fit in a frame), its frames, content hash and dotted-path overrides."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
from pydantic import Field, model_serializer, model_validator

from simbench.errors import ScenarioError
from simbench.scenario.fields import FrozenModel, Int, Real, field_error, omit_defaults
from simbench.scenario.sections import BodyConfig, CalibrationSceneConfig, CameraConfig, LightingConfig, MarkerPipelineConfig, MotionConfig, PipelineConfig, PropConfig, RigConfig, SensorConfig, SetConfig, ShirtPipelineConfig, SubjectConfig


class Scenario(FrozenModel):
    name: str
    description: str = ""
    seed: Int = Field(0, ge=0, le=2**32 - 1)
    seeds: Int = Field(1, ge=1, le=1000, description="`simbench run` without --seeds runs this many seeds: seed, seed + 1, ... "
                       "(not part of a run's content hash: each run has one seed)")
    duration_s: Real = Field(2.0, gt=0.0, le=120.0)
    fps: Real = Field(30.0, gt=0.0, le=1000.0)
    body: BodyConfig = BodyConfig()
    subject: SubjectConfig = SubjectConfig()
    motion: MotionConfig = MotionConfig()
    sensor: SensorConfig = SensorConfig()
    rig: RigConfig | None = None
    cameras: tuple[CameraConfig, ...] = ()
    lighting: LightingConfig = LightingConfig()
    set: SetConfig = SetConfig()
    props: tuple[PropConfig, ...] = ()
    markers_pipeline: MarkerPipelineConfig = MarkerPipelineConfig()
    shirt_pipeline: ShirtPipelineConfig = ShirtPipelineConfig()
    calibration_scene: CalibrationSceneConfig | None = None
    pipeline: PipelineConfig | None = Field(None, description="[pipeline] kind = 'command': score a user's system instead")
    source_dir: str = Field("", exclude=True, description="directory of the scenario file (relative paths)")
    source_file: str = Field("", exclude=True, description="the scenario file (what errors found after loading name)")

    @model_validator(mode="after")
    def _checks(self):
        if not self.cameras and self.rig is None:
            object.__setattr__(self, "rig", RigConfig())
        names = [c.name for c in self.cameras]
        if len(set(names)) != len(names):
            raise ValueError(f"camera names must be unique, got {names}")
        if self.n_frames < 1:
            raise field_error("duration_s", self.duration_s, f"duration_s * fps = {self.duration_s} * {self.fps} gives "
                                                            f"no frame; a take needs 1 frame to render, 2 to run")
        self._cameras_see_the_subject()
        if self.sensor.exposure_ms > 1000.0 / self.fps + 1e-9:
            raise ValueError(f"sensor.exposure_ms = {self.sensor.exposure_ms} exceeds the frame interval 1/fps = {1000.0 / self.fps:.2f} ms")
        if self.sensor.readout_ms > 1000.0 / self.fps + 1e-9:
            raise field_error("sensor.readout_ms", self.sensor.readout_ms,
                              f"a rolling shutter's readout fits in the frame interval 1/fps = {1000.0 / self.fps:.2f} ms")
        if self.markers_pipeline.calibration == "estimated" and self.calibration_scene is None:
            raise ValueError("markers_pipeline.calibration = 'estimated' needs a [calibration_scene] section "
                             "(the board and wand pictures the calibration is estimated from)")
        return self

    @model_serializer(mode="wrap")
    def _omit_builtin_pipeline(self, handler):
        # Scenarios without a [pipeline] section serialise (and hash) as they did before it.
        return omit_defaults(handler(self), {"pipeline": None})

    @property
    def command_pipeline(self) -> "PipelineConfig | None":
        """The ``[pipeline]`` when it names a command, else None (the project's pipeline runs)."""
        return self.pipeline if self.pipeline is not None and self.pipeline.kind == "command" else None

    def _cameras_see_the_subject(self) -> None:
        """Every camera is 0.5 m or more from the subject's vertical axis (x = y = 0) and sees part
        of it, from the floor to the body's height, within the cone of its narrower field of view
        (the subject starts there; a camera inside the body or looking elsewhere sees nothing)."""
        if self.cameras:
            cams, where = self.cameras, [f"cameras.{i}" for i in range(len(self.cameras))]
        elif getattr(self.rig, "from_calibration", None) is None:  # a calibration file's rig is checked when it loads
            cams, where = self.rig.camera_configs(), ["rig"] * self.rig.count
        else:
            return
        column = np.stack([np.zeros(9), np.zeros(9), np.linspace(0.0, self.body.height_m, 9)], axis=1)  # (9, 3) m
        for cam, field in zip(cams, where):
            p = np.asarray(cam.position)
            axis = np.subtract(cam.look_at, p) / np.linalg.norm(np.subtract(cam.look_at, p))
            rays = column - p
            dist = np.linalg.norm(rays, axis=1)
            rig = {k: getattr(self.rig, k) for k in ("count", "radius_m", "height_m", "look_at")} if field == "rig" else None
            nearest = np.linalg.norm(p - [0.0, 0.0, np.clip(p[2], 0.0, self.body.height_m)])
            if nearest < 0.5:
                raise field_error(field if field == "rig" else f"{field}.position", rig or cam.position,
                                  f"camera {cam.name!r} at {tuple(round(float(v), 3) for v in p)} is {nearest:.2f} m from "
                                  f"the subject (the line x = y = 0 from the floor to {self.body.height_m} m): inside "
                                  f"the body; place cameras 0.5 m from it or more")
            angle = np.degrees(np.arccos(np.clip(rays @ axis / dist, -1.0, 1.0)))
            if angle.min() > cam.half_fov_deg():
                raise field_error(field if field == "rig" else f"{field}.look_at", rig or cam.look_at,
                                  f"camera {cam.name!r} at {tuple(round(float(v), 3) for v in p)} looking at {cam.look_at} "
                                  f"does not see the subject (the line x = y = 0 from the floor to {self.body.height_m} m "
                                  f"is {angle.min():.0f} deg off its axis, its field of view reaches "
                                  f"{cam.half_fov_deg():.0f} deg); point it at the subject")

    def check_runnable(self, source: Path | str) -> None:
        """What a run (render, pipelines, scores) needs beyond a valid scenario, which may also
        just be rendered (one camera is a valid render): a :class:`ScenarioError` naming
        ``source`` before anything renders. The marker pipeline and the calibration session
        triangulate, so they need two cameras; a take of one frame has no motion to track."""
        n = len(self.cameras) if self.cameras else None if getattr(self.rig, "from_calibration", None) else self.rig.count
        needs = ("the marker pipeline" if self.subject.markers != "none" or self.motion.c3d or self.motion.trc
                 else "the calibration session" if self.calibration_scene is not None else None)
        if n == 1 and needs:
            field = "cameras" if self.cameras else "rig.count"
            raise ScenarioError(source, field, [c.name for c in self.cameras] if self.cameras else 1,
                                f"{needs} triangulates, so it needs two cameras or more")
        if self.n_frames < 2:
            raise ScenarioError(source, "duration_s", self.duration_s, f"duration_s * fps = {self.duration_s} * {self.fps} "
                                f"gives {self.n_frames} frame; a run needs 2 frames or more")

    @property
    def n_frames(self) -> int:
        return int(round(self.duration_s * self.fps))

    @property
    def origin(self) -> str:
        """What an error found after loading names as the scenario's file: the file, else its folder, else the name."""
        return self.source_file or self.source_dir or self.name

    def resolve_path(self, p: str) -> Path:
        path = Path(p)
        return path if path.is_absolute() else Path(self.source_dir or ".") / path

    def content_hash(self) -> str:
        """Stable hash of the resolved scenario (what determines the run's numbers)."""
        data = self.model_dump(mode="json")
        data.pop("seeds", None)  # how many seeds to run is not one run's content (and hashes of older files stay)
        # fields added later, at the default that reproduces the runs made before them: left out, so that the
        # baselines' and sweep databases' hashes of the same scenarios stay (motion.subject_trial, session 28)
        if data.get("motion", {}).get("subject_trial") == "take":
            data["motion"].pop("subject_trial")
        blob = json.dumps(data, sort_keys=True).encode()
        return hashlib.sha256(blob).hexdigest()[:16]

    def with_overrides(self, overrides: dict[str, object]) -> "Scenario":
        """A copy with dotted-path fields replaced (``{"sensor.exposure_ms": 20}``), validated."""
        data = self.model_dump(mode="python")
        for dotted, value in overrides.items():
            _set_dotted(data, dotted, value)
        data["source_dir"], data["source_file"] = self.source_dir, self.source_file
        return Scenario.model_validate(data)


class OverridePathError(ValueError):
    """A dotted override path that does not lead to a field: ``field`` is the part of it that fails, ``value`` the
    value it was to set."""

    def __init__(self, field: str, reason: str, value: object = None) -> None:
        self.field, self.reason, self.value = field, reason, value
        super().__init__(f"{field}: {reason}")


def _list_index(node: list, key: str, where: str) -> int:
    """``key`` as an index of the list ``node`` named ``where``; :class:`OverridePathError` if it is none."""
    n = len(node)
    span = f"0-{n - 1}" if n else "none: the list is empty"
    if not key.isdigit():
        raise OverridePathError(f"{where}.{key}", f"{where} is a list: index it with a number (indices {span})")
    if int(key) >= n:
        raise OverridePathError(f"{where}.{key}", f"{where} has {n} entries (indices {span})")
    return int(key)


def _set_dotted(data: dict, dotted: str, value: object) -> None:
    """Set ``data``'s field at ``dotted`` (``"sensor.exposure_ms"``, ``"cameras.0.hfov_deg"``) to ``value``, making
    the tables on the way; :class:`OverridePathError` where the path indexes a list wrongly, goes on through a value,
    or indexes a list the scenario does not have (a table is made only for a name)."""
    try:
        _walk_and_set(data, dotted.split("."), value)
    except OverridePathError as exc:
        exc.value = value
        raise


def _walk_and_set(data: dict, keys: list[str], value: object) -> None:
    node, parent, where = data, None, ""
    for depth, k in enumerate(keys):
        last = depth == len(keys) - 1
        here = f"{where}.{k}" if where else k
        if isinstance(node, tuple):  # a model's dump (Scenario.with_overrides): lists as tuples
            node = list(node)
            parent[keys[depth - 1] if isinstance(parent, dict) else int(keys[depth - 1])] = node
        if isinstance(node, list):
            k = _list_index(node, k, where)
        elif not isinstance(node, dict):
            raise OverridePathError(here, f"{where} is a value ({node!r}), not a table: set {where} itself")
        if last:
            node[k] = value
            return
        if isinstance(node, dict) and (k not in node or node[k] is None):
            if keys[depth + 1].isdigit():
                raise OverridePathError(f"{here}.{keys[depth + 1]}", f"this scenario has no {here} list to index; "
                                        f"write [[{here}]] tables in the scenario file")
            node[k] = {}
        parent, node, where = node, node[k], here
