"""The scenario schema's shared types: bounded finite numbers (``Real``, ``Int``, ``Coord``, ``Unit``,
``Length``, ``Coef``), plain names, :func:`field_error` and :class:`FrozenModel`, the base of every
file schema of the bench (scenarios, sweeps, suites, baselines)."""

from __future__ import annotations

import math
import re
from typing import Annotated

import numpy as np
from pydantic import AfterValidator, BaseModel, BeforeValidator, ConfigDict, Field, StringConstraints
from pydantic_core import PydanticCustomError


def _a_number(v: object) -> object:
    """Before pydantic's own float/int parsing: only numbers (pydantic would take ``true`` as 1
    and ``"3"`` as 3) and only finite ones (NaN and inf would pass a missing bound, and NaN
    passes every comparison)."""
    if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)):
        raise PydanticCustomError("not_a_number", "expected a number, got {kind}", {"kind": type(v).__name__})
    if not math.isfinite(v):
        raise PydanticCustomError("not_finite", "expected a finite number (NaN and inf are refused)")
    return v


#: Every number of the file schemas is one of these two: finite, not a boolean or a string, and
#: bounded (a field's own ``Field(ge=..., le=...)`` narrows the default bound of +-1e6).
Real = Annotated[float, BeforeValidator(_a_number), Field(ge=-1e6, le=1e6)]
Int = Annotated[int, BeforeValidator(_a_number), Field(ge=-1_000_000, le=1_000_000)]
#: A coordinate or a vector component in metres (or m/s): within 1 km of the origin.
Coord = Annotated[float, BeforeValidator(_a_number), Field(ge=-1000.0, le=1000.0)]
Vec3 = tuple[Coord, Coord, Coord]
#: A linear albedo, 0..1 per channel.
Unit = Annotated[float, BeforeValidator(_a_number), Field(ge=0.0, le=1.0)]
RGB = tuple[Unit, Unit, Unit]
#: A positive length in metres, up to 20 m (sizes of props, half extents of volumes).
Length = Annotated[float, BeforeValidator(_a_number), Field(gt=0.0, le=20.0)]
#: A lens distortion coefficient (OpenCV's k1, k2, p1, p2, k3).
Coef = Annotated[float, BeforeValidator(_a_number), Field(ge=-100.0, le=100.0)]
Distortion = tuple[Coef, Coef, Coef, Coef, Coef]
_NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.+-]{0,63}")


def _plain_name(v: str) -> str:
    if not _NAME.fullmatch(v):
        raise PydanticCustomError("name", "expected a plain name: letters, digits, '_', '.', '+', '-' (1 to 64 of them, "
                                          "not starting with '.', '+' or '-'), e.g. 'cam_left'")
    return v


#: A name that becomes part of a file name or is matched by other fields (cameras, lights, props).
Name = Annotated[str, AfterValidator(_plain_name)]
#: A file the scenario reads (relative to the scenario file, or absolute).
FilePath = Annotated[str, StringConstraints(min_length=1, strip_whitespace=True)]


def field_error(field: str, value: object, allowed: str) -> PydanticCustomError:
    """A model validator's error about one of its fields: :func:`validation_error_to_scenario_error`
    names ``field`` (under the model's own path) and ``value`` instead of the whole table."""
    return PydanticCustomError("scenario_field", "{allowed}", {"allowed": allowed, "field": field, "value": value})


class FrozenModel(BaseModel):
    """Base of every file schema of the bench (scenarios, sweeps, suites, baselines): an unknown
    field is an error naming it, and a validated instance cannot change."""

    model_config = ConfigDict(extra="forbid", frozen=True)


def omit_defaults(data: object, defaults: dict[str, object]) -> object:
    """``data``, a model's serialisation, without the keys that equal their value in ``defaults``:
    fields added after scenarios' content hashes were recorded serialise (and hash) as before
    them while they keep these values (for a model serializer in ``mode="wrap"``)."""
    if isinstance(data, dict):
        for key, value in defaults.items():
            if key in data and data[key] == value:
                del data[key]
    return data
