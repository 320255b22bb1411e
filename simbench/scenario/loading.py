"""Loading scenario files: TOML read and validated, ``--set`` overrides parsed, any validation
problem turned into one :class:`~simbench.errors.ScenarioError` naming the file, the field, the
value and what is allowed; a rig from a calibration file checked against the scenario."""

from __future__ import annotations

import tomllib
from pathlib import Path

from pydantic import ValidationError

from mocap.calibration_formats import load_calibration
from mocap.errors import MocapInputError
from simbench.errors import ScenarioError, SimbenchInputError
from simbench.scenario.model import OverridePathError, Scenario, _set_dotted


def _format_loc(loc: tuple) -> str:
    parts = []
    for p in loc:
        if isinstance(p, int):
            parts.append(str(p))
        elif p in ("ball", "barrier", "moving") or p.startswith("function-"):
            continue
        else:
            parts.append(str(p))
    return ".".join(parts) or "<root>"


def validation_error_to_scenario_error(path: Path, exc: ValidationError) -> ScenarioError:
    err = exc.errors()[0]
    loc = _format_loc(tuple(err.get("loc", ())))
    value = err.get("input")
    msg = err.get("msg", "invalid")
    if err.get("type") == "scenario_field":  # a model's check about one of its fields (field_error)
        ctx = err.get("ctx", {})
        loc = ctx["field"] if loc == "<root>" else f"{loc}.{ctx['field']}"
        value = ctx["value"]
    if err.get("type") == "extra_forbidden":
        msg = "unknown field; check the spelling against `simbench info --schema`"
    if err.get("type") == "missing":
        value = "<missing>"
        msg = "this field is required"
    if isinstance(value, dict) and err.get("type") != "scenario_field":
        value = "{...}"
    extra = f" (and {len(exc.errors()) - 1} more problem(s))" if len(exc.errors()) > 1 else ""
    return ScenarioError(path, loc, value, msg + extra)


def read_toml_file(path: Path, where_they_live: str) -> dict:
    """The table of a TOML file (scenario, sweep, suites); a :class:`ScenarioError` naming the
    file when it is missing (``where_they_live`` says where such files are) or not TOML."""
    if not path.is_file():
        raise ScenarioError(path, "<file>", str(path), f"file not found; {where_they_live}")
    try:
        # utf-8-sig: a byte-order mark (what Windows editors put first) is not TOML, and tomllib refused the
        # file at "line 1, column 1" without saying why
        text = path.read_bytes().decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line_no = exc.object.count(b"\n", 0, exc.start) + 1
        line = exc.object.splitlines()[line_no - 1].decode("utf-8", "replace")  # shown with U+FFFD where it is not UTF-8
        raise ScenarioError(path, "<encoding>", line, f"line {line_no} (byte {exc.start} of the file) is not UTF-8; "
                                                      f"TOML files are UTF-8 text, save it as such") from None
    except OSError as exc:
        raise ScenarioError(path, "<file>", str(path), f"cannot be read ({exc.strerror})") from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(path, "<syntax>", str(exc), "fix the TOML syntax at the line given") from None


def parse_overrides(items: list[str]) -> dict[str, object]:
    """``FIELD=VALUE`` strings (``--set`` options) to a dict for :func:`load_scenario`'s ``overrides``;
    values parsed as TOML (numbers, strings, booleans, arrays), else kept as the string."""
    out: dict[str, object] = {}
    for item in items:
        if "=" not in item:
            raise SimbenchInputError(f"--set {item!r}: expected FIELD=VALUE, e.g. sensor.exposure_ms=20")
        key, value = item.split("=", 1)
        try:
            out[key.strip()] = tomllib.loads(f"v = {value}")["v"]
        except tomllib.TOMLDecodeError:
            out[key.strip()] = value
    return out


def load_scenario(path: str | Path, overrides: dict[str, object] | None = None) -> Scenario:
    """Read and validate a scenario TOML file.

    Raises
    ------
    ScenarioError
        naming the file, the field, the value and what is allowed.
    """
    path = Path(path)
    data = read_toml_file(path, "scenarios live in scenarios/*.toml")
    data.setdefault("name", path.stem)
    data["source_dir"] = str(path.parent.resolve())
    data["source_file"] = str(path)
    for dotted, value in (overrides or {}).items():
        try:
            _set_dotted(data, dotted, value)
        except OverridePathError as exc:
            raise ScenarioError(path, exc.field, value, exc.reason) from None
    try:
        scenario = Scenario.model_validate(data)
    except ValidationError as exc:
        raise validation_error_to_scenario_error(path, exc) from None
    _check_rig_calibration(path, scenario)
    for key in ("bvh", "c3d", "trc"):
        given = getattr(scenario.motion, key)
        if given and not scenario.resolve_path(given).is_file():
            shared = "; it is real data from the project's shared/ folder: put shared/ beside the repository" if "shared" in Path(given).parts else ""
            raise ScenarioError(path, f"motion.{key}", given, f"file not found (looked for {scenario.resolve_path(given)}){shared}")
    return scenario


def _check_rig_calibration(path: Path, scenario: Scenario) -> None:
    """``rig.from_calibration``: the file loads (a fisheye or malformed file is refused, naming
    the file's own field) and its cameras share one image size (the bench renders one)."""
    given = scenario.rig.from_calibration if scenario.rig is not None else None
    if given is None:
        return
    try:
        calibration = load_calibration(scenario.resolve_path(given))
    except MocapInputError as exc:
        raise ScenarioError(path, "rig.from_calibration", given, str(exc)) from None
    sizes = sorted({c.size for c in calibration})
    if len(sizes) > 1:
        raise ScenarioError(path, "rig.from_calibration", given,
                            f"its cameras have different image sizes {sizes}; the bench renders one size for every camera")
