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

from simbench.render.color import cct_to_rgb
from simbench.render.rasterizer import Light
from simbench.scenario import LIGHTING_PRESETS, LightConfig, LightingConfig


@dataclass(frozen=True)
class LightState:
    """Every light of the set at one instant (what the ground truth records)."""

    names: tuple[str, ...]
    intensities: np.ndarray      # (L,)
    rgb: np.ndarray              # (L, 3) colour * intensity
    ambient_rgb: np.ndarray      # (3,)


#: Ambient irradiance of each lighting preset: (scale, colour temperature K, tint) of
#: ``scale * cct_to_rgb(cct, tint)``; the presets' lights are :data:`simbench.scenario.LIGHTING_PRESETS`.
_AMBIENT: dict[str, tuple[float, float, float]] = {
    "office_fluorescent": (0.35, 4100.0, 1.5),
    "tungsten_lamp": (0.12, 2800.0, 0.0),
    "daylight_outdoor": (1.6, 9000.0, 0.0),
    "dim_gym": (0.08, 4300.0, 0.0),
    "mixed": (0.3, 4100.0, 1.5),
    "custom": (0.0, 6500.0, 0.0),
}


def _preset(name: str) -> tuple[list[LightConfig], np.ndarray]:
    """Lights and ambient irradiance (linear RGB) of a named preset."""
    scale, cct, tint = _AMBIENT[name]
    ambient = scale * cct_to_rgb(cct, tint) if scale > 0 else np.zeros(3)
    return list(LIGHTING_PRESETS[name]), ambient


class Lighting:
    """The set's lights over time, built from a :class:`LightingConfig`."""

    def __init__(self, config: LightingConfig) -> None:
        """``config`` is validated: its events switch lights of its preset or its own lights."""
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
