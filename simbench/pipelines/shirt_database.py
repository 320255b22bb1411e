"""The colour-shirt pipeline's pose database, made from the bench's humanoid.

The database (:class:`mocap.shirt.pose_database.PoseDatabase`) holds upper-body poses
sampled uniformly over the configurations of the humanoid (each estimated hinge
uniform between its joint limits, read from the model) and over a box of root
orientations around facing the viewer (yaw, pitch and roll about the subject's own
axes, uniform in the configured ranges), each rasterised orthographically as a
normalised 40x40 id map.  It also carries the shirt model the pipeline needs without
the simulator: the humanoid MJCF text and the body-frame triangle meshes of the
shirt's bodies with their patch ids (plus head and hands, which can hide the shirt),
exported from :func:`simbench.scenes.surface.body_surface`.

Rendering uses the pipeline's own CPU rasteriser
(:meth:`mocap.shirt.shirt_model.ShirtModel.render_orthographic`) so that database
entries and run-time renders of a pose are the same pixels.

Default location: ``$SIMBENCH_CACHE_DIR`` or ``~/.cache/simbench``, file
``shirt_db_<hash>.npz`` where the hash covers the subject, the size, the ranges and
the seed; :func:`ensure_database` builds it when missing. ``simbench shirt build-db``
(:mod:`simbench.cli.shirt`) builds one on request.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import time
from contextlib import contextmanager
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Callable, ContextManager, Iterator, TypeVar

import numpy as np
from filelock import FileLock, Timeout
from scipy.spatial.transform import Rotation

from mocap.errors import InputFileError
from mocap.shirt.pose_database import PoseDatabase, tiny_id_map
from mocap.shirt.geometry import SHIRT_BODIES, ShirtGeometry
from mocap.shirt.shirt_model import ShirtModel
from simbench.errors import SimbenchInputError
from simbench.scenes.anthropometry import BodyParams
from simbench.scenes.humanoid import humanoid_mjcf
from simbench.scenes.shirt import COLOUR_NAMES, PATCH_COLOUR
from simbench.scenes.surface import body_surface

T = TypeVar("T")

__all__ = [
    "OCCLUDER_BODIES",
    "FACING_VIEWER",
    "PoseSampling",
    "shirt_geometry",
    "shirt_model",
    "sample_poses",
    "render_entry",
    "build_database",
    "cache_dir",
    "cache_lock",
    "read_or_build",
    "default_database_path",
    "ensure_database",
    "ProgressFactory",
]

OCCLUDER_BODIES: tuple[str, ...] = ("pelvis", "head", "hand_l", "hand_r")
"""Bodies without shirt that can hide part of it (rendered as non-shirt): the trousers over the shirt's hem, head, hands."""

FACING_VIEWER = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, -1.0], [-1.0, 0.0, 0.0]])
"""View-frame rotation of a subject facing the viewer: its left (+Y) to image right,
its up (+Z) to image up (-y), its front (+X) towards the viewer (-z)."""

_RENDER_SIZE = 96  # px: orthographic render, then normalised to 40x40
_RENDER_MARGIN = 1.15
_BATCH = 48  # poses per rasteriser call

log = logging.getLogger(__name__)

#: ``factory(description, total) -> (context manager, advance)``: a progress display the
#: caller (the command line) supplies; ``advance(n)`` reports ``n`` more units done.
ProgressFactory = Callable[[str, int], tuple[ContextManager, Callable[[int], None]]]


@dataclass(frozen=True)
class PoseSampling:
    """How database poses are drawn.

    Angles in degrees: the root's yaw (turning about its up axis), pitch (leaning
    about its left axis) and roll (about its forward axis) away from facing the viewer,
    each uniform in ``[-x, x]``.
    """

    n_poses: int = 80_000
    yaw_deg: float = 80.0
    pitch_deg: float = 25.0
    roll_deg: float = 20.0
    seed: int = 0

    def __post_init__(self) -> None:
        if int(self.n_poses) < 10:
            raise SimbenchInputError(f"shirt database: n_poses = {self.n_poses}; use at least 10 (the pipeline blends 10 neighbours)")
        for name in ("yaw_deg", "pitch_deg", "roll_deg"):
            v = float(getattr(self, name))
            if not (0.0 <= v <= 180.0):
                raise SimbenchInputError(f"shirt database: {name} = {v}; give a range in [0, 180] degrees")


def shirt_geometry(params: BodyParams) -> ShirtGeometry:
    """Body-frame meshes of the shirt's bodies and occluders, with patch ids (from the bench's surface)."""
    parts = {p.body: p for p in body_surface(params, shirt=True)}
    names = SHIRT_BODIES + OCCLUDER_BODIES
    verts, vbody, faces, fpatch = [], [], [], []
    offset = 0
    for i, b in enumerate(names):
        part = parts[b]
        v = np.asarray(part.mesh.vertices, np.float32)
        f = np.asarray(part.mesh.faces, np.int64)
        verts.append(v)
        vbody.append(np.full(len(v), i, np.int16))
        faces.append(f + offset)
        fpatch.append(np.asarray(part.face_patch, np.int16) if b in SHIRT_BODIES else np.full(len(f), -1, np.int16))
        offset += len(v)
    return ShirtGeometry(names, np.concatenate(verts), np.concatenate(vbody), np.concatenate(faces).astype(np.int32),
                         np.concatenate(fpatch), np.asarray(PATCH_COLOUR, np.int16), tuple(COLOUR_NAMES))


def shirt_model(params: BodyParams) -> ShirtModel:
    return ShirtModel(humanoid_mjcf(params), shirt_geometry(params))


def sample_poses(model: ShirtModel, sampling: PoseSampling, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Hinges ``(N, 11)`` uniform within the joint limits and view rotations ``(N, 3, 3)``."""
    n = int(sampling.n_poses)
    lo, hi = model.kin.lower, model.kin.upper
    hinges = lo + (hi - lo) * rng.random((n, len(lo)))
    ang = np.radians([sampling.yaw_deg, sampling.pitch_deg, sampling.roll_deg])
    ypr = (2.0 * rng.random((n, 3)) - 1.0) * ang
    # yaw about the subject's Z, then pitch about its Y, then roll about its X (intrinsic)
    turn = Rotation.from_euler("ZYX", ypr).as_matrix()
    return hinges, FACING_VIEWER @ turn


def render_entry(model: ShirtModel, hinges: np.ndarray, view_rotation: np.ndarray):
    """The normalised tiny map of one pose, with its square in view metres (or None if no shirt shows)."""
    vv = model.view_vertices(hinges, view_rotation)
    centre, side = model.shirt_extent(vv)
    side *= _RENDER_MARGIN
    r = model.render_orthographic(vv, centre, side, _RENDER_SIZE)
    tm = tiny_id_map(r.colour, model.n_colours)
    if tm is None:
        return None
    # render pixel (x, y) centre -> view metres
    px = side / _RENDER_SIZE
    c_m = centre + (tm.centre + 0.5 - _RENDER_SIZE / 2.0) * px
    return tm.ids, c_m, tm.side * px


def build_database(params: BodyParams, sampling: PoseSampling, progress: Callable[[int], None] | None = None) -> PoseDatabase:
    """Sample, render and index a pose database for a subject."""
    model = shirt_model(params)
    rng = np.random.default_rng(np.random.SeedSequence([sampling.seed, 0x5D8]))
    hinges, views = sample_poses(model, sampling, rng)
    n = len(hinges)
    tiny = np.full((n, 40, 40), -1, np.int8)
    centre = np.zeros((n, 2), np.float32)
    side = np.zeros(n, np.float32)
    ok = np.zeros(n, bool)
    for a in range(0, n, _BATCH):
        b = min(a + _BATCH, n)
        vv = model.view_vertices_batch(hinges[a:b], views[a:b])
        c, s = model.shirt_extent_batch(vv)
        s = s * _RENDER_MARGIN
        maps = model.render_orthographic_batch(vv, c, s, _RENDER_SIZE)
        px = s / _RENDER_SIZE
        for j in range(b - a):
            tm = tiny_id_map(maps[j], model.n_colours)
            if tm is None:
                continue
            i = a + j
            tiny[i] = tm.ids
            centre[i] = c[j] + (tm.centre + 0.5 - _RENDER_SIZE / 2.0) * px[j]
            side[i] = tm.side * px[j]
            ok[i] = True
        if progress is not None:
            progress(b - a)
    meta = {"subject": asdict(params), "sampling": asdict(sampling), "render_size_px": _RENDER_SIZE,
            "key": database_key(params, sampling),
            "created_unix_s": time.time(), "dropped_without_shirt": int((~ok).sum())}
    return PoseDatabase.build(tiny[ok], hinges[ok], views[ok], centre[ok], side[ok], model.geometry, model.mjcf_text, meta,
                              np.random.default_rng(np.random.SeedSequence([sampling.seed, 0x9CA])))


def cache_dir() -> Path:
    """``$SIMBENCH_CACHE_DIR`` if set, else ``~/.cache/simbench``."""
    env = os.environ.get("SIMBENCH_CACHE_DIR")
    return Path(env) if env else Path.home() / ".cache" / "simbench"


def database_key(params: BodyParams, sampling: PoseSampling) -> str:
    blob = json.dumps({"subject": asdict(params), "sampling": asdict(sampling), "version": 4, "occluders": list(OCCLUDER_BODIES), "render": _RENDER_SIZE},
                      sort_keys=True).encode()
    return hashlib.sha256(blob).hexdigest()[:12]


def default_database_path(params: BodyParams, sampling: PoseSampling) -> Path:
    return cache_dir() / f"shirt_db_{database_key(params, sampling)}.npz"


class _BuildEstimate:
    """Says once, 10 s into a database build, how long the whole build will take at the rate so far."""

    def __init__(self, total: int, after_s: float = 10.0) -> None:
        self.total, self.after_s, self.done, self.t0, self.said = total, after_s, 0, time.perf_counter(), False

    def advance(self, n: int) -> None:
        self.done += n
        elapsed = time.perf_counter() - self.t0
        if not self.said and elapsed >= self.after_s and self.done < self.total:
            self.said = True
            rate = self.done / elapsed
            # a warning, as the build's first line is: a sweep's or --seeds' workers show warnings only, and the
            # first line promises this one
            log.warning("shirt pose database: %d of %d poses in %.0f s (%.0f poses/s): about %.0f min to go",
                     self.done, self.total, elapsed, rate, (self.total - self.done) / rate / 60.0)


def ensure_database(params: BodyParams, sampling: PoseSampling, path: str | Path | None = None,
                    progress_factory: ProgressFactory | None = None) -> PoseDatabase:
    """Load the database at ``path`` (default: the cache), building it first when missing.

    ``progress_factory`` shows the build's progress (the command line passes its progress
    bar); without it the build reports only its start and end (``logging``). Processes
    that want the same file at once build it once (:func:`cache_lock`); a cached file that
    cannot be read is built again, while an unreadable file the user named is an error.
    """
    named = path is not None
    path = Path(path) if path is not None else default_database_path(params, sampling)

    def build() -> PoseDatabase:
        where = (f"shirt_pipeline.database = {str(path)!r} does not exist" if named
                 else f"no cached shirt pose database for this subject and database_size ({path})")
        log.warning("%s: building it now, %d poses (how long it takes is said 10 s in; `simbench shirt build-db` "
                    "builds it ahead of a run)", where, sampling.n_poses)
        estimate = _BuildEstimate(int(sampling.n_poses))
        if progress_factory is None:
            db = build_database(params, sampling, progress=estimate.advance)
        else:
            prog, advance = progress_factory(f"shirt database ({sampling.n_poses} poses)", int(sampling.n_poses))
            with prog:
                db = build_database(params, sampling, progress=lambda n: (advance(n), estimate.advance(n)))
        db.save(path)
        log.info("wrote %s (%d poses)", path, len(db))
        return db

    return read_or_build(path, lambda p: _load_cached(p, named), build)


def read_or_build(path: Path, read: Callable[[Path], T | None], build: Callable[[], T]) -> T:
    """What ``read`` finds in the cache file at ``path`` (None: unreadable), else what ``build`` makes and writes there.

    A whole file is read without the lock (files are written whole or not at all); to build, :func:`cache_lock` is
    taken and the file looked at again, so that processes that want it at once build it once.
    """
    seen = _file_stamp(path)
    if seen is not None and (found := read(path)) is not None:
        return found
    with cache_lock(path):
        if _file_stamp(path) not in (None, seen) and (found := read(path)) is not None:
            return found  # another process wrote it meanwhile
        return build()


def _file_stamp(path: Path) -> tuple[int, int] | None:
    """``(mtime_ns, size)`` of the file at ``path``, None when there is none: whether another process wrote it."""
    try:
        st = path.stat()
    except FileNotFoundError:
        return None
    return st.st_mtime_ns, st.st_size


def _load_cached(path: Path, named: bool) -> PoseDatabase | None:
    """The database at ``path``; None, said once, when a cached one cannot be read (an unreadable file the
    user named raises :class:`~mocap.errors.InputFileError`)."""
    try:
        return PoseDatabase.load(path)
    except InputFileError as exc:
        if named:
            raise
        log.warning("the cached shirt pose database %s cannot be read (%s): building it again", path, exc.problem)
        return None


@contextmanager
def cache_lock(path: str | Path) -> Iterator[None]:
    """Held while a file at ``path`` is looked for and, when missing, built and written: a second process that
    wants the same file waits (saying so once), then finds it written.

    Why: on a fresh machine the two processes of ``simbench sweep -j 2`` both found the database missing, built
    it at once and wrote it through one temporary name; the file they left was corrupt, and every later shirt
    run failed to read it (session 27). The lock file lives in the cache folder's ``locks/`` (named by a hash of
    ``path``), never beside a file the user named. ``filelock``: an OS lock that is released when its process
    dies, so a killed build does not block the next one.
    """
    key = hashlib.sha256(str(Path(path).resolve()).encode()).hexdigest()[:16]
    folder = cache_dir() / "locks"
    try:
        folder.mkdir(parents=True, exist_ok=True)
        writable = True
    except OSError as exc:  # a cache folder this process cannot write: build without the lock, as before it
        log.warning("cannot make %s (%s): building without a lock against other processes", folder, exc.strerror)
        writable = False
    if not writable:
        yield
        return
    lock = FileLock(folder / f"{key}.lock")
    try:
        lock.acquire(blocking=False)
    except Timeout:
        log.warning("waiting for another process that is writing %s", path)
        lock.acquire()
    try:
        yield
    finally:
        lock.release()
