"""Lights of the set: presets, colour temperature, intensity, and timed events.

Units: a light's ``intensity`` is its irradiance (arbitrary radiometric units) at
normal incidence for directional lights, or at 1 m for point lights; with the
default sensor, irradiance 3 on a white surface at 8 ms exposure is about 40 % of
full scale. Light colours are linear sRGB of the light's correlated colour
temperature (:func:`simbench.render.color.cct_to_rgb`), luminance-normalised.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from simbench.errors import ScenarioError
from simbench.render.color import cct_to_rgb
from simbench.render.rasterizer import Light
from simbench.scenario import LightConfig, LightingConfig


@dataclass(frozen=True)
class LightState:
    """Every light of the set at one instant (what the ground truth records)."""

    names: tuple[str, ...]
    intensities: np.ndarray      # (L,)
    rgb: np.ndarray              # (L, 3) colour * intensity
    ambient_rgb: np.ndarray      # (3,)


def _preset(name: str) -> tuple[list[LightConfig], np.ndarray]:
    """Lights and ambient irradiance (linear RGB) of a named preset."""
    ceiling = [
        LightConfig(name=f"ceiling_{i}", kind="point", position=(x, y, 2.9), cct_k=4100.0, tint=1.5, intensity=5.0)
        for i, (x, y) in enumerate(((1.5, 1.5), (1.5, -1.5), (-1.5, 1.5), (-1.5, -1.5)))
    ]
    tungsten = LightConfig(name="tungsten", kind="point", position=(1.4, 1.3, 1.7), cct_k=2800.0, intensity=7.0)
    if name == "office_fluorescent":
        return ceiling, 0.35 * cct_to_rgb(4100.0, 1.5)
    if name == "tungsten_lamp":
        return [tungsten], 0.12 * cct_to_rgb(2800.0)
    if name == "daylight_outdoor":
        sun = LightConfig(name="sun", kind="directional", direction=(-0.4, 0.3, -0.85), cct_k=5600.0, intensity=7.0)
        return [sun], 1.6 * cct_to_rgb(9000.0)
    if name == "dim_gym":
        gym = [
            LightConfig(name=f"gym_{i}", kind="point", position=(x, 0.0, 6.0), cct_k=4300.0, intensity=12.0)
            for i, x in enumerate((-2.0, 2.0))
        ]
        return gym, 0.08 * cct_to_rgb(4300.0)
    if name == "mixed":
        return ceiling + [tungsten], 0.3 * cct_to_rgb(4100.0, 1.5)
    if name == "custom":
        return [], np.zeros(3)
    raise ValueError(f"unknown lighting preset {name!r}")


class Lighting:
    """The set's lights over time, built from a :class:`LightingConfig`."""

    def __init__(self, config: LightingConfig, scenario_path: str = "<scenario>") -> None:
        lights, ambient = _preset(config.preset)
        by_name = {light.name: light for light in lights}
        for light in config.lights:  # user lights add to / replace preset lights
            by_name[light.name] = light
        self.configs = list(by_name.values())
        self.names = tuple(by_name)
        self.ambient_rgb = np.asarray(ambient, float) * config.scale
        self._colour = np.array([cct_to_rgb(c.cct_k, c.tint) for c in self.configs]).reshape(-1, 3)
        self._base = np.array([c.intensity for c in self.configs], float) * config.scale
        self._events = sorted(config.events, key=lambda e: e.t_s)
        for i, ev in enumerate(self._events):
            if ev.light not in by_name:
                raise ScenarioError(scenario_path, f"lighting.events.{i}.light", ev.light,
                                    f"no such light; lights are {sorted(by_name)}")
        self._scale = config.scale

    def intensities_at(self, t: float) -> np.ndarray:
        """Intensity of every light ``(L,)`` at time ``t`` (events are step changes)."""
        out = self._base.copy()
        for ev in self._events:
            if t >= ev.t_s:
                out[self.names.index(ev.light)] = ev.intensity * self._scale
        return out

    def state_at(self, t: float) -> LightState:
        inten = self.intensities_at(t)
        return LightState(self.names, inten, self._colour * inten[:, None], self.ambient_rgb.copy())

    def lights_at(self, t: float) -> list[Light]:
        """Rasteriser lights at time ``t`` (switched-off lights omitted)."""
        inten = self.intensities_at(t)
        out = []
        for cfg, colour, i in zip(self.configs, self._colour, inten):
            if i <= 0:
                continue
            if cfg.kind == "point":
                out.append(Light("point", np.asarray(cfg.position, float), colour * i))
            else:
                d = np.asarray(cfg.direction, float)
                out.append(Light("directional", d / np.linalg.norm(d), colour * i))
        return out
