"""Scenario files: TOML validated with pydantic.

A scenario says everything a run needs: the body, what it wears (markers or the
colour shirt), the motion, cameras and their sensor, lighting, props, duration,
seed, and how the capture pipeline is configured. ``load_scenario`` turns any
validation problem into one :class:`~simbench.errors.ScenarioError` naming the file,
the field, the value and what is allowed.

Names are checked against their registries when the scenario loads, before anything
renders: the motion clip (:data:`simbench.scenes.motions.MOTIONS`), the marker set
(:data:`simbench.scenes.markers.MARKER_SETS`), the body proportions
(:class:`simbench.scenes.anthropometry.BodyParams`), the lighting preset and the lights
its events switch (:data:`LIGHTING_PRESETS`), the tracker (:mod:`mocap.trackers`) and the
ChArUco dictionary (:data:`mocap.calib.boards.ARUCO_DICTIONARIES`).

The schema's shared types are in :mod:`simbench.scenario.fields`, its sections in
:mod:`simbench.scenario.sections`, the :class:`Scenario` in :mod:`simbench.scenario.model` and
the loading in :mod:`simbench.scenario.loading`; every name is importable from here.
"""

from __future__ import annotations

from simbench.scenario.fields import (  # noqa: F401
    _a_number,
    _NAME,
    _plain_name,
    Coef,
    Coord,
    Distortion,
    field_error,
    FilePath,
    FrozenModel,
    Int,
    Length,
    Name,
    Real,
    RGB,
    Unit,
    Vec3,
)
from simbench.scenario.sections import (  # noqa: F401
    _BVH_FIELDS,
    _CAPTURE_FIELDS,
    _CEILING,
    _LATER_SENSOR_FIELDS,
    _TUNGSTEN,
    BallConfig,
    BarrierConfig,
    BodyConfig,
    CalibrationSceneConfig,
    CameraConfig,
    CaptureGapsConfig,
    ClockConfig,
    LightConfig,
    LightEventConfig,
    LIGHTING_PRESETS,
    LightingConfig,
    MarkerPipelineConfig,
    MarkerSetName,
    MotionConfig,
    MovingConfig,
    PipelineConfig,
    PropConfig,
    RigConfig,
    SensorConfig,
    SetConfig,
    ShirtPipelineConfig,
    SubjectConfig,
)
from simbench.scenario.model import (  # noqa: F401
    _set_dotted,
    Scenario,
)
from simbench.scenario.loading import (  # noqa: F401
    _check_rig_calibration,
    _format_loc,
    load_scenario,
    parse_overrides,
    read_toml_file,
    validation_error_to_scenario_error,
)

__all__ = ["Real", "Int", "Coord", "Vec3", "Unit", "RGB", "Length", "Coef", "Distortion", "Name", "FilePath", "field_error", "FrozenModel", "BodyConfig", "MarkerSetName", "SubjectConfig", "CaptureGapsConfig", "MotionConfig", "ClockConfig", "SensorConfig", "CameraConfig", "RigConfig", "LightConfig", "LightEventConfig", "LIGHTING_PRESETS", "LightingConfig", "SetConfig", "BallConfig", "BarrierConfig", "MovingConfig", "PropConfig", "MarkerPipelineConfig", "ShirtPipelineConfig", "PipelineConfig", "CalibrationSceneConfig", "Scenario", "validation_error_to_scenario_error", "read_toml_file", "parse_overrides", "load_scenario"]
