"""Props that occlude the subject: a thrown ball, a static barrier and a moving box.

Each prop is a small frozen dataclass that writes its own MJCF ``<body>`` (world
frame, metres, SI units) and gives its render mesh in that body's frame, so that
``world = pose @ mesh`` with the ``(4, 4)`` pose the simulation reports for it.

Contact groups (``contype`` / ``conaffinity`` bits; MuJoCo collides two geoms when
``(a.contype & b.conaffinity) or (b.contype & a.conaffinity)``):

======================  =======  ===========  ===========================================
geom                    contype  conaffinity  collides with
======================  =======  ===========  ===========================================
floor                   1        1            ball
humanoid                2        0            ball (never itself, never the floor)
ball                    7        7            everything
barrier                 1        1            ball
moving box              4        4            ball
======================  =======  ===========  ===========================================
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Union

import numpy as np
import trimesh

__all__ = ["BallProp", "BarrierProp", "MovingProp", "Prop", "FLOOR_CONTYPE", "FLOOR_CONAFFINITY"]

FLOOR_CONTYPE = 1
FLOOR_CONAFFINITY = 1
_BALL_BITS = 7
_BARRIER_BITS = 1
_MOVER_BITS = 4
_CONTACT_OMEGA = 400.0  # rad/s, natural frequency of the ball's contact spring


def _vec3(value, what: str) -> tuple[float, float, float]:
    arr = np.asarray(value, dtype=np.float64).ravel()
    if arr.shape != (3,) or not np.isfinite(arr).all():
        raise ValueError(f"{what} must be 3 finite numbers, got {value!r}")
    return tuple(float(v) for v in arr)


def _rgb(value, what: str) -> tuple[float, float, float]:
    rgb = _vec3(value, what)
    if not all(0.0 <= v <= 1.0 for v in rgb):
        raise ValueError(f"{what} must be linear RGB in 0..1, got {value!r}")
    return rgb


def _fmt(values) -> str:
    return " ".join(f"{float(v):.9g}" for v in values)


def _check_name(name: str, kind: str) -> None:
    if not name or not name.replace("_", "").replace("-", "").isalnum():
        raise ValueError(f"{kind} name {name!r}: use letters, digits, '_' or '-'")


def _check_prop(prop, kind: str, vectors: tuple[str, ...], box: str | None = None) -> None:
    """The checks every prop shares, in this order: its name; for a box (``box``: what the
    message adds about the axes) a positive ``size_m``; its 3-vector fields ``vectors`` and
    ``rgb``, stored as tuples of floats."""
    _check_name(prop.name, kind)
    what = f"{kind} {prop.name!r}"
    if box is not None:
        size = _vec3(prop.size_m, f"{what} size_m")
        if min(size) <= 0:
            raise ValueError(f"{what}: size_m must be positive{box}, got {size}")
        object.__setattr__(prop, "size_m", size)
    for name in vectors:
        object.__setattr__(prop, name, _vec3(getattr(prop, name), f"{what} {name}"))
    object.__setattr__(prop, "rgb", _rgb(prop.rgb, f"{what} rgb"))


@dataclass(frozen=True)
class BallProp:
    """A ball thrown by physics: free body, bounces off the floor, the body and props.

    Attributes
    ----------
    name : str
    radius_m : float
    position : (3,) float
        Centre at t = 0, world metres.
    velocity : (3,) float
        Linear velocity at t = 0, m/s.
    rgb : (3,) float
        Linear-RGB albedo.
    mass_kg : float
        Default 0.43 kg (a football).
    restitution : float
        Coefficient of restitution of its contacts (0 = dead, 1 = perfectly elastic).
    """

    name: str = "ball"
    radius_m: float = 0.11
    position: tuple[float, float, float] = (2.0, -0.3, 1.5)
    velocity: tuple[float, float, float] = (-4.0, 0.3, 1.5)
    rgb: tuple[float, float, float] = (0.8, 0.35, 0.05)
    mass_kg: float = 0.43
    restitution: float = 0.7

    def __post_init__(self) -> None:
        _check_prop(self, "BallProp", ("position", "velocity"))
        if not 0.005 <= self.radius_m <= 2.0:
            raise ValueError(f"BallProp {self.name!r}: radius_m = {self.radius_m} is out of range (0.005 .. 2 m)")
        if not self.mass_kg > 0:
            raise ValueError(f"BallProp {self.name!r}: mass_kg must be positive, got {self.mass_kg}")
        if not 0.0 <= self.restitution < 1.0:
            raise ValueError(f"BallProp {self.name!r}: restitution must be in [0, 1), got {self.restitution}")

    def contact_solref(self) -> tuple[float, float]:
        """MuJoCo ``solref`` in its direct form ``(-stiffness, -damping)``.

        The contact is a damped spring of natural frequency ``_CONTACT_OMEGA`` (contact
        lasts about pi / omega = 8 ms, several 1 ms physics steps, so it stays stable)
        whose damping ratio gives the requested restitution:
        ``e = exp(-zeta pi / sqrt(1 - zeta^2))``.  (MuJoCo's default ``timeconst,
        dampratio`` form makes an under-damped contact far too stiff for 1 ms steps.)
        """
        e = max(self.restitution, 1e-6)
        zeta = -np.log(e) / np.sqrt(np.pi**2 + np.log(e) ** 2)
        return (-(_CONTACT_OMEGA**2), -2.0 * zeta * _CONTACT_OMEGA)

    def mjcf(self) -> str:
        """The ball's ``<body>`` element (free joint named ``<name>_free``)."""
        return (
            f'<body name="{self.name}" pos="{_fmt(self.position)}">\n'
            f'  <freejoint name="{self.name}_free"/>\n'
            f'  <geom name="{self.name}_geom" type="sphere" size="{self.radius_m:.9g}" mass="{self.mass_kg:.9g}" '
            f'contype="{_BALL_BITS}" conaffinity="{_BALL_BITS}" priority="1" condim="3" friction="0.6 0.005 0.0001" '
            f'solref="{_fmt(self.contact_solref())}" solimp="0.99 0.99 0.001 0.5 2" rgba="{_fmt(self.rgb)} 1"/>\n'
            f"</body>"
        )

    def initial_qvel(self) -> np.ndarray:
        """``(6,)`` free-joint velocity at t = 0: linear (world) then angular (zero)."""
        return np.array([*self.velocity, 0.0, 0.0, 0.0])

    def mesh(self) -> trimesh.Trimesh:
        """Render mesh in the ball's frame (centred), metres."""
        return trimesh.creation.icosphere(subdivisions=3, radius=self.radius_m)


@dataclass(frozen=True)
class BarrierProp:
    """A static box standing in the scene (a screen, a table top, a wall piece).

    Attributes
    ----------
    name : str
    size_m : (3,) float
        Full size: thickness (x), width (y), height (z) in its own frame, metres.
    position : (3,) float
        Centre, world metres.
    yaw_deg : float
        Rotation about the world Z axis, degrees.
    rgb : (3,) float
        Linear-RGB albedo.
    """

    name: str = "barrier"
    size_m: tuple[float, float, float] = (0.05, 1.0, 1.2)
    position: tuple[float, float, float] = (1.2, 0.0, 0.6)
    yaw_deg: float = 0.0
    rgb: tuple[float, float, float] = (0.25, 0.3, 0.5)

    def __post_init__(self) -> None:
        _check_prop(self, "BarrierProp", ("position",), box=" (thickness, width, height)")
        object.__setattr__(self, "yaw_deg", float(self.yaw_deg))

    def pose(self) -> np.ndarray:
        """``(4, 4)`` world pose of the barrier's frame (constant)."""
        T = np.eye(4)
        a = np.deg2rad(self.yaw_deg)
        T[:2, :2] = [[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]
        T[:3, 3] = self.position
        return T

    def mjcf(self) -> str:
        """The barrier's ``<body>`` element (no joint: welded to the world)."""
        half = np.asarray(self.size_m) / 2
        a = np.deg2rad(self.yaw_deg)
        quat = (np.cos(a / 2), 0.0, 0.0, np.sin(a / 2))
        return (
            f'<body name="{self.name}" pos="{_fmt(self.position)}" quat="{_fmt(quat)}">\n'
            f'  <geom name="{self.name}_geom" type="box" size="{_fmt(half)}" '
            f'contype="{_BARRIER_BITS}" conaffinity="{_BARRIER_BITS}" rgba="{_fmt(self.rgb)} 1"/>\n'
            f"</body>"
        )

    def mesh(self) -> trimesh.Trimesh:
        """Render mesh in the barrier's frame (centred box), metres."""
        return trimesh.creation.box(extents=self.size_m)


@dataclass(frozen=True)
class MovingProp:
    """A box sliding at constant velocity along a straight path (prismatic joint).

    The slide joint is frictionless and the body's weight is compensated, so the box
    keeps its velocity unless the ball hits it.  It passes through the subject and the
    floor (it only collides with balls): use it as a moving occluder.

    Attributes
    ----------
    name : str
    size_m : (3,) float
        Full size of the box (x, y, z), metres.
    start : (3,) float
        Centre at t = 0, world metres.
    velocity : (3,) float
        m/s; the joint axis is its direction (a zero velocity gives a still box).
    rgb : (3,) float
        Linear-RGB albedo.
    mass_kg : float
    """

    name: str = "mover"
    size_m: tuple[float, float, float] = (0.3, 0.3, 0.3)
    start: tuple[float, float, float] = (1.0, -2.0, 1.0)
    velocity: tuple[float, float, float] = (0.0, 1.5, 0.0)
    rgb: tuple[float, float, float] = (0.2, 0.6, 0.2)
    mass_kg: float = 5.0

    def __post_init__(self) -> None:
        _check_prop(self, "MovingProp", ("start", "velocity"), box="")
        if not self.mass_kg > 0:
            raise ValueError(f"MovingProp {self.name!r}: mass_kg must be positive, got {self.mass_kg}")

    @property
    def speed(self) -> float:
        return float(np.linalg.norm(self.velocity))

    @property
    def axis(self) -> np.ndarray:
        """Unit direction of travel (X if the box stands still)."""
        s = self.speed
        return np.asarray(self.velocity) / s if s > 0 else np.array([1.0, 0.0, 0.0])

    def mjcf(self) -> str:
        """The box's ``<body>`` element (slide joint named ``<name>_slide``)."""
        half = np.asarray(self.size_m) / 2
        return (
            f'<body name="{self.name}" pos="{_fmt(self.start)}" gravcomp="1">\n'
            f'  <joint name="{self.name}_slide" type="slide" pos="0 0 0" axis="{_fmt(self.axis)}" '
            f'limited="false" damping="0" frictionloss="0" armature="0"/>\n'
            f'  <geom name="{self.name}_geom" type="box" size="{_fmt(half)}" mass="{self.mass_kg:.9g}" '
            f'contype="{_MOVER_BITS}" conaffinity="{_MOVER_BITS}" rgba="{_fmt(self.rgb)} 1"/>\n'
            f"</body>"
        )

    def initial_qvel(self) -> np.ndarray:
        """``(1,)`` slide-joint velocity at t = 0, m/s."""
        return np.array([self.speed])

    def mesh(self) -> trimesh.Trimesh:
        """Render mesh in the box's frame (centred), metres."""
        return trimesh.creation.box(extents=self.size_m)


Prop = Union[BallProp, BarrierProp, MovingProp]
