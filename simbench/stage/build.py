"""The stage of any scenario: the humanoid's, or a real capture's markers."""

from __future__ import annotations

from simbench.scenario import Scenario
from simbench.stage.capture import CaptureStage
from simbench.stage.stage import Stage


def build_stage(scenario: Scenario) -> Stage:
    """:class:`CaptureStage` for a scenario whose motion is a C3D/TRC capture, else :class:`Stage`."""
    if scenario.motion.c3d or scenario.motion.trc:  # a real capture's markers, no humanoid
        return CaptureStage.from_capture_scenario(scenario)
    return Stage.from_scenario(scenario)
