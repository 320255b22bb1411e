"""Tracker registry: names to :class:`~mocap.trackers.base.Tracker2D` classes.

A tracker becomes available everywhere a tracker name is accepted (``simbench run``
scenarios, ``mocap markers``, ``simbench study trackers``, ``simbench bench trackers``)
once it is registered:

* decorate the class with :func:`register_tracker` in any module that gets imported;
* or name it by entry point, ``"package.module:ClassName"``, wherever a tracker name
  is accepted (the module is imported on first use);
* or declare it in an installed package's metadata under the entry-point group
  ``mocap.trackers`` (``[project.entry-points."mocap.trackers"] mine = "pkg.mod:Mine"``).

The registry is the one piece of module-level state of the trackers: a name table
filled by ``register_tracker`` at import time, read through the read-only
:data:`TRACKERS` view.
"""

from __future__ import annotations

import importlib
import inspect
from importlib.metadata import entry_points
from types import MappingProxyType
from typing import Any, Callable, Mapping

import numpy as np

from mocap.errors import MocapInputError
from mocap.trackers.base import Tracker2D

ENTRY_POINT_GROUP = "mocap.trackers"

_REGISTRY: dict[str, type] = {}
#: Read-only view ``name -> Tracker2D subclass`` of the registered trackers.
TRACKERS: Mapping[str, type] = MappingProxyType(_REGISTRY)


class TrackerNotFoundError(MocapInputError):
    """A tracker name (scenario field, CLI option) that names no tracker."""


def register_tracker(name: str | None = None, *, replace: bool = False) -> Callable[[type], type]:
    """Class decorator adding a tracker to :data:`TRACKERS`.

    Parameters
    ----------
    name : str, optional
        Registry name; defaults to the class's ``name`` attribute, else its lower-case
        class name.
    replace : bool, default False
        Allow replacing a different class already registered under ``name``.

    Examples
    --------
    >>> @register_tracker("my_kalman")            # doctest: +SKIP
    ... class MyKalman(Tracker2D): ...
    """
    def decorate(cls: type) -> type:
        if not (isinstance(cls, type) and issubclass(cls, Tracker2D)):
            raise TypeError(f"register_tracker: {cls!r} is not a subclass of mocap.trackers.Tracker2D")
        key = name or cls.__dict__.get("name") or cls.__name__.lower()
        old = _REGISTRY.get(key)
        if old is not None and old is not cls and not replace and _qualname(old) != _qualname(cls):
            raise ValueError(f"tracker name {key!r} is already used by {_qualname(old)}; pick another name or pass replace=True")
        cls.name = key
        _REGISTRY[key] = cls
        return cls

    return decorate


def unregister_tracker(name: str) -> None:
    """Remove a tracker from :data:`TRACKERS` (e.g. a test's or a plugin's own)."""
    if name not in _REGISTRY:
        raise TrackerNotFoundError(f"unknown tracker {name!r}; registered: {', '.join(sorted(_REGISTRY))}")
    del _REGISTRY[name]


def _qualname(cls: type) -> str:
    return f"{cls.__module__}:{cls.__qualname__}"


#: Modules whose trackers register themselves when imported (the built-in trackers).
BUILTIN_MODULES = ("mocap.trackers.openmocap", "mocap.trackers.alpha_beta", "mocap.trackers.kalman",
                   "mocap.trackers.condensation", "mocap.trackers.imm")


def _load_builtins() -> None:
    """Import the built-in trackers' modules (their decorators fill the registry), by name as a
    plugin's: they import this module, so importing them here at the top would be a cycle."""
    for module in BUILTIN_MODULES:
        importlib.import_module(module)


def _from_entry_point(spec: str) -> type:
    module_name, _, attr = spec.partition(":")
    if not module_name or not attr:
        raise TrackerNotFoundError(f"tracker {spec!r}: an entry point must read 'package.module:ClassName'")
    try:
        obj: Any = importlib.import_module(module_name)
    except ImportError as exc:
        raise TrackerNotFoundError(f"tracker {spec!r}: cannot import module {module_name!r} ({exc}); check the module path and that it is installed") from exc
    for part in attr.split("."):
        if not hasattr(obj, part):
            raise TrackerNotFoundError(f"tracker {spec!r}: module {module_name!r} has no attribute {attr!r}; check the class name")
        obj = getattr(obj, part)
    if not (isinstance(obj, type) and issubclass(obj, Tracker2D)):
        raise TrackerNotFoundError(f"tracker {spec!r}: {attr} is not a subclass of mocap.trackers.Tracker2D")
    return obj


def _installed_entry_points() -> dict[str, str]:
    return {ep.name: ep.value for ep in entry_points(group=ENTRY_POINT_GROUP)}


def available_trackers() -> list[str]:
    """Names of all registered trackers (built-in, decorated, installed entry points)."""
    _load_builtins()
    return sorted(set(_REGISTRY) | set(_installed_entry_points()))


def get_tracker(name: str) -> type:
    """The tracker class for a registry name or a ``"module:Class"`` entry point.

    Raises
    ------
    TrackerNotFoundError
        With the list of known names.
    """
    if not isinstance(name, str) or not name:
        raise TrackerNotFoundError(f"tracker name must be a non-empty string, got {name!r}")
    if ":" in name:
        return _from_entry_point(name)
    _load_builtins()
    if name in _REGISTRY:
        return _REGISTRY[name]
    installed = _installed_entry_points()
    if name in installed:
        return _from_entry_point(installed[name])
    raise TrackerNotFoundError(
        f"unknown tracker {name!r}; known trackers: {', '.join(available_trackers())}, "
        "or give 'package.module:ClassName' of a Tracker2D subclass"
    )


def tracker_params(name: str) -> dict[str, Any]:
    """Documented keyword parameters of a tracker and their defaults (its own and the base's)."""
    cls = get_tracker(name)
    params: dict[str, Any] = {}
    for klass in reversed(cls.__mro__):
        if not (isinstance(klass, type) and issubclass(klass, Tracker2D)):
            continue
        for p in inspect.signature(klass.__init__).parameters.values():
            if p.kind is inspect.Parameter.KEYWORD_ONLY:
                params[p.name] = p.default
    return params


def make_tracker(name: str, initial_xy: np.ndarray, dt: float, rng: np.random.Generator, **params: Any) -> "Tracker2D":
    """Build a tracker by name, checking the parameter names first.

    Raises
    ------
    TrackerNotFoundError
        Unknown tracker name.
    MocapInputError
        A parameter the tracker does not take (the message lists those it takes).
    """
    cls = get_tracker(name)
    known = tracker_params(name)
    unknown = sorted(set(params) - set(known))
    if unknown:
        raise MocapInputError(
            f"tracker {name!r} has no parameter(s) {', '.join(unknown)}; its parameters are: "
            + ", ".join(f"{k}={v!r}" for k, v in known.items())
        )
    return cls(initial_xy, dt, rng, **params)
