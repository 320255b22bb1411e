"""A scene: the humanoid (with marker sites and rendered surface), the floor and props.

:func:`build_scene` assembles everything the simulation and the renderer need into a
frozen :class:`Scene`.  Its MJCF holds physics only (no lights, no cameras: rendering
happens elsewhere); the humanoid is the first body, so its 40 qpos come first.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Sequence

import mujoco

from simbench.scenes.anthropometry import BodyParams
from simbench.scenes.humanoid import BODY_NAMES, NQ, humanoid_body_xml, humanoid_only_mjcf
from simbench.scenes.markers import MarkerSpec, marker_set as _marker_set
from simbench.scenes.props import FLOOR_CONAFFINITY, FLOOR_CONTYPE, BallProp, BarrierProp, MovingProp, Prop
from simbench.scenes.surface import DEFAULT_CLOTHES_RGB, DEFAULT_SKIN_RGB, BodyPart, body_surface

__all__ = ["Scene", "build_scene", "humanoid_only_mjcf", "PHYSICS_TIMESTEP_S"]

PHYSICS_TIMESTEP_S = 0.001  # props integrate at 1 ms


@dataclass(frozen=True, eq=False)
class Scene:
    """Everything that is simulated and rendered, except cameras and lights.

    Attributes
    ----------
    mjcf_xml : str
        MuJoCo model: floor plane at z = 0, the humanoid (first body; qpos[:40]) with
        its marker sites, the props (after it, in ``props`` order).
    body_params : BodyParams
    marker_specs : tuple[MarkerSpec, ...]
        The markers (empty without a marker set), in the set's order.
    surface_parts : tuple[BodyPart, ...]
        The humanoid's rendered surface, in ``BODY_NAMES`` order.
    props : tuple[Prop, ...]
    marker_set : str | None
    shirt : bool
    """

    mjcf_xml: str
    body_params: BodyParams
    marker_specs: tuple[MarkerSpec, ...]
    surface_parts: tuple[BodyPart, ...]
    props: tuple = ()
    marker_set: str | None = None
    shirt: bool = False

    @cached_property
    def model(self) -> mujoco.MjModel:
        """The compiled model (compiled once per Scene; do not modify it)."""
        return mujoco.MjModel.from_xml_string(self.mjcf_xml)

    def body_id(self, name: str) -> int:
        """MuJoCo body id (index into ``SceneStates.body_xpos``) of a humanoid body or prop."""
        bid = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_BODY, name)
        if bid < 0:
            raise KeyError(f"scene has no body {name!r}; humanoid bodies are {list(BODY_NAMES)}, props {self.prop_names}")
        return int(bid)

    @property
    def marker_names(self) -> list[str]:
        return [m.name for m in self.marker_specs]

    @property
    def prop_names(self) -> list[str]:
        return [p.name for p in self.props]

    def humanoid_mjcf(self) -> str:
        """The humanoid alone (same body, markers as sites), e.g. for Pinocchio."""
        return humanoid_only_mjcf(self.body_params, self.marker_set)


def _floor_xml() -> str:
    return (
        f'<geom name="floor" type="plane" size="0 0 1" pos="0 0 0" contype="{FLOOR_CONTYPE}" '
        f'conaffinity="{FLOOR_CONAFFINITY}" friction="0.8 0.005 0.0001" rgba="0.5 0.5 0.5 1"/>'
    )


def build_scene(
    params: BodyParams = BodyParams(),
    marker_set: str | None = None,
    shirt: bool = False,
    props: Sequence[Prop] = (),
    skin_rgb: tuple[float, float, float] = DEFAULT_SKIN_RGB,
    clothes_rgb: tuple[float, float, float] = DEFAULT_CLOTHES_RGB,
) -> Scene:
    """Assemble a scene.

    Parameters
    ----------
    params : BodyParams
        The subject.
    marker_set : str, optional
        ``"plugin_gait_full"``, ``"sparse_joints"``, ``"upper_body"`` or None.
    shirt : bool
        Dress the subject in the 20-patch colour shirt.
    props : sequence of BallProp, BarrierProp, MovingProp
        Names must be unique and differ from the humanoid's bodies.
    skin_rgb, clothes_rgb : (3,) float
        Linear-RGB albedo of skin and clothes.

    Returns
    -------
    Scene
    """
    props = tuple(props)
    names = [p.name for p in props]
    for p in props:
        if not isinstance(p, (BallProp, BarrierProp, MovingProp)):
            raise TypeError(f"build_scene: props must be BallProp, BarrierProp or MovingProp, got {type(p).__name__}")
    clash = sorted({n for n in names if names.count(n) > 1} | (set(names) & set(BODY_NAMES)) | ({"floor", "world"} & set(names)))
    if clash:
        raise ValueError(f"build_scene: prop names must be unique and not a humanoid body, 'floor' or 'world': {clash}")
    markers = tuple(_marker_set(marker_set, params)) if marker_set is not None else ()
    if markers and set(names) & {m.name for m in markers}:
        raise ValueError(f"build_scene: prop names clash with marker names: {sorted(set(names) & {m.name for m in markers})}")
    surface = tuple(body_surface(params, shirt=shirt, skin_rgb=skin_rgb, clothes_rgb=clothes_rgb))
    body = humanoid_body_xml(params, marker_set, indent="    ")
    prop_xml = "\n".join("    " + line for p in props for line in p.mjcf().splitlines())
    xml = (
        '<mujoco model="simbench_scene">\n'
        '  <compiler angle="radian" autolimits="true"/>\n'
        f'  <option timestep="{PHYSICS_TIMESTEP_S}" gravity="0 0 -9.81"/>\n'
        "  <worldbody>\n"
        f"    {_floor_xml()}\n"
        f"{body}\n"
        f"{prop_xml}\n"
        "  </worldbody>\n"
        "</mujoco>\n"
    )
    scene = Scene(
        mjcf_xml=xml,
        body_params=params,
        marker_specs=markers,
        surface_parts=surface,
        props=props,
        marker_set=marker_set,
        shirt=shirt,
    )
    # the humanoid must own qpos[:40] (the contract of humanoid_qpos_fn)
    if scene.model.jnt_qposadr[scene.model.joint("root").id] != 0 or scene.model.body("pelvis").id != 1 or scene.model.nq < NQ:
        raise RuntimeError("build_scene: the humanoid is not the first body of the scene")
    return scene
