"""The sweep file: a grid or a seeded random sample over any scenario fields, expanded into runs.

A sweep file (``scenarios/sweeps/*.toml``) names a base scenario, overrides applied
to every run (``[set]``), and factors, each over one dotted scenario field or a named
set of levels that change several fields at once::

    name = "lighting_blur_tracker"
    scenario = "../visible_office.toml"      # relative to the sweep file
    mode = "grid"                            # or "random" with `samples` and `seed`

    [set]
    "rig.count" = 2
    duration_s = 0.5

    [[factors]]
    field = "lighting.preset"
    values = ["office_fluorescent", "tungsten_lamp", "dim_gym"]

    [[factors]]
    name = "blur"
    [factors.levels]
    off = { "sensor.motion_blur" = false, "sensor.exposure_ms" = 4.0 }
    long = { "sensor.exposure_ms" = 25.0 }

    [[factors]]                              # random mode only
    field = "sensor.read_noise_e"
    range = [1.0, 20.0]
    log = true

Every run is validated before anything renders: a bad field names the sweep file, the
factor, the value and what the scenario schema allows. Each run has a stable id: a hash
of the resolved scenario's content hash and its overrides, so ``--resume`` knows what is
done.

The runs themselves execute in :mod:`simbench.sweeps.sweep`.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
from pydantic import Field, StrictBool, ValidationError, field_validator, model_validator

from simbench.errors import ScenarioError
from simbench.scenario import FrozenModel, Int, Real, Scenario, load_scenario, read_toml_file, validation_error_to_scenario_error
from simbench.scenario.model import OverridePathError

__all__ = ["flatten_dotted", "Factor", "display_value", "SweepSpec", "RunSpec", "Sweep", "run_id_for", "load_sweep", "expand"]


def flatten_dotted(d: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    """``{"sensor": {"exposure_ms": 4}}`` -> ``{"sensor.exposure_ms": 4}`` (TOML's unquoted dotted keys)."""
    out: dict[str, Any] = {}
    for k, v in d.items():
        key = f"{prefix}{k}"
        if isinstance(v, dict) and v:
            out.update(flatten_dotted(v, key + "."))
        else:
            out[key] = v
    return out


class Factor(FrozenModel):
    """One swept factor: ``values`` of a field, named ``levels`` (several fields each), or a ``range``."""

    field: str | None = Field(None, description="dotted scenario field, e.g. sensor.exposure_ms")
    name: str | None = Field(None, description="factor name in reports (default: the field)")
    values: list[Any] | None = Field(None, min_length=1)
    labels: list[str] | None = Field(None, description="display names of `values` (e.g. for props lists)")
    levels: dict[str, dict[str, Any]] | None = Field(None, min_length=1, description="level name -> {dotted field: value}")
    range: tuple[Real, Real] | None = Field(None, description="[low, high] sampled uniformly (random mode)")
    log: StrictBool = Field(False, description="sample `range` log-uniformly")
    integer: StrictBool = Field(False, description="sample `range` as integers (inclusive)")

    @model_validator(mode="after")
    def _one_kind(self):
        kinds = [k for k in ("values", "levels", "range") if getattr(self, k) is not None]
        if len(kinds) != 1:
            raise ValueError(f"give exactly one of `values`, `levels` or `range` (got {kinds or 'none'})")
        if self.levels is None and not self.field:
            raise ValueError("`values` and `range` need `field = \"dotted.scenario.field\"`")
        if self.levels is not None and self.field:
            raise ValueError("`levels` set their own fields; give `name` instead of `field`")
        if self.levels is not None and not self.name:
            raise ValueError("a factor with `levels` needs a `name`")
        if self.labels is not None and (self.values is None or len(self.labels) != len(self.values)):
            raise ValueError("`labels` must have one entry per value")
        if self.range is not None:
            lo, hi = self.range
            if not hi > lo:
                raise ValueError(f"range must be [low, high] with high > low, got {list(self.range)}")
            if self.log and lo <= 0:
                raise ValueError("a log range needs low > 0")
        if self.levels is not None:
            object.__setattr__(self, "levels", {k: flatten_dotted(v) for k, v in self.levels.items()})
        return self

    @property
    def key(self) -> str:
        return self.name or self.field or ""

    def grid_levels(self) -> list[tuple[object, dict[str, Any]]]:
        """``[(level shown in reports, overrides), ...]``; not for ``range`` factors."""
        if self.levels is not None:
            return [(name, dict(ov)) for name, ov in self.levels.items()]
        labels = self.labels or [display_value(v) for v in self.values]
        return [(lab, {self.field: v}) for lab, v in zip(labels, self.values)]

    def sample(self, rng: np.random.Generator) -> tuple[object, dict[str, Any]]:
        if self.range is None:
            levels = self.grid_levels()
            return levels[int(rng.integers(len(levels)))]
        lo, hi = self.range
        if self.integer:
            v: object = int(rng.integers(int(math.ceil(lo)), int(math.floor(hi)) + 1))
        elif self.log:
            v = float(np.exp(rng.uniform(np.log(lo), np.log(hi))))
        else:
            v = float(rng.uniform(lo, hi))
        return v, {self.field: v}


def display_value(v: object) -> object:
    """Scalars stay as they are (numeric axes in reports); anything else becomes compact JSON."""
    if isinstance(v, (bool, int, float, str)):
        return v
    return json.dumps(v, separators=(",", ":"), sort_keys=True, default=str)


class SweepSpec(FrozenModel):
    name: str = Field(pattern=r"^[A-Za-z0-9_.-]+$")
    description: str = ""
    scenario: str = Field(description="base scenario TOML, relative to the sweep file")
    mode: Literal["grid", "random"] = "grid"
    samples: Int | None = Field(None, ge=1, le=100000, description="number of runs in random mode")
    seed: Int = Field(0, ge=0, le=2**32 - 1, description="seed of the random sample (not the scenarios' seed)")
    set: dict[str, Any] = Field(default_factory=dict, description="overrides applied to every run")
    factors: list[Factor] = Field(min_length=1)

    @field_validator("set", mode="before")
    @classmethod
    def _flatten(cls, v):
        return flatten_dotted(v) if isinstance(v, dict) else v

    @model_validator(mode="after")
    def _checks(self):
        keys = [f.key for f in self.factors]
        dup = {k for k in keys if keys.count(k) > 1}
        if dup:
            raise ValueError(f"factor names must be unique; repeated: {sorted(dup)}")
        if self.mode == "grid":
            if any(f.range is not None for f in self.factors):
                raise ValueError("`range` factors need mode = \"random\"; in a grid give `values`")
            if self.samples is not None:
                raise ValueError("`samples` is for mode = \"random\"; a grid runs every combination")
        elif self.samples is None:
            raise ValueError("mode = \"random\" needs `samples = N`")
        return self


@dataclass(frozen=True)
class RunSpec:
    """One run of a sweep (or suite): its id, the factor levels, the resolved scenario."""

    run_id: str
    index: int
    sweep: str
    factors: dict[str, object]
    overrides: dict[str, Any]
    scenario: Scenario


@dataclass(frozen=True)
class Sweep:
    spec: SweepSpec
    path: Path
    runs: tuple[RunSpec, ...]
    duplicates: int = 0

    @property
    def name(self) -> str:
        return self.spec.name

    def factor_levels(self) -> dict[str, list]:
        """Levels of each factor in file order (sampled values for ``range`` factors)."""
        out: dict[str, list] = {}
        for f in self.spec.factors:
            if f.range is None:
                out[f.key] = [lab for lab, _ in f.grid_levels()]
            else:
                out[f.key] = sorted({r.factors[f.key] for r in self.runs})
        return out


def run_id_for(scenario: Scenario, overrides: dict[str, Any]) -> str:
    """Stable id of a run: hash of the resolved scenario's content hash and its overrides."""
    blob = json.dumps({"scenario": scenario.content_hash(), "overrides": overrides}, sort_keys=True, default=str)
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


def load_sweep(path: str | Path, extra_set: dict[str, Any] | None = None) -> Sweep:
    """Read, validate and expand a sweep file (``extra_set`` as if added to ``[set]``)."""
    path = Path(path)
    data = read_toml_file(path, "sweep files live in scenarios/sweeps/*.toml")
    data.setdefault("name", path.stem)
    try:
        spec = SweepSpec.model_validate(data)
    except ValidationError as exc:
        raise validation_error_to_scenario_error(path, exc) from None
    if extra_set:
        spec = spec.model_copy(update={"set": {**spec.set, **flatten_dotted(extra_set)}})
    return Sweep(spec, path, *expand(spec, path))


def _with(base: Scenario, overrides: dict[str, Any], path: Path, where: str) -> Scenario:
    try:
        return base.with_overrides(overrides)
    except ValidationError as exc:
        err = validation_error_to_scenario_error(path, exc)
        raise ScenarioError(path, f"{where} -> scenario field '{err.field}'", err.value, err.allowed) from None
    except OverridePathError as exc:
        raise ScenarioError(path, f"{where} -> scenario field '{exc.field}'", exc.value, exc.reason) from None


def expand(spec: SweepSpec, path: Path) -> tuple[tuple[RunSpec, ...], int]:
    """All runs of a sweep, validated; returns ``(runs, number of duplicate runs dropped)``."""
    scenario_path = (path.parent / spec.scenario).resolve()
    if not scenario_path.is_file():
        raise ScenarioError(path, "scenario", spec.scenario, f"file not found (looked for {scenario_path})")
    base = load_scenario(scenario_path)
    base = _with(base, spec.set, path, "set")
    # Each level on its own first, so an error names the factor and level that causes it.
    for i, f in enumerate(spec.factors):
        probes = f.grid_levels() if f.range is None else [(v, {f.field: v}) for v in f.range]
        for label, ov in probes:
            _with(base, ov, path, f"factors[{i}] ({f.key} = {label!r})")
    if spec.mode == "grid":
        combos = itertools.product(*[f.grid_levels() for f in spec.factors])
    else:
        rng = np.random.default_rng(spec.seed)
        combos = [[f.sample(rng) for f in spec.factors] for _ in range(spec.samples)]
    runs: list[RunSpec] = []
    seen: set[str] = set()
    duplicates = 0
    for combo in combos:
        factors = {f.key: lab for f, (lab, _) in zip(spec.factors, combo)}
        factor_ov: dict[str, Any] = {}
        for _, ov in combo:
            factor_ov.update(ov)
        sc = _with(base, factor_ov, path, "run " + ", ".join(f"{k}={v!r}" for k, v in factors.items()))
        overrides = {**spec.set, **factor_ov}
        rid = run_id_for(sc, overrides)
        if rid in seen:
            duplicates += 1
            continue
        seen.add(rid)
        runs.append(RunSpec(rid, len(runs), spec.name, factors, overrides, sc))
    return tuple(runs), duplicates
