"""The pose database of step 2: tiny 40x40 id maps of upper-body poses and their nearest-neighbour search.

Each entry is an upper-body pose (the 11 hinges of
:data:`mocap.shirt.kinematics.UPPER_HINGES` and the root's orientation in a *view
frame*: x right, y down, z away from the viewer) rasterised orthographically and
normalised by :func:`tiny_id_map`: the square around the shirt's pixels is resampled
to 40x40 cells holding a colour id (or background).  The same function normalises the
classified shirt region of a camera image, so query and entries agree.

Distance and index
------------------
Two tiny maps are compared by the Euclidean distance between their *encodings*
(:func:`encode_tiny`): per colour, the fraction of each 2x2 block of cells that has the
colour, smoothed by a 3x3 binomial filter (10 colours x 20 x 20 = 4000 numbers).  This
is a smoothed count of the cells whose colours differ (the distance Wang & Popovic
use on tiny id maps), but tolerant to the one- or two-cell misalignments that the
normalisation leaves between a noisy classification and a rendering.  Exact search
in 4000 dimensions over 80,000 entries costs ~20 ms per query on one core, so the
encodings are projected on their 96 principal components (randomised SVD of a sample
of 8000 entries) and indexed by ``faiss.IndexHNSWFlat`` (a graph index:
sub-millisecond queries, recall close to 1 at this size); the best ``candidates``
are then re-ranked with the exact 4000-dimensional distance.  faiss is the
well-kept library for this; the PCA is three lines of numpy.

Blending: the neighbours' hinges are averaged with weights
``exp(-(d_i^2 - d_1^2) / (2 sigma^2))`` (``sigma`` the spread of the 10 distances), and
their orientations (after turning each into the world with its camera's view) by the
weighted quaternion mean of the largest cluster (``scipy.spatial.transform.Rotation.mean``).
"""

from __future__ import annotations

import json
import zipfile
import zlib
from dataclasses import dataclass, field
from pathlib import Path

# ezc3d before faiss: the two SWIG modules share SWIG's runtime type table, and whichever
# loads first owns the converter of std::vector<size_t>. With faiss first, ezc3d's
# Parameter.set rejects its own dimension vectors and every C3D write in the process fails
# (a sweep worker that ran a shirt scenario, then a marker scenario).
import ezc3d  # noqa: F401
import faiss
import numba
import numpy as np
from scipy.spatial.transform import Rotation

from mocap.atomic_files import atomic_target
from mocap.errors import InputFileError
from mocap.npz_files import read_npz
from mocap.shirt.geometry import ShirtGeometry
from mocap.shirt.kinematics import UPPER_HINGES

__all__ = [
    "TINY_SIZE",
    "TinyMap",
    "tiny_id_map",
    "encode_tiny",
    "Neighbours",
    "PoseDatabase",
    "blend_weights",
    "blend_poses",
    "FORMAT_VERSION",
]

TINY_SIZE = 40
_ENC_POOL = 2
_CACHE_ENCODINGS = 20000  # database entries whose encodings a PoseDatabase keeps (search re-ranks 32 a query)
FORMAT_VERSION = 2
_PCA_DIMS = 96
_MIN_PIXELS = 25


#: the arrays a database file holds (:meth:`PoseDatabase.save`)
_ARRAYS = ("tiny", "hinges", "view_quat", "box_centre_m", "box_side_m", "mjcf_text", "meta", "pca_mean", "pca_basis", "index_bytes",
           "hinge_names", *(f"geometry_{n}" for n in ShirtGeometry.ARRAY_NAMES))


@dataclass(frozen=True)
class TinyMap:
    """A normalised tiny id map and the square it was taken from.

    Attributes
    ----------
    ids : (40, 40) int8
        Colour id per cell, -1 for background.
    centre : (2,) float
        Centre of the square in the source map's coordinates (x, y; pixel centres at
        integers) — or in metres for the database's orthographic renders.
    side : float
        Side of the square in the same units.
    """

    ids: np.ndarray
    centre: np.ndarray
    side: float

    def cell_to_source(self, xy: np.ndarray) -> np.ndarray:
        """Cell coordinates ``(..., 2)`` (cell centres at integers) -> source coordinates."""
        return (np.asarray(xy, float) + 0.5) / TINY_SIZE * self.side - 0.5 * self.side + self.centre

    def source_to_cell(self, xy: np.ndarray) -> np.ndarray:
        return (np.asarray(xy, float) - self.centre + 0.5 * self.side) / self.side * TINY_SIZE - 0.5


def _percentiles(v: np.ndarray, percentile: float) -> np.ndarray:
    """``np.percentile(v, [percentile, 100 - percentile])`` of non-negative integers ``v (n,)``, ``n >= 2``: its "linear" method
    operation for operation (the same float64 values), without its generic machinery (several times its cost here;
    compiled: four calls a frame, where numpy's fifteen small calls cost more than the counting)."""
    return _percentile_pair(np.ascontiguousarray(v), float(percentile))


@numba.njit(cache=True, nogil=True)
def _percentile_pair(v, percentile):  # pragma: no cover
    """:func:`_percentiles`: per quantile ``q``, ``vi = (n - 1) q``, ``prev = floor(vi)`` and ``nxt = prev + 1`` (both -1,
    the last, where ``vi >= n - 1``), ``t = vi - prev``, the order statistics ``a, b`` at ``prev, nxt`` (by counting),
    then numpy's lerp ``a + (b - a) t``, or ``b - (b - a)(1 - t)`` where ``t >= 0.5``."""
    n = v.size
    top = 0
    for x in v:
        top = max(top, x + 1)
    cum = np.zeros(top, np.int64)
    for x in v:
        cum[x] += 1
    for i in range(1, top):
        cum[i] += cum[i - 1]
    out = np.empty(2)
    qs = (percentile / 100.0, (100.0 - percentile) / 100.0)
    for j in range(2):
        vi = (n - 1) * qs[j]
        prev = np.floor(vi)
        nxt = prev + 1.0
        if vi >= n - 1:
            prev = -1.0
            nxt = -1.0
        ip, inx = int(prev), int(nxt)
        stats = np.empty(2, np.int64)
        for m, k in enumerate((ip, inx)):
            k = k + n if k < 0 else k
            # np.searchsorted(cum, k, side="right"): the first value whose cumulative count exceeds k
            x = 0
            while x < top and cum[x] <= k:
                x += 1
            stats[m] = x
        a, b = stats[0], stats[1]
        t = vi - ip
        diff = b - a
        out[j] = b - diff * (1.0 - t) if t >= 0.5 else a + diff * t
    return out


def tiny_id_map(colour: np.ndarray, n_colours: int, margin: float = 1.08, percentile: float = 1.0) -> TinyMap | None:
    """Normalise a colour id map (shirt region of an image, or a render) to 40x40 cells.

    The square is centred on the shirt pixels' robust bounding box (``percentile`` to
    ``100 - percentile`` of their x and y, so a few stray pixels do not move it) and
    ``margin`` times its longer side; each cell takes the colour covering most of
    it, or background when colours cover less than half of it.

    Parameters
    ----------
    colour : (H, W) int
        Colour id ``0..n_colours-1`` per pixel, -1 elsewhere.
    n_colours : int

    Returns
    -------
    TinyMap or None
        None when fewer than 25 pixels carry a colour.
    """
    colour = np.asarray(colour)
    ys, xs = np.nonzero(colour >= 0)
    if xs.size < _MIN_PIXELS:
        return None
    # both ends of each axis from one call (one partition of the coordinates, not two)
    px, py = _percentiles(xs, percentile), _percentiles(ys, percentile)
    lo = np.array([px[0], py[0]])
    hi = np.array([px[1], py[1]])
    centre = 0.5 * (lo + hi)
    side = float(max(hi[0] - lo[0], hi[1] - lo[1]) + 1.0) * margin
    side = max(side, 4.0)
    # the square (n x n pixels from (x0, y0), padded where it leaves the map) in 40 x 40
    # cells: each pixel falls into the cell holding its centre; fractions per colour
    x0 = int(np.floor(centre[0] - side / 2 + 0.5))
    y0 = int(np.floor(centre[1] - side / 2 + 0.5))
    n = int(np.ceil(side))
    if n < TINY_SIZE:
        # fewer pixels than cells: each cell takes the pixel under its centre
        src = (np.floor((np.arange(TINY_SIZE) + 0.5) * (n / TINY_SIZE))).astype(np.int64)
        H, W = colour.shape
        yy, xx = y0 + src[:, None], x0 + src[None, :]
        ok = (yy >= 0) & (yy < H) & (xx >= 0) & (xx < W)
        ids = np.where(ok, colour[np.clip(yy, 0, H - 1), np.clip(xx, 0, W - 1)], -1).astype(np.int8)
        return TinyMap(ids, np.array([x0 + (n - 1) / 2.0, y0 + (n - 1) / 2.0]), float(n))
    cell_of = ((np.arange(n) + 0.5) * (TINY_SIZE / n)).astype(np.int64)
    per_cell = np.bincount(cell_of, minlength=TINY_SIZE).astype(np.float32)
    inside = (xs >= x0) & (xs < x0 + n) & (ys >= y0) & (ys < y0 + n)
    cx, cy = cell_of[xs[inside] - x0], cell_of[ys[inside] - y0]
    key = (cy * TINY_SIZE + cx) * n_colours + colour[ys[inside], xs[inside]]
    counts = np.bincount(key, minlength=TINY_SIZE * TINY_SIZE * n_colours).reshape(TINY_SIZE, TINY_SIZE, n_colours)
    frac = counts / (per_cell[:, None, None] * per_cell[None, :, None])
    ids = np.where(frac.sum(axis=2) >= 0.5, frac.argmax(axis=2), -1).astype(np.int8)
    # the square actually sampled: n pixels from (x0, y0) (pixel centres at integers)
    return TinyMap(ids, np.array([x0 + (n - 1) / 2.0, y0 + (n - 1) / 2.0]), float(n))


def encode_tiny(ids: np.ndarray, n_colours: int) -> np.ndarray:
    """Encodings ``(N, n_colours * 400)`` float32 of tiny maps ``(N, 40, 40)`` (see the module docstring)."""
    ids = np.asarray(ids)
    if ids.ndim == 2:
        ids = ids[None]
    return _encode(np.ascontiguousarray(ids, np.int8), int(n_colours), TINY_SIZE // _ENC_POOL, _ENC_POOL).reshape(len(ids), -1)


@numba.njit(cache=True, nogil=True)
def _encode(ids, K, g, pool):  # pragma: no cover
    """Each colour's share of every pool x pool block, smoothed by [1 2 1] / 4 along both axes (edges replicated).

    Compiled (a query encodes its 32 candidates every frame); float32 operations in the
    order of the former numpy form, so encodings (and the database's projection) are
    unchanged.
    """
    N = ids.shape[0]
    counts = np.zeros((N, K, g, g), np.float32)
    for n in range(N):
        for y in range(ids.shape[1]):
            for x in range(ids.shape[2]):
                c = ids[n, y, x]
                if c >= 0:
                    counts[n, c, y // pool, x // pool] += 1
    inv = np.float32(1.0 / (pool * pool))
    q, h = np.float32(0.25), np.float32(0.5)
    rows = np.empty((N, K, g, g), np.float32)
    out = np.empty((N, K, g, g), np.float32)
    for n in range(N):
        for k in range(K):
            for i in range(g):
                im, ip = max(i - 1, 0), min(i + 1, g - 1)
                for j in range(g):
                    rows[n, k, i, j] = q * (counts[n, k, im, j] * inv + counts[n, k, ip, j] * inv) + h * (counts[n, k, i, j] * inv)
            for i in range(g):
                for j in range(g):
                    jm, jp = max(j - 1, 0), min(j + 1, g - 1)
                    out[n, k, i, j] = q * (rows[n, k, i, jm] + rows[n, k, i, jp]) + h * rows[n, k, i, j]
    return out


@dataclass(frozen=True)
class Neighbours:
    """Nearest database entries of one query, best first.

    Attributes
    ----------
    index : (k,) int
    distance : (k,) float
        Encoding distance (see the module docstring).
    hinges : (k, 11) float
        Radians, :data:`UPPER_HINGES` order.
    view_rotation : (k, 3, 3) float
        Root orientation in the view frame (maps root-frame vectors to view coordinates).
    box_centre_m : (k, 2) float
        Centre of the tiny map's square in the view plane relative to the root, metres.
    box_side_m : (k,) float
    """

    index: np.ndarray
    distance: np.ndarray
    hinges: np.ndarray
    view_rotation: np.ndarray
    box_centre_m: np.ndarray
    box_side_m: np.ndarray


@dataclass(eq=False)
class PoseDatabase:
    """Tiny id maps of upper-body poses with their poses, the shirt model and a faiss index.

    Attributes
    ----------
    tiny : (N, 40, 40) int8
        Colour id maps (-1 background).
    hinges : (N, 11) float32
        Radians.
    view_quat : (N, 4) float32
        Root orientation in the view frame, quaternion ``x y z w`` (scipy order).
    box_centre_m : (N, 2) float32
    box_side_m : (N,) float32
    geometry : ShirtGeometry
    mjcf_text : str
        The humanoid the poses belong to.
    meta : dict
        How the database was made (sizes, ranges, seed, subject).
    pca_mean : (D,) float32, pca_basis : (d, D) float32
    index_bytes : (n,) uint8
        ``faiss.serialize_index`` of the HNSW index over the projected encodings.
    """

    tiny: np.ndarray
    hinges: np.ndarray
    view_quat: np.ndarray
    box_centre_m: np.ndarray
    box_side_m: np.ndarray
    geometry: ShirtGeometry
    mjcf_text: str
    meta: dict
    pca_mean: np.ndarray
    pca_basis: np.ndarray
    index_bytes: np.ndarray
    _index: object = field(default=None, repr=False)

    def __len__(self) -> int:
        return len(self.tiny)

    @property
    def n_colours(self) -> int:
        return self.geometry.n_colours

    # ------------------------------------------------------------------ building
    @classmethod
    def build(cls, tiny: np.ndarray, hinges: np.ndarray, view_rotation: np.ndarray, box_centre_m: np.ndarray,
              box_side_m: np.ndarray, geometry: ShirtGeometry, mjcf_text: str, meta: dict,
              rng: np.random.Generator, pca_dims: int = _PCA_DIMS, hnsw_m: int = 32) -> "PoseDatabase":
        """Index entries: PCA of the encodings (on up to 8,000 of them) and an HNSW graph."""
        tiny = np.asarray(tiny, np.int8)
        K = geometry.n_colours
        n = len(tiny)
        sample = rng.choice(n, size=min(n, 8000), replace=False)
        enc = encode_tiny(tiny[sample], K)
        mean = enc.mean(axis=0)
        basis = _principal_axes(enc - mean, min(pca_dims, len(enc)), rng)
        index = faiss.IndexHNSWFlat(basis.shape[0], hnsw_m)
        index.hnsw.efConstruction = 80
        # one thread: faiss inserts into the graph in parallel, and the graph (hence the
        # approximate neighbours a query gets, hence the tracked poses) would then depend
        # on the thread count and timing of the machine that built the database
        threads = faiss.omp_get_max_threads()
        faiss.omp_set_num_threads(1)
        try:
            for a in range(0, n, 5000):
                index.add(cls._project(encode_tiny(tiny[a:a + 5000], K), mean, basis))
        finally:
            faiss.omp_set_num_threads(threads)
        db = cls(tiny, np.asarray(hinges, np.float32), Rotation.from_matrix(view_rotation).as_quat().astype(np.float32),
                 np.asarray(box_centre_m, np.float32), np.asarray(box_side_m, np.float32), geometry, mjcf_text, dict(meta),
                 mean.astype(np.float32), basis, faiss.serialize_index(index))
        db._index = index
        return db

    @staticmethod
    def _project(enc: np.ndarray, mean: np.ndarray, basis: np.ndarray) -> np.ndarray:
        return np.ascontiguousarray((enc - mean) @ basis.T, dtype=np.float32)

    # ------------------------------------------------------------------ I/O
    def save(self, path: str | Path) -> Path:
        """Write one ``.npz`` (compressed); written to a temporary name and renamed."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        meta = dict(self.meta, format_version=FORMAT_VERSION, n_poses=len(self))
        with atomic_target(path, ".npz") as tmp:
            np.savez_compressed(tmp, tiny=self.tiny, hinges=self.hinges, view_quat=self.view_quat,
                                box_centre_m=self.box_centre_m, box_side_m=self.box_side_m, mjcf_text=np.array(self.mjcf_text),
                                meta=np.array(json.dumps(meta)), pca_mean=self.pca_mean, pca_basis=self.pca_basis,
                                index_bytes=np.asarray(self.index_bytes, np.uint8), hinge_names=np.array(UPPER_HINGES),
                                **self.geometry.to_arrays())
        return path

    @staticmethod
    def is_database(path: str | Path) -> bool:
        """Whether ``path`` is a pose database file (its ``meta`` names a ``format_version``); reads only that."""
        try:
            with np.load(path, allow_pickle=False) as z:
                return "meta" in z.files and "format_version" in json.loads(str(z["meta"]))
        except (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile, zlib.error):
            return False

    @classmethod
    def load(cls, path: str | Path) -> "PoseDatabase":
        path = Path(path)
        fix = "build it with `simbench shirt build-db`"
        z = read_npz(path, _ARRAYS, "pose database", fix)  # a missing, foreign or corrupt file: one InputFileError
        meta = json.loads(str(z["meta"]))
        if meta.get("format_version") != FORMAT_VERSION:
            raise InputFileError(path, f"format_version {meta.get('format_version')!r}, this pipeline reads {FORMAT_VERSION}", fix)
        names = tuple(str(s) for s in z["hinge_names"])
        if names != UPPER_HINGES:
            raise InputFileError(path, f"hinges {names} differ from {UPPER_HINGES}", fix)
        db = cls(z["tiny"], z["hinges"], z["view_quat"], z["box_centre_m"], z["box_side_m"], ShirtGeometry.from_arrays(z, source=str(path)),
                 str(z["mjcf_text"]), meta, z["pca_mean"], z["pca_basis"], z["index_bytes"])
        try:
            db._index = faiss.deserialize_index(db.index_bytes)
        except RuntimeError as exc:  # a damaged index, with faiss's own message
            raise InputFileError(path, f"not a readable pose database ({exc})", fix) from None
        return db

    # ------------------------------------------------------------------ search
    def view_rotation(self, i: np.ndarray) -> np.ndarray:
        return Rotation.from_quat(self.view_quat[np.asarray(i)]).as_matrix()

    def _encodings(self, idx: np.ndarray) -> np.ndarray:
        """``encode_tiny(self.tiny[idx])``, each entry's encoding kept once computed (an entry's encoding is its own:
        the same values as encoding the candidates together), up to ``_CACHE_ENCODINGS`` entries."""
        cache = self.__dict__.setdefault("_encoded", {})
        todo = [int(i) for i in idx if int(i) not in cache]
        if todo:
            if len(cache) + len(todo) > _CACHE_ENCODINGS:
                cache.clear()
            for i, row in zip(todo, encode_tiny(self.tiny[todo], self.n_colours)):
                cache[i] = row
        out = np.empty((len(idx), self.n_colours * (TINY_SIZE // _ENC_POOL) ** 2), np.float32)
        for j, i in enumerate(idx):
            out[j] = cache[int(i)]
        return out

    def search(self, tiny: np.ndarray, k: int = 10, candidates: int = 32, ef_search: int = 64) -> Neighbours:
        """The ``k`` entries nearest to a tiny map ``(40, 40)``: HNSW on the projections, exact re-ranking."""
        K = self.n_colours
        q = encode_tiny(tiny, K)
        if self._index is None:
            self._index = faiss.deserialize_index(self.index_bytes)
        self._index.hnsw.efSearch = max(ef_search, candidates)
        _, I = self._index.search(self._project(q, self.pca_mean, self.pca_basis), min(candidates, len(self)))
        cand = I[0][I[0] >= 0]
        d = np.linalg.norm(self._encodings(cand) - q, axis=1)
        order = np.argsort(d)[:k]
        idx = cand[order]
        return Neighbours(idx, d[order], self.hinges[idx].astype(float), self.view_rotation(idx),
                          self.box_centre_m[idx].astype(float), self.box_side_m[idx].astype(float))


def _principal_axes(x: np.ndarray, k: int, rng: np.random.Generator, oversample: int = 32, power: int = 3) -> np.ndarray:
    """The ``k`` leading principal axes ``(k, D)`` float32 of centred rows ``x (n, D)``: randomised SVD.

    Halko, Martinsson & Tropp (2011), algorithm 4.4 (subspace iteration): a full SVD of a
    8000 x 4000 matrix takes minutes, this a second.  Written out (a dozen lines) because
    scikit-learn, which has it, is not a dependency.
    """
    x = np.asarray(x, np.float32)
    m = min(k + oversample, *x.shape)
    Q, _ = np.linalg.qr(x @ rng.standard_normal((x.shape[1], m)).astype(np.float32))
    for _ in range(power):
        Z, _ = np.linalg.qr(x.T @ Q)
        Q, _ = np.linalg.qr(x @ Z)
    _, _, vt = np.linalg.svd(Q.T @ x, full_matrices=False)
    return np.ascontiguousarray(vt[:k], dtype=np.float32)


def blend_weights(distance: np.ndarray) -> np.ndarray:
    """Normalised weights ``exp(-(d_i - d_min)^2 / (2 sigma^2))``, ``sigma`` the spread of the distances."""
    d = np.asarray(distance, float)
    if d.size == 0:
        return d
    sigma = max(float(np.std(d)), 1e-6)
    w = np.exp(-((d - d.min()) ** 2) / (2.0 * sigma**2))
    return w / w.sum()


def blend_poses(hinges: np.ndarray, rotations: np.ndarray, weights: np.ndarray,
                cluster_deg: float = 40.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Weighted blend of candidate poses.

    Parameters
    ----------
    hinges : (n, 11) float
    rotations : (n, 3, 3) float
        World orientations of the candidates' roots.
    weights : (n,) float
    cluster_deg : float
        Only candidates within this angle of the heaviest orientation cluster take part.

    Returns
    -------
    hinges : (11,) float
    rotation : (3, 3) float
    used : (n,) bool
    """
    w = np.asarray(weights, float)
    R = Rotation.from_matrix(rotations)
    # pairwise angles; the candidate with the most weight within cluster_deg seeds the cluster
    # (angle of R_i^-1 R_j = 2 arccos |q_i . q_j|, all pairs at once)
    quat = R.as_quat()
    rel = 2.0 * np.arccos(np.clip(np.abs(quat @ quat.T), 0.0, 1.0))
    near = rel < np.radians(cluster_deg)
    seed = int(np.argmax(near @ w))
    used = near[seed]
    wu = w * used
    wu = wu / wu.sum()
    h = (wu[:, None] * np.asarray(hinges, float)).sum(axis=0)
    rot = R[used].mean(weights=wu[used]).as_matrix()
    return h, rot, used
