"""The bad inputs of the fuzzer (:mod:`fuzz_inputs`, which runs and judges them): mutations of
the shipped scenarios for ``simbench run`` (:func:`scenario_cases`) and spoiled takes for
``mocap markers`` (:func:`mocap_cases`). Which values are bad is written here, independently of
the schema, so a bound missing from the schema shows as an accepted bad value.
"""

from __future__ import annotations

import contextlib
import copy
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterator

import cv2
import numpy as np
import tomli_w

REPO = Path(__file__).resolve().parents[1]
SCENARIOS = REPO / "scenarios"

# ------------------------------------------------------------------------- what is bad
#: Quantities that are positive by their nature (a count, a duration, a rate, a size): zero and
#: negative values are bad. Paths as in the resolved scenario; ``*`` is any list index.
POSITIVE = (
    "duration_s", "fps", "body.height_m", "motion.speed", "sensor.exposure_ms", "sensor.gain", "sensor.full_well_e",
    "sensor.wb_adapt_s", "sensor.blur_step_px", "sensor.max_subframes", "sensor.antialias", "sensor.electrons_per_unit",
    "sensor.ae_target", "sensor.ae_adapt_s", "sensor.ae_max_gain",
    "rig.count", "rig.radius_m", "rig.hfov_deg", "rig.width", "rig.height", "rig.span_deg", "cameras.*.width",
    "cameras.*.height", "cameras.*.hfov_deg", "lighting.scale", "set.room_size_m", "props.*.radius_m", "props.*.size_m.*",
    "shirt_pipeline.database_size", "shirt_pipeline.training_frames", "calibration_scene.board_cols",
    "calibration_scene.board_rows", "calibration_scene.square_m", "calibration_scene.n_views",
    "calibration_scene.board_thickness_m", "calibration_scene.wand_d01_m", "calibration_scene.wand_d12_m",
    "calibration_scene.wand_marker_radius_m", "calibration_scene.volume_half_m.*", "motion.gaps.fraction",
    "motion.gaps.min_frames", "motion.gaps.max_frames", "motion.gaps.runs",
)
#: Fields whose value is looked up in a registry: an unknown name is bad.
REGISTERED = ("subject.markers", "motion.clip", "markers_pipeline.tracker", "lighting.preset", "sensor.mode",
              "sensor.gamma", "sensor.white_balance", "markers_pipeline.smoothing", "markers_pipeline.labelling",
              "calibration_scene.dictionary", "calibration_scene.board", "lighting.events.*.light", "props.*.kind",
              "lighting.lights.*.kind", "motion.up_axis", "motion.end")
#: Names that end up in file names or are matched by other fields: not a plain name is bad.
NAMES = ("cameras.*.name", "lighting.lights.*.name", "props.*.name")
#: Files a scenario reads.
PATHS = ("motion.bvh", "motion.c3d", "motion.trc", "rig.from_calibration", "shirt_pipeline.database")
BAD_NUMBERS = (math.nan, math.inf, -math.inf, 1e300, -1e300, True, False, "12", [1.0], {"x": 1.0})
BAD_NAMES = ("", "a/b", "../up", "/abs/name", ".hidden", "white space", "x" * 80)
BAD_SCENARIO_NAMES = ("", "../escape", "/abs/elsewhere", "a/b", ".", "..")


@dataclass
class Case:
    """One bad input: the bytes of the file (or the arguments), what was done, and which
    fields (dotted paths, or option names) the one-line error may name."""

    label: str
    kind: str
    fields: tuple[str, ...]
    text: bytes = b""
    args: tuple[str, ...] = ()
    use_out: bool = True
    value: object = None
    prepare: Callable[[Path], None] | None = None
    patch: Callable[[], contextlib.AbstractContextManager] | None = None


# ------------------------------------------------------------------------ scenario cases
def _match(pattern: str, path: str) -> bool:
    a, b = pattern.split("."), path.split(".")
    return len(a) == len(b) and all(x == "*" or x == y for x, y in zip(a, b))


def _leaves(node: object, prefix: str = "") -> Iterator[tuple[str, object]]:
    if isinstance(node, dict):
        for k, v in node.items():
            yield from _leaves(v, f"{prefix}.{k}" if prefix else k)
    elif isinstance(node, list) and node and not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in node):
        for i, v in enumerate(node):
            yield from _leaves(v, f"{prefix}.{i}")
    else:
        yield prefix, node
        if isinstance(node, list):
            for i, v in enumerate(node):
                if not isinstance(v, list):
                    yield f"{prefix}.{i}", v


def _get(data: dict, path: str) -> object:
    node: object = data
    for k in path.split("."):
        node = node[int(k)] if isinstance(node, list) else node[k]
    return node


def _set(data: dict, path: str, value: object) -> None:
    keys = path.split(".")
    node: object = data
    for k in keys[:-1]:
        node = node[int(k)] if isinstance(node, list) else node.setdefault(k, {})
    if isinstance(node, list):
        node[int(keys[-1])] = value
    else:
        node[keys[-1]] = value


def _delete(data: dict, path: str) -> None:
    keys = path.split(".")
    node: object = data
    for k in keys[:-1]:
        node = node[int(k)] if isinstance(node, list) else node[k]
    del node[keys[-1]]


def _drop_none(node: object) -> object:
    if isinstance(node, dict):
        return {k: _drop_none(v) for k, v in node.items() if v is not None}
    if isinstance(node, list):
        return [_drop_none(v) for v in node]
    return node


def resolved_bases(names: list[str] | None = None) -> dict[str, dict]:
    """The shipped scenarios, resolved: every field (defaults filled in) as a TOML-able table,
    relative paths made absolute so the files can live anywhere."""
    from simbench.scenario import load_scenario

    bases = {}
    for path in sorted(SCENARIOS.glob("*.toml")):
        if path.name == "suites.toml" or (names and path.stem not in names):
            continue
        sc = load_scenario(path)
        data = sc.model_dump(mode="json")
        data.pop("seeds", None)  # how many seeds `simbench run` repeats: not a field of one run
        for p in PATHS:
            with contextlib.suppress(KeyError, TypeError):
                v = _get(data, p)
                if isinstance(v, str):
                    _set(data, p, str(sc.resolve_path(v)))
        bases[path.stem] = _drop_none(data)
    return bases


def _toml(data: dict) -> bytes:
    return tomli_w.dumps(data).encode()


def _value_text(v: object) -> str | None:
    """What the error line must show of a scalar value (None: a table or list, shown abbreviated)."""
    if isinstance(v, float) and math.isnan(v):
        return "nan"
    if isinstance(v, (bool, int, float, str)):
        return repr(v)
    return None


def scenario_cases(n: int, rng: np.random.Generator, bases: dict[str, dict]) -> list[Case]:
    """``n`` bad scenario files, mutations of ``bases`` drawn with ``rng``."""
    kinds = {"bad number": 30, "zero or negative": 12, "unknown name": 10, "bad name": 8, "scenario name": 4,
             "bad path": 5, "unknown field": 5, "missing field": 3, "wrong table": 4, "file bytes": 6, "geometry": 13,
             "--set": 6}
    names = list(bases)
    kind_names, weights = list(kinds), np.array(list(kinds.values()), float)
    cases: list[Case] = []
    attempts = 0
    while len(cases) < n and attempts < 50 * n:
        attempts += 1
        base_name = names[rng.integers(len(names))]
        kind = kind_names[rng.choice(len(kind_names), p=weights / weights.sum())]
        case = _mutate(kind, base_name, copy.deepcopy(bases[base_name]), rng)
        if case is not None:
            case.label = f"{len(cases):03d} {base_name}: {case.label}"
            cases.append(case)
    return cases


def _pick(rng: np.random.Generator, items: list):
    return items[rng.integers(len(items))] if items else None


def _mutate(kind: str, base: str, data: dict, rng: np.random.Generator) -> Case | None:
    """One mutation of kind ``kind`` of the resolved scenario ``data`` (None: it has nothing to mutate)."""
    return _MUTATIONS[kind](kind, data, dict(_leaves(data)), rng)


def _bad_number(kind: str, data: dict, leaves: dict, rng: np.random.Generator) -> Case | None:
    path = _pick(rng, [p for p, v in leaves.items() if isinstance(v, (int, float)) and not isinstance(v, bool)])
    value = BAD_NUMBERS[rng.integers(len(BAD_NUMBERS))]
    if path is None:
        return None
    _set(data, path, value)
    return Case(f"{path} = {value!r}", kind, (path,), _toml(data), value=value)


def _bad_zero_or_negative(kind: str, data: dict, leaves: dict, rng: np.random.Generator) -> Case | None:
    path = _pick(rng, [p for p, v in leaves.items() if any(_match(q, p) for q in POSITIVE) and isinstance(v, (int, float))])
    if path is None:
        return None
    value = [0, -1, -0.5, -1e6][rng.integers(4)]
    value = type(_get(data, path))(value) if isinstance(_get(data, path), int) and value == int(value) else value
    _set(data, path, value)
    return Case(f"{path} = {value!r}", kind, (path,), _toml(data), value=value)


def _bad_unknown_name(kind: str, data: dict, leaves: dict, rng: np.random.Generator) -> Case | None:
    path = _pick(rng, [p for p in leaves if any(_match(q, p) for q in REGISTERED)])
    if path is None:
        return None
    value = ["no_such_thing", "Kalman", "", "office fluorescent"][rng.integers(4)]
    _set(data, path, value)
    # an unknown prop or light kind is reported by the union under the list entry
    return Case(f"{path} = {value!r}", kind, (path,), _toml(data), value=value)


def _bad_name(kind: str, data: dict, leaves: dict, rng: np.random.Generator) -> Case | None:
    path = _pick(rng, [p for p in leaves if any(_match(q, p) for q in NAMES)])
    if path is None:
        path = "cameras.0.name"
        data["cameras"] = [{"name": "c0", "position": [3.0, 0.0, 1.5]}, {"name": "c1", "position": [0.0, 3.0, 1.5]}]
    value = BAD_NAMES[rng.integers(len(BAD_NAMES))]
    _set(data, path, value)
    return Case(f"{path} = {value!r}", kind, (path,), _toml(data), value=value)


def _bad_scenario_name(kind: str, data: dict, leaves: dict, rng: np.random.Generator) -> Case | None:
    value = BAD_SCENARIO_NAMES[rng.integers(len(BAD_SCENARIO_NAMES))]
    data["name"] = value
    return Case(f"name = {value!r} (default --out)", kind, ("name",), _toml(data), use_out=False, value=value)


def _bad_path(kind: str, data: dict, leaves: dict, rng: np.random.Generator) -> Case | None:
    path = _pick(rng, [p for p in PATHS if p in leaves and isinstance(leaves[p], str)] or ["motion.bvh"])
    value = ["", "   ", "/nonexistent/take.bvh", "../../no/such/file.c3d", "/"][rng.integers(5)]
    if path == "motion.bvh":
        data["motion"] = {k: v for k, v in data["motion"].items() if k not in ("c3d", "trc", "labels", "gaps", "up_axis")}
        data["motion"]["clip"] = "bvh"
    _set(data, path, value)
    return Case(f"{path} = {value!r}", kind, (path, "motion"), _toml(data), value=value)


def _bad_unknown_field(kind: str, data: dict, leaves: dict, rng: np.random.Generator) -> Case | None:
    tables = [k for k, v in data.items() if isinstance(v, dict)]
    where = _pick(rng, ["", *tables])
    key = ["colour", "fsp", "exposure", "Count", "durations"][rng.integers(5)]
    path = f"{where}.{key}" if where else key
    _set(data, path, 1)
    return Case(f"{path} = 1 (unknown field)", kind, (path,), _toml(data))


def _bad_missing_field(kind: str, data: dict, leaves: dict, rng: np.random.Generator) -> Case | None:
    options = [p for p in leaves if re.fullmatch(r"(cameras\.\d+\.(name|position)|lighting\.lights\.\d+\.name|"
                                                  r"lighting\.events\.\d+\.(light|t_s|intensity))", p)]
    path = _pick(rng, options)
    if path is None:
        data["cameras"] = [{"name": "c0", "position": [3.0, 0.0, 1.5]}, {"name": "c1", "position": [0.0, 3.0, 1.5]}]
        path = ["cameras.1.name", "cameras.0.position"][rng.integers(2)]
    _delete(data, path)
    return Case(f"{path} missing", kind, (path,), _toml(data))


def _bad_wrong_table(kind: str, data: dict, leaves: dict, rng: np.random.Generator) -> Case | None:
    path = _pick(rng, ["rig", "sensor", "lighting", "body", "motion", "cameras", "props", "set"])
    value = [5, "text", [1, 2], True][rng.integers(4)]
    data[path] = value
    return Case(f"{path} = {value!r}", kind, (path,), _toml(data), value=value)


def _bad_file_bytes(kind: str, data: dict, leaves: dict, rng: np.random.Generator) -> Case | None:
    text = _toml(data)
    how = ["latin-1", "invalid utf-8", "duplicate key", "unclosed string", "unclosed table", "nul byte"][rng.integers(6)]
    if how == "latin-1":
        text = text.replace(b'description = "', b'description = "caf\xe9 ', 1) if b"description" in text else b'description = "caf\xe9"\n' + text
    elif how == "invalid utf-8":
        at = int(rng.integers(len(text)))
        text = text[:at] + b"\xff\xfe" + text[at:]
    elif how == "duplicate key":
        text = b"fps = 30.0\n" + text
    elif how == "unclosed string":
        text = b'description = "no end\n' + text
    elif how == "unclosed table":
        text = text + b"\n[rig\ncount = 4\n"
    else:
        text = b"seed = \x00\n" + text
    return Case(f"file: {how}", kind, ("<encoding>", "<syntax>", "fps", "description", "seed"), text)


def _bad_geometry(kind: str, data: dict, leaves: dict, rng: np.random.Generator) -> Case | None:
    return _geometry(data, rng)


def _bad_set_option(kind: str, data: dict, leaves: dict, rng: np.random.Generator) -> Case | None:
    """The file is good; the command line's override is not: its value, or its path."""
    if rng.random() < 0.4:
        return _bad_set_path(kind, data, leaves, rng)
    path = _pick(rng, [p for p, v in leaves.items() if isinstance(v, (int, float)) and not isinstance(v, bool)])
    text, value = [("nan", math.nan), ("inf", math.inf), ("-1e300", -1e300), ("true", True), ('"x"', "x"),
                   ("[1, 2]", None)][rng.integers(6)]
    return Case(f"--set {path}={text}", kind, (path,), _toml(data), args=("--set", f"{path}={text}"), value=value)


def _bad_set_path(kind: str, data: dict, leaves: dict, rng: np.random.Generator) -> Case | None:
    """An override path that leads to no field: a list index out of range or not a number, or a field inside a value."""
    indexed = [p for p in leaves if any(part.isdigit() for part in p.split("."))]
    how = int(rng.integers(3))
    if how < 2 and indexed:
        parts = _pick(rng, indexed).split(".")
        i = next(j for j, part in enumerate(parts) if part.isdigit())
        parts[i] = "99" if how == 0 else "first"
        bad, field = ".".join(parts), ".".join(parts[: i + 1])
    else:
        path = _pick(rng, [p for p, v in leaves.items() if isinstance(v, (int, float, str)) and not isinstance(v, bool)])
        bad = field = f"{path}.inner"
    return Case(f"--set {bad}=1", kind, (field,), _toml(data), args=("--set", f"{bad}=1"), value=1)


_MUTATIONS: dict[str, Callable[[str, dict, dict, np.random.Generator], Case | None]] = {
    "bad number": _bad_number,
    "zero or negative": _bad_zero_or_negative,
    "unknown name": _bad_unknown_name,
    "bad name": _bad_name,
    "scenario name": _bad_scenario_name,
    "bad path": _bad_path,
    "unknown field": _bad_unknown_field,
    "missing field": _bad_missing_field,
    "wrong table": _bad_wrong_table,
    "file bytes": _bad_file_bytes,
    "geometry": _bad_geometry,
    "--set": _bad_set_option,
}


def _two_cameras(**first) -> list[dict]:
    return [{"name": "c0", "position": [3.0, 0.0, 1.5], **first}, {"name": "c1", "position": [0.0, 3.0, 1.5]}]


def _geometry(data: dict, rng: np.random.Generator) -> Case:
    """Degenerate geometry: every one of these would render nothing useful, or nothing."""
    how = int(rng.integers(11))
    fps = data.get("fps", 30.0)
    if how == 0:
        data["cameras"] = _two_cameras(position=[0.1, 0.05, 1.0], look_at=[3.0, 0.0, 1.0])
        return Case("a camera inside the body", "geometry", ("cameras.0.position", "cameras.0"), _toml(data))
    if how == 1:
        data["cameras"] = _two_cameras(look_at=[3.0, -20.0, 1.5])
        return Case("a camera looking away from the subject", "geometry", ("cameras.0.look_at", "cameras.0"), _toml(data))
    if how == 2:
        data.pop("cameras", None)
        data.setdefault("rig", {})["look_at"] = [60.0, 0.0, 1.0]
        return Case("a rig looking at a point 60 m away", "geometry", ("rig", "rig.look_at"), _toml(data))
    if how == 3:
        data["cameras"] = _two_cameras(K=[[0.0, 0.0, 320.0], [0.0, 0.0, 240.0], [0.0, 0.0, 1.0]], hfov_deg=None)
        data["cameras"][0].pop("hfov_deg")
        return Case("K = 0", "geometry", ("cameras.0.K",), _toml(data))
    if how == 4:
        data["cameras"] = _two_cameras(K=[[500.0, 0.0, 320.0], [0.0, 500.0, 240.0], [1.0, 0.0, 0.0]])
        return Case("K's last row not [0, 0, 1]", "geometry", ("cameras.0.K",), _toml(data))
    if how == 5:
        lighting = data.setdefault("lighting", {})
        lighting["lights"] = [*lighting.get("lights", []), {"name": "sun2", "kind": "directional", "direction": [0.0, 0.0, 0.0]}]
        i = len(lighting["lights"]) - 1
        return Case("a zero light direction", "geometry", (f"lighting.lights.{i}.direction",), _toml(data))
    if how == 6:
        data["duration_s"] = 1.0 / fps
        return Case("duration_s = 1/fps: one frame", "geometry", ("duration_s",), _toml(data), value=data["duration_s"])
    if how == 7:
        data["props"] = [*data.get("props", []), {"kind": "ball", "radius_m": 1.0}]
        return Case("a 2 m ball", "geometry", (f"props.{len(data['props']) - 1}.radius_m",), _toml(data), value=1.0)
    if how == 8:
        data["cameras"] = _two_cameras()[:1]
        data.pop("rig", None)
        data.setdefault("subject", {})["markers"] = "plugin_gait_full"
        return Case("one camera for the marker pipeline", "geometry", ("cameras",), _toml(data))
    if how == 9:
        data["cameras"] = _two_cameras(position=[3.0, 0.0, 1.0], look_at=[3.0, 0.0, 1.0])
        return Case("look_at = position", "geometry", ("cameras.0.look_at", "cameras.0"), _toml(data))
    data["cameras"] = _two_cameras(up=[0.0, 0.0, 0.0])
    return Case("a zero up vector", "geometry", ("cameras.0.up",), _toml(data))


# ------------------------------------------------------------------------- mocap cases
W, H, N_FRAMES = 160, 120, 6


def _synthetic_take(d: Path, n_frames: int = N_FRAMES) -> tuple[list[Path], Path, Path]:
    """Three 160x120 cameras around three markers that move a little: videos (MJPG AVI), an
    OpenCV calibration and a label template. ``mocap markers`` on them succeeds."""
    from mocap.calibration import Calibration, Camera
    from mocap.labelling import LabelTemplate, save_template

    markers = np.array([[0.0, 0.0, 1.0], [0.5, 0.0, 1.0], [0.0, 0.4, 1.5]])
    cams = []
    for i, (x, y) in enumerate(((-3.0, -3.0), (3.0, -3.0), (0.0, 3.5))):
        eye = np.array([x, y, 1.6])
        z = np.array([0.0, 0.1, 1.1]) - eye
        z /= np.linalg.norm(z)
        xa = np.cross(z, [0, 0, 1.0])
        xa /= np.linalg.norm(xa)
        R = np.stack([xa, np.cross(z, xa), z])
        cams.append(Camera(f"cam{i}", (W, H), [[140.0, 0, (W - 1) / 2], [0, 140.0, (H - 1) / 2], [0, 0, 1]], [0.0] * 5, R, -R @ eye))
    cal = Calibration(tuple(cams))
    cal_path = d / "cal.yml"
    cal.save_opencv_yaml(cal_path)
    tmpl = save_template(LabelTemplate(("A", "B", "C"), markers), d / "template.csv")
    videos = []
    for cam in cams:
        path = d / f"{cam.name}.avi"
        vw = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 30.0, (W, H))
        for f in range(n_frames):
            img = np.zeros((H, W, 3), np.uint8)
            for uv in cam.project(markers + [0.01 * f, 0.0, 0.0]):
                cv2.circle(img, (int(round(uv[0])), int(round(uv[1]))), 2, (255, 255, 255), -1, cv2.LINE_AA)
            vw.write(img)
        vw.release()
        videos.append(path)
    return videos, cal_path, tmpl


def _video(path: Path, n: int, size=(W, H), value: int = 0, fps: float = 30.0) -> None:
    vw = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), fps, size)
    for _ in range(n):
        vw.write(np.full((size[1], size[0], 3), value, np.uint8))
    vw.release()


def _edit_yaml(pattern: str, repl: str) -> Callable[[Path], None]:
    def prepare(d: Path) -> None:
        text = (d / "cal.yml").read_text()
        new = re.sub(pattern, repl, text, count=1, flags=re.S)
        if new == text:
            raise RuntimeError(f"fuzz: {pattern!r} not in the calibration")
        (d / "cal.yml").write_text(new)
    return prepare


def _write(name: str, data: bytes) -> Callable[[Path], None]:
    return lambda d: (d / name).write_bytes(data)


def mocap_cases(n: int, rng: np.random.Generator) -> list[Case]:
    """At least ``n`` bad ``mocap markers`` inputs (all of the kinds below, drawn with ``rng``
    when more are asked for than there are kinds). ``args`` are the command line after
    ``markers``; ``{d}`` is the case's folder, holding a good take made by :func:`_synthetic_take`."""
    V = ("{d}/cam0.avi", "{d}/cam1.avi", "{d}/cam2.avi")
    std = ("--calibration", "{d}/cal.yml", "--template", "{d}/template.csv", "--out", "{d}/cap")

    def c(label, fields, prepare=None, videos=V, extra=(), opts=std, patch=None) -> Case:
        return Case(label, "mocap", fields, args=(*videos, *opts, *extra), prepare=prepare, patch=patch)

    def vid(i, **kw):
        return lambda d: _video(d / f"cam{i}.avi", **{"n": N_FRAMES, **kw})

    def yaml_value(key, value):  # the first matrix `key` of the calibration gets `value` in its data
        return _edit_yaml(rf"({key}: !!opencv-matrix.*?data: \[ )([^,\]]+)", rf"\g<1>{value}")

    kinds = [
        c("all-black videos", ("cam0.avi",), lambda d: [vid(i, value=0)(d) for i in range(3)]),
        c("all-white videos", ("cam0.avi",), lambda d: [vid(i, value=255)(d) for i in range(3)]),
        c("a video at half size", ("cam1.avi",), vid(1, size=(W // 2, H // 2))),
        c("a video at double size", ("cam2.avi",), vid(2, size=(2 * W, 2 * H))),
        c("videos of unequal length", ("cam0.avi",), vid(1, n=N_FRAMES + 3)),
        c("a video at another frame rate", ("cam0.avi", "cam2.avi"), vid(2, fps=25.0)),
        c("a video that is text", ("cam1.avi",), _write("cam1.avi", b"not a video\n")),
        c("an empty video file", ("cam0.avi",), _write("cam0.avi", b"")),
        c("a missing video", ("cam2.avi",), lambda d: (d / "cam2.avi").unlink()),
        c("two videos for three cameras", ("cam0.avi",), videos=V[:2]),
        c("four videos for three cameras", ("cam3.avi",), lambda d: vid(3)(d), videos=(*V, "{d}/cam3.avi")),
        c("an empty calibration", ("cal.yml",), _write("cal.yml", b"")),
        c("a garbage calibration", ("cal.yml",), _write("cal.yml", b"\x00\x01garbage\xff")),
        c("a calibration of another YAML", ("cal.yml",), _write("cal.yml", b"%YAML:1.0\n---\nfoo: 1\n")),
        c("NaN in a calibration's K", ("cal.yml",), yaml_value("camera_0_K", ".Nan")),
        c("inf in a calibration's K", ("cal.yml",), yaml_value("camera_1_K", ".Inf")),
        c("NaN in a calibration's R", ("cal.yml",), yaml_value("camera_2_R", ".Nan")),
        c("a zero focal length", ("cal.yml",), yaml_value("camera_0_K", "0.")),
        c("a calibration's K of 2x2", ("cal.yml",), _edit_yaml(r"(camera_0_K: !!opencv-matrix\s+rows: )3(\s+cols: )3(\s+dt: d\s+data: \[)[^\]]*\]",
                                                                 r"\g<1>2\g<2>2\g<3> 60., 0., 0., 60. ]")),
        c("a calibration whose R is no rotation", ("cal.yml",), yaml_value("camera_1_R", "7.")),
        c("a calibration file that is missing", ("nope.yml",), opts=("--calibration", "{d}/nope.yml", *std[2:])),
        c("a calibration that is a folder", ("cal_dir",), lambda d: (d / "cal_dir").mkdir(),
          opts=("--calibration", "{d}/cal_dir", *std[2:])),
        c("a non-UTF-8 template", ("template.csv",), _write("template.csv", b"name,x,y,z\nA\xe9,0,0,1\nB,0.2,0,1\nC,0,0.2,1.2\n")),
        c("an empty template", ("template.csv",), _write("template.csv", b"")),
        c("a template with NaN", ("template.csv",), _write("template.csv", b"name,x,y,z\nA,nan,0,1\nB,0.2,0,1\nC,0,0.2,1.2\n")),
        c("a template with text for a number", ("template.csv",), _write("template.csv", b"name,x,y,z\nA,zero,0,1\nB,0.2,0,1\nC,0,0.2,1.2\n")),
        c("a template with a duplicated label", ("template.csv",), _write("template.csv", b"name,x,y,z\nA,0,0,1\nA,0.2,0,1\nC,0,0.2,1.2\n")),
        c("a template row with two columns", ("template.csv",), _write("template.csv", b"name,x,y,z\nA,0,0\nB,0.2,0,1\nC,0,0.2,1.2\n")),
        c("a missing template", ("nope.csv",), opts=(*std[:2], "--template", "{d}/nope.csv", *std[4:])),
        c("no --template and no --labelled-trial", ("--template",), opts=(*std[:2], *std[4:])),
        c("--fps 0", ("--fps",), extra=("--fps", "0")),
        c("--fps -30", ("--fps",), extra=("--fps", "-30")),
        c("--fps nan", ("--fps",), extra=("--fps", "nan")),
        c("--fps inf", ("--fps",), extra=("--fps", "inf")),
        c("--fps 1e300", ("--fps",), extra=("--fps", "1e300")),
        c("--out naming a file", ("cap",), _write("cap", b"my notes\n")),
        c("--out naming a user's folder", ("cap",), lambda d: ((d / "cap").mkdir(), (d / "cap" / "thesis.tex").write_text("ch. 1"))),
        c("--mode bogus", ("--mode",), extra=("--mode", "bogus")),
        c("--tracker unknown", ("--tracker",), extra=("--tracker", "no_such_tracker")),
        c("--subject missing", ("nope.toml",), extra=("--subject", "{d}/nope.toml")),
        c("--labelled-trial missing", ("nope.c3d",), extra=("--labelled-trial", "{d}/nope.c3d")),
        c("--labelled-trial with --subject", ("--labelled-trial", "--subject"),
          extra=("--labelled-trial", "{d}/t.c3d", "--subject", "{d}/s.toml")),
        c("a labelled trial of another file type", ("trial.txt",), _write("trial.txt", b"A,B,C\n"),
          extra=("--labelled-trial", "{d}/trial.txt")),
        c("a garbage labelled trial", ("trial.c3d",), _write("trial.c3d", b"\x00\x01garbage\xff" * 40),
          extra=("--labelled-trial", "{d}/trial.c3d")),
        c("an empty labelled trial", ("trial.trc",), _write("trial.trc", b""), extra=("--labelled-trial", "{d}/trial.trc")),
        c("a labelled trial without time_s", ("trial.csv", "time_s"), _write("trial.csv", b"frame,A_x_mm,A_y_mm,A_z_mm\n0,1,2,3\n"),
          extra=("--labelled-trial", "{d}/trial.csv")),
        c("a labelled trial of other markers", ("trial.csv",), _write("trial.csv", _trial_csv(("X", "Y", "Z"), 5)),
          extra=("--labelled-trial", "{d}/trial.csv")),
        c("a labelled trial of one frame", ("trial.csv",), _write("trial.csv", _trial_csv(("A", "B", "C"), 1)),
          extra=("--labelled-trial", "{d}/trial.csv")),
        c("a labelled trial that is a folder", ("trial.c3d",), lambda d: (d / "trial.c3d").mkdir(),
          extra=("--labelled-trial", "{d}/trial.c3d")),
        c("a failure after the export began", ("cap",), patch=_failing_export),
        c("a take of one frame", ("cam0.avi",), lambda d: _synthetic_take(d, n_frames=1)),
        c("a video that is a folder", ("cam1.avi",), lambda d: ((d / "cam1.avi").unlink(), (d / "cam1.avi").mkdir())),
        c("a calibration with one camera", ("cal.yml",), _one_camera_calibration),
    ]
    cases = list(kinds)
    while len(cases) < n:
        cases.append(copy.copy(kinds[rng.integers(len(kinds))]))
    for i, case in enumerate(cases):
        case.label = f"m{i:02d} {case.label}"
    return cases


def _trial_csv(labels: tuple[str, ...], frames: int) -> bytes:
    """A labelled trial as the pipeline's CSV: ``labels`` at fixed offsets moving together over ``frames``."""
    head = "frame,time_s," + ",".join(f"{n}_{a}_mm" for n in labels for a in "xyz")
    rows = [f"{f},{f / 30:.4f}," + ",".join(f"{100 * i + f:.1f},{50 * i:.1f},1000" for i in range(len(labels))) for f in range(frames)]
    return ("\n".join([head, *rows]) + "\n").encode()


def _one_camera_calibration(d: Path) -> None:
    from mocap.calibration import Calibration

    cal = Calibration.load(d / "cal.yml")
    Calibration(tuple(cal)[:1]).save_opencv_yaml(d / "cal.yml")


@contextlib.contextmanager
def _failing_export():
    """The export writes one file into the output folder, then fails (a disk that fills up)."""
    from mocap import marker_pipeline

    real = marker_pipeline.export_capture

    def export_then_fail(capture, out_dir, *a, **k):
        (Path(out_dir) / "markers.c3d").write_bytes(b"half")
        raise OSError(28, "No space left on device", str(Path(out_dir) / "markers.trc"))

    marker_pipeline.export_capture = export_then_fail
    try:
        yield
    finally:
        marker_pipeline.export_capture = real
